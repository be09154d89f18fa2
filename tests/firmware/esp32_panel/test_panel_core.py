"""The panel firmware's core modules (layout, debounce, link, app) under CPython and the real MicroPython runtime.

Both runs execute tests/firmware/esp32_panel/panel_core_checks.py against the actual firmware files and the wire codec
bproto.py.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from bracketry_base import paths

HERE = Path(__file__).resolve().parent
FIRMWARE = paths.firmware_dir() / "esp32_panel"
BPROTO = paths.repo_root() / "host" / "bracketry_rig" / "wire" / "bproto.py"
CHECKS = HERE / "panel_core_checks.py"
VECTOR_CHECKS = HERE / "panel_vector_checks.py"
VECTORS = paths.firmware_dir() / "protocol" / "protocol_vectors.json"
RUNNER = HERE / "panel_mpy_run.mjs"
MACHINE_CHECKS = HERE / "panel_machine_checks.py"
FAKE_MACHINE_DIR = HERE / "mpy_fake"
SCRIPTS = {"core": CHECKS, "vectors": VECTOR_CHECKS, "machine": MACHINE_CHECKS}


def _expected_checks(script: Path = CHECKS) -> list[str]:
    return re.findall(r"^def (check_\w+)\(", script.read_text(), flags=re.M)



def _passed(stdout: str) -> list[str]:
    return [line[5:].strip() for line in stdout.splitlines() if line.startswith("PASS ")]


@pytest.mark.parametrize("which", sorted(SCRIPTS))
def test_panel_checks_cpython(which: str) -> None:
    env_path = f"{FAKE_MACHINE_DIR}:{FIRMWARE}:{BPROTO.parent}" if which == "machine" else f"{FIRMWARE}:{BPROTO.parent}"
    proc = subprocess.run([sys.executable, str(SCRIPTS[which])], capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"}, cwd=VECTORS.parent)
    assert proc.returncode == 0, proc.stderr
    assert _passed(proc.stdout) == _expected_checks(SCRIPTS[which])


def run_micropython(script: Path, files: list[Path], timeout_s: float = 240) -> subprocess.CompletedProcess[str]:
    """Run ``script`` under the MicroPython WebAssembly runtime with ``files`` copied to its root folder."""
    return subprocess.run(["node", str(RUNNER), str(paths.micropython_module_path()), str(script),
                           *[str(f) for f in files]], capture_output=True, text=True, timeout=timeout_s)


def firmware_core_files() -> list[Path]:
    """The hardware-independent firmware modules plus the codec (what the checks import)."""
    return [BPROTO, *sorted(FIRMWARE.glob("panel_*.py"))]


@pytest.mark.micropython
@pytest.mark.parametrize("which", sorted(SCRIPTS))
def test_panel_checks_micropython(which: str) -> None:
    files = [*firmware_core_files(), VECTORS]
    if which == "machine":  # the machine layer too, on a fake `machine` (the runtime has none)
        files = [BPROTO, *sorted(FIRMWARE.glob("*.py")), FAKE_MACHINE_DIR / "machine.py"]
    proc = run_micropython(SCRIPTS[which], files)
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert _passed(proc.stdout) == _expected_checks(SCRIPTS[which])


@pytest.mark.micropython
def test_panel_runs_on_micropython_implementation(tmp_path: Path) -> None:
    """The checks really ran on MicroPython (not a CPython fallback): sys.implementation is micropython."""
    script = tmp_path / "impl.py"
    script.write_text("import sys, panel_app\nprint('IMPL', sys.implementation.name, panel_app.FW_VERSION)\n")
    proc = run_micropython(script, firmware_core_files(), timeout_s=60)
    assert proc.returncode == 0, proc.stderr
    assert "IMPL micropython (1, 0, 0)" in proc.stdout
