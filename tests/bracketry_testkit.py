"""Shared test helpers: component checks, strict mode, free loopback ports, process cleanup.

Strict mode (``BRACKETRY_STRICT=1``, set by CI) turns every "required component missing" skip into a failure, so a
green CI proves that the real Aravis, QEMU, MicroPython runtime and sample data were exercised.
"""

from __future__ import annotations

import functools
import os
import shutil
import socket
import subprocess
from pathlib import Path

import pytest

from bracketry_base import paths
from bracketry_rig import doctor

STRICT = os.environ.get("BRACKETRY_STRICT") == "1"


def missing_component(reason: str) -> None:
    """Skip the current test because a component is absent, or fail it in strict mode."""
    if STRICT:
        pytest.fail(f"required component missing (BRACKETRY_STRICT=1): {reason}", pytrace=False)
    pytest.skip(reason)


@functools.cache
def _checks() -> dict[str, doctor.Check]:
    return {c.name: c for c in doctor.run_all()}


#: pytest marker -> doctor check names it needs
MARKER_NEEDS: dict[str, tuple[str, ...]] = {
    "aravis": ("Aravis typelib 0.8", "arv-fake-gv-camera-0.8", "PyGObject"),
    "qemu": ("arm-none-eabi-gcc", "qemu-system-arm netduinoplus2"),
    "micropython": ("Node.js", "MicroPython WebAssembly"),
    "realdata": ("BorealHDR sample data",),
    "socat": ("socat",),
    "chromium": ("Chromium",),
    "orbslam3": ("ORB-SLAM3 (pyorbslam3)",),
    "latex": ("pdflatex (booktabs, amssymb)",),
}


def require_marker_components(marker: str) -> None:
    """Skip (or fail in strict mode) unless every component of ``marker`` is present."""
    for name in MARKER_NEEDS.get(marker, ()):
        check = _checks()[name]
        if not check.ok:
            missing_component(f"{name} not found; fix: {check.fix}")


def sample_dir() -> Path:
    """The real BorealHDR sample folder (holding ``calibration/``), or skip/fail with the reason."""
    root = paths.sample_data_dir()
    if root is None:
        missing_component(f"BorealHDR sample not found at ../shared/data/borealhdr_sample or ${paths.SAMPLE_ENV}")
        raise AssertionError("unreachable")
    return root


def free_tcp_port() -> int:
    """A free TCP port on 127.0.0.1 (bound then released)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def stop_process(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """End a process this test started (by its PID only): SIGTERM, then SIGKILL after ``timeout_s``."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=timeout_s)


def build_c_under_asan(sources: list[Path], exe: Path, extra_flags: tuple[str, ...] = ()) -> Path:
    """Compile C99 ``sources`` into ``exe`` with the host gcc, -Werror, ASan and UBSan (no recovery); a missing gcc is
    a missing component. Returns ``exe``."""
    gcc = shutil.which("gcc")
    if gcc is None:
        missing_component("host gcc not found; fix: apt-get install gcc")
    subprocess.run([str(gcc), "-std=c99", "-Wall", "-Wextra", "-Werror", *extra_flags, "-g", "-O1",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer",
                    *map(str, sources), "-o", str(exe)], check=True, timeout=120)
    return exe


def tracked_markdown_files(root: Path) -> list[Path]:
    """The Markdown files git tracks under ``root`` (not the reports a run writes into the working tree)."""
    try:
        out = subprocess.run(["git", "-C", str(root), "ls-files", "--cached", "-z", "--", "*.md"], check=True,
                             capture_output=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("git is not available to list the repository's Markdown files")
    return sorted({root / p for p in out.decode().split("\0") if p and (root / p).is_file()})
