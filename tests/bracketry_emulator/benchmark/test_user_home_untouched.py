"""Nothing a user owns is changed behind their back (#44 item 3): importing every module of both packages, and
dask-jobqueue as the Slurm runs import it, writes nothing into the user's home; a suite folder handed out of the
cache holds copies, so writing into it leaves the cache as it was."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from bracketry_base.paths import repo_root
from bracketry_emulator.synth.suite import _link_tree

IMPORT_ALL = """
import importlib, pkgutil
import bracketry, bracketry_base, bracketry_emulator, bracketry_rig
for pkg in (bracketry_base, bracketry_rig, bracketry_emulator, bracketry):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
from bracketry_emulator.benchmark.cluster import import_slurm_cluster
import_slurm_cluster()
print("imported")
"""


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


def test_importing_every_module_and_dask_jobqueue_leaves_home_empty(tmp_path: Path) -> None:
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DASK_", "XDG_"))}
    env.update(HOME=str(home), PYTHONPATH=os.pathsep.join(str(repo_root() / p) for p in ("host", "emulator")))
    res = subprocess.run([sys.executable, "-c", IMPORT_ALL], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and "imported" in res.stdout, res.stderr[-2000:]
    assert _files(home) == []
    # the check can fail: a plain import of dask-jobqueue writes its config into this home
    res = subprocess.run([sys.executable, "-c", "import dask_jobqueue"], env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert [p.name for p in _files(home)] == ["jobqueue.yaml"]


def test_a_suite_folder_holds_copies_of_the_cache(tmp_path: Path) -> None:
    cache, suite = tmp_path / "cache", tmp_path / "suite"
    (cache / "forest" / "walk").mkdir(parents=True)
    (cache / "forest" / "walk" / "frame.png").write_bytes(b"cached")
    (cache / "manifest.yaml").write_text("suite: x\n")
    _link_tree(cache, suite)
    (suite / "forest" / "walk" / "frame.png").write_bytes(b"edited by the user")
    with open(suite / "manifest.yaml", "a") as fh:
        fh.write("note: mine\n")
    assert (cache / "forest" / "walk" / "frame.png").read_bytes() == b"cached"
    assert (cache / "manifest.yaml").read_text() == "suite: x\n"
    frame = Path("forest", "walk", "frame.png")
    assert (suite / frame).stat().st_ino != (cache / frame).stat().st_ino
