"""The commands that run work in parallel processes (demo, benchmark, emulate) apply their runtime profile (one
OpenBLAS thread among its settings) before numpy loads OpenBLAS: that only works while importing the CLI and those
commands does not import numpy."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

COMMANDS = ("bracketry.cli.demo", "bracketry_emulator.cli.benchmark", "bracketry_emulator.cli.emulate")


def test_cli_commands_set_blas_threads_before_numpy_loads() -> None:
    code = f"import sys\nimport bracketry.cli, {', '.join(COMMANDS)}\nprint('numpy' in sys.modules)\n"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "False", "numpy is imported before the commands set OPENBLAS_NUM_THREADS"
    for name in COMMANDS:
        spec = importlib.util.find_spec(name)
        assert spec is not None and spec.origin is not None
        assert "apply_profile(" in Path(spec.origin).read_text(), name


def test_one_blas_thread_keeps_a_thread_count_the_caller_set(monkeypatch: pytest.MonkeyPatch) -> None:
    from bracketry_emulator.runtime_policy import set_blas_threads

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    set_blas_threads(1)
    assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    set_blas_threads(1)
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
