"""A laptop benchmarks without root (#42 item 6, README "Installs by role"): as a non-root user, from its own venv
with the emulator extra (no Debian package, no sudo), a synthetic trajectory rendered and benchmarked with the
built-in VO.

The venv is installed by ``tests/laptop_venv.py``, a set-up step (it downloads from PyPI) that ``.ci/run`` runs; this
test copies the current source into the user's home (its editable install reads it there) and runs the commands as
that user through ``runuser`` with a clean environment.
"""

from __future__ import annotations

import shutil

import pytest

from bracketry_base.paths import repo_root
from bracketry_testkit import missing_component
from laptop_venv import as_user, copy_source, home_paths, ready_user

pytestmark = pytest.mark.slow


def test_a_non_root_user_benchmarks_a_synthetic_trajectory_from_its_own_venv() -> None:
    user, why = ready_user(repo_root())
    if user is None:
        missing_component(why)
        return
    src, venv, _stamp = home_paths(user)
    copy_source(repo_root(), src, user)
    bracketry = str(venv / "bin" / "bracketry")
    # the user's own install: its source, no root, nothing of the rig's or the learning extras
    res = as_user(user, str(venv / "bin" / "python"), "-c",
                  "import os, importlib.util as u, bracketry, bracketry_emulator; "
                  "print(os.getuid(), bracketry.__file__, bracketry_emulator.__file__, u.find_spec('torch'), "
                  "u.find_spec('gi'))", timeout_s=120)
    assert res.returncode == 0, res.stderr[-2000:]
    uid, host_pkg, emu_pkg, torch, gi = res.stdout.split()
    assert int(uid) == user.pw_uid != 0
    assert host_pkg.startswith(str(src)) and emu_pkg.startswith(str(src))
    assert torch == gi == "None"

    home = src.parent
    walk, bench = home / "laptop-walk", home / "laptop-bench"
    for folder in (walk, bench):
        shutil.rmtree(folder, ignore_errors=True)
    res = as_user(user, bracketry, "synth", "trajectory", "--out", str(walk), "--duration-s", "4",
                  "--resolution", "320x200", "--quiet", timeout_s=1800)
    assert res.returncode == 0, res.stderr[-3000:]
    res = as_user(user, bracketry, "benchmark", str(walk), "--out", str(bench), "--slam", "builtin",
                  "--methods", "ae50,fix", "--workers", "2", "--quiet", timeout_s=1800)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (bench / "report" / "report.md").is_file() and (bench / "report" / "results.csv").is_file()
    rows = (bench / "report" / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 2  # one trajectory x 2 methods
    assert all(p.stat().st_uid == user.pw_uid for p in bench.rglob("*"))
