"""A laptop benchmarks without root (#42 item 6, docs/FIELD.md "Benchmarking"): as a non-root user, with the
system Python, a venv of its own (``python3 -m venv``) and the emulator extra installed from PyPI
(``pip install -e '.[emulator]'``: no Debian package, no sudo), the demo-size synthetic suite rendered and
benchmarked with the built-in VO.

The user is ``$BRACKETRY_LAPTOP_USER`` (default ``bracketry-laptop``), made with ``useradd`` when the test runs as
root and it does not exist; the commands run as it through ``runuser`` with a clean environment. Its venv and suite
are kept in its home between runs (the venv is installed again only when pyproject.toml or a C source changes; the
first install downloads the extra's wheels from PyPI, as a laptop does). The source is copied into its home (the
user reads nothing of the test's tree).
"""

from __future__ import annotations

import hashlib
import os
import pwd
import shutil
import subprocess
from pathlib import Path

import pytest

from bracketry.paths import repo_root
from bracketry_testkit import missing_component

pytestmark = pytest.mark.slow

USER = os.environ.get("BRACKETRY_LAPTOP_USER", "bracketry-laptop")
#: the system Python a laptop has (Debian 12: 3.11), never the test's own interpreter or venv
SYSTEM_PYTHON = "/usr/bin/python3"


def laptop_user() -> pwd.struct_passwd:
    """The non-root user, made when missing (needs root; else the test is skipped, or fails in strict mode)."""
    if os.geteuid() != 0:
        missing_component("running as another user needs root (runuser)")
    for tool in ("runuser", "useradd"):
        if shutil.which(tool) is None:
            missing_component(f"{tool} not found")
    if not Path(SYSTEM_PYTHON).is_file():
        missing_component(f"no system Python at {SYSTEM_PYTHON}")
    try:
        return pwd.getpwnam(USER)
    except KeyError:
        subprocess.run(["useradd", "--create-home", "--shell", "/bin/bash", USER], check=True)
        return pwd.getpwnam(USER)


def as_user(user: pwd.struct_passwd, *cmd: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """``cmd`` as ``user`` in its home, with a clean environment (no PYTHONPATH, no venv of the test's)."""
    env = ["env", "-i", f"HOME={user.pw_dir}", f"USER={user.pw_name}", "PATH=/usr/local/bin:/usr/bin:/bin",
           "LANG=C.UTF-8"]
    return subprocess.run(["runuser", "-u", user.pw_name, "--", *env, *cmd], cwd=user.pw_dir, capture_output=True,
                          text=True, timeout=timeout_s)


def source_files(root: Path) -> list[str]:
    """The repository's files (tracked and new, not ignored): what a clone holds."""
    out = subprocess.run(["git", "-C", str(root), "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                         capture_output=True, check=True).stdout
    return sorted(f for f in out.decode().split("\0") if f and (root / f).is_file())


def copy_source(root: Path, dest: Path, user: pwd.struct_passwd) -> str:
    """Copy the repository's files into ``dest`` (owned by ``user``); returns the digest of what the install depends
    on (pyproject.toml and the C sources)."""
    digest = hashlib.sha256(str(dest).encode())
    for name in source_files(root):
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / name, target)
        if name == "pyproject.toml" or name.endswith(".c"):
            digest.update(name.encode() + (root / name).read_bytes())
    subprocess.run(["chown", "-R", f"{user.pw_uid}:{user.pw_gid}", str(dest)], check=True)
    return digest.hexdigest()


def test_a_non_root_user_benchmarks_the_demo_suite_from_its_own_venv() -> None:
    user = laptop_user()
    home = Path(user.pw_dir)
    src, venv = home / "bracketry-src", home / "venv-emulator"  # not "bracketry": a folder of the package's name
    stamp = venv / ".bracketry-installed"
    digest = copy_source(repo_root(), src, user)
    if not stamp.is_file() or stamp.read_text() != digest:
        if not (venv / "bin" / "python").is_file():
            res = as_user(user, SYSTEM_PYTHON, "-m", "venv", str(venv), timeout_s=300)
            assert res.returncode == 0, res.stderr[-2000:]
        res = as_user(user, str(venv / "bin" / "pip"), "install", "-q", "-e", f"{src}[emulator]", timeout_s=3600)
        assert res.returncode == 0, res.stderr[-3000:]
        as_user(user, "sh", "-c", f"printf %s {digest} > {stamp}", timeout_s=30)
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

    suite, bench = home / "laptop-suite", home / "laptop-bench"
    res = as_user(user, bracketry, "synth", "suite", "--size", "demo", "--seed", "0", "--out", str(suite),
                  "--workers", "2", "--quiet", timeout_s=1800)
    assert res.returncode == 0, res.stderr[-3000:]
    shutil.rmtree(bench, ignore_errors=True)
    res = as_user(user, bracketry, "benchmark", str(suite / "manifest.yaml"), "--out", str(bench), "--slam",
                  "builtin", "--methods", "ae50,fix", "--workers", "2", "--quiet", timeout_s=1800)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (bench / "report" / "report.md").is_file() and (bench / "report" / "results.csv").is_file()
    rows = (bench / "report" / "results.csv").read_text().splitlines()
    assert len(rows) == 1 + 14 * 2  # 14 trajectories x 2 methods
    assert all(p.stat().st_uid == user.pw_uid for p in bench.rglob("*"))
