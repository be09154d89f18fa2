"""Checks of every component the rig software and the test-suite need, each with its version or a one-line fix."""

from __future__ import annotations

import re
import shutil
import subprocess
from dataclasses import dataclass

from bracketry_base import paths


@dataclass(frozen=True)
class Check:
    """One component: ``ok`` with a ``version`` (or detail), or not ok with a ``fix`` (one line)."""

    name: str
    ok: bool
    version: str
    fix: str


def _run(cmd: list[str], timeout_s: float = 20.0) -> str | None:
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return (out.stdout + out.stderr).strip()


def check_pygobject() -> Check:
    fix = "run ./setup.sh (pip install 'PyGObject<3.51' needs libgirepository1.0-dev libcairo2-dev pkg-config)"
    try:
        import gi  # type: ignore[import-untyped]
    except ImportError:
        return Check("PyGObject", False, "", fix)
    return Check("PyGObject", True, getattr(gi, "__version__", "?"), "")


def check_aravis_typelib() -> Check:
    fix = "apt-get install gir1.2-aravis-0.8 libaravis-0.8-0 (or run ./setup.sh)"
    try:
        import gi  # type: ignore[import-untyped]

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # type: ignore[import-untyped]  # noqa: F401
    except (ImportError, ValueError):
        return Check("Aravis typelib 0.8", False, "", fix)
    return Check("Aravis typelib 0.8", True, _deb_version("libaravis-0.8-0") or "0.8", "")


def _deb_version(package: str) -> str:
    """The installed version of a Debian package, or "" (not a Debian system, not installed)."""
    try:
        out = subprocess.run(["dpkg-query", "-W", "-f=${Version}", package], capture_output=True, text=True,
                             timeout=10, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    return out.stdout.strip() if out.returncode == 0 else ""


def check_binary(name: str, exe: str, version_args: list[str], fix: str, pattern: str = r"(\d+\.\d+(\.\d+)?)",
                 ) -> Check:
    path = shutil.which(exe)
    if path is None:
        return Check(name, False, "", fix)
    out = _run([path, *version_args]) or ""
    m = re.search(pattern, out)
    return Check(name, True, m.group(1) if m else path, "")


def check_fake_camera() -> Check:
    fix = "apt-get install aravis-tools (or run ./setup.sh)"
    path = shutil.which("arv-fake-gv-camera-0.8")
    if path is None:
        return Check("arv-fake-gv-camera-0.8", False, "", fix)
    return Check("arv-fake-gv-camera-0.8", True, _deb_version("aravis-tools") or path, "")


def check_qemu_machine() -> Check:
    fix = "apt-get install qemu-system-arm (or run ./setup.sh)"
    exe = shutil.which("qemu-system-arm")
    if exe is None:
        return Check("qemu-system-arm netduinoplus2", False, "", fix)
    ver = _run([exe, "--version"]) or ""
    machines = _run([exe, "-M", "help"]) or ""
    m = re.search(r"version (\d+\.\d+\.\d+)", ver)
    if "netduinoplus2" not in machines:
        return Check("qemu-system-arm netduinoplus2", False, m.group(1) if m else "",
                     "this QEMU lacks the netduinoplus2 machine: install Debian's qemu-system-arm >= 5.2")
    return Check("qemu-system-arm netduinoplus2", True, m.group(1) if m else "?", "")


def check_micropython() -> Check:
    fix = "run ./setup.sh (npm install @micropython/micropython-webassembly-pyscript into .venv/micropython-wasm)"
    mjs = paths.micropython_module_path()
    if not mjs.is_file():
        return Check("MicroPython WebAssembly", False, "", fix)
    pkg = mjs.parent / "package.json"
    ver = "?"
    if pkg.is_file():
        m = re.search(r'"version"\s*:\s*"([^"]+)"', pkg.read_text())
        ver = m.group(1) if m else "?"
    return Check("MicroPython WebAssembly", True, ver, "")


def check_orbslam3() -> Check:
    """ORB-SLAM3 through ``pyorbslam3``: its native module must load (it links the OpenGL/X11 runtime libraries).

    Loaded in a child interpreter, so a missing shared library cannot take this process down with it.
    """
    import sys

    fix = ("pip install 'pyorbslam3>=0.1.1,<0.2' and apt-get install libgl1 libegl1 libopengl0 libsm6 libice6 "
           "libx11-6 libxext6 (or run ./setup.sh)")
    code = ("import importlib.metadata as m, pyorbslam3._core as c; "
            "assert hasattr(c, 'Slam'); print(m.version('pyorbslam3'))")
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return Check("ORB-SLAM3 (pyorbslam3)", False, "", fix)
    if out.returncode != 0:
        last = (out.stderr.strip().splitlines() or ["?"])[-1]
        return Check("ORB-SLAM3 (pyorbslam3)", False, "", f"{last[:120]}; {fix}")
    return Check("ORB-SLAM3 (pyorbslam3)", True, out.stdout.strip(), "")


def check_sample_data() -> Check:
    root = paths.sample_data_dir()
    if root is None:
        return Check("BorealHDR sample data", False, "",
                     f"put the sample at ../shared/data/borealhdr_sample or set ${paths.SAMPLE_ENV}")
    return Check("BorealHDR sample data", True, str(root), "")


def check_pdflatex() -> Check:
    """pdflatex with the packages the report's LaTeX tables need (booktabs, amssymb)."""
    fix = "apt-get install texlive-latex-base texlive-latex-recommended texlive-fonts-recommended (or run ./setup.sh)"
    if shutil.which("pdflatex") is None:
        return Check("pdflatex (booktabs, amssymb)", False, "", fix)
    missing = [sty for sty in ("booktabs.sty", "amssymb.sty") if not (_run(["kpsewhich", sty]) or "").endswith(sty)]
    if missing:
        return Check("pdflatex (booktabs, amssymb)", False, "", f"{', '.join(missing)} not found: {fix}")
    version = re.search(r"TeX Live (\d+)", _run(["pdflatex", "--version"]) or "")
    return Check("pdflatex (booktabs, amssymb)", True, f"TeX Live {version.group(1)}" if version else "?", "")


def run_all() -> list[Check]:
    """Run every check; never raises."""
    return [
        check_aravis_typelib(),
        check_fake_camera(),
        check_pygobject(),
        check_binary("arm-none-eabi-gcc", "arm-none-eabi-gcc", ["--version"],
                     "apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi (or run ./setup.sh)",
                     r"(\d+\.\d+\.\d+)"),
        check_qemu_machine(),
        check_binary("socat", "socat", ["-V"], "apt-get install socat (or run ./setup.sh)", r"socat version (\S+)"),
        check_binary("Node.js", "node", ["--version"], "apt-get install nodejs npm (or run ./setup.sh)",
                     r"v?(\d+\.\d+\.\d+)"),
        check_micropython(),
        check_binary("Chromium", "chromium", ["--version"], "apt-get install chromium (or run ./setup.sh)",
                     r"Chromium (\S+)"),
        check_orbslam3(),
        check_pdflatex(),
        check_sample_data(),
    ]
