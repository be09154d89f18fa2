"""docs/TUTORIAL-plugin.md as a reader follows it: its method file and its commands, read from the tutorial and run
in an empty folder; the verdict table it shows is the one the run writes."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from bracketry_base.paths import repo_root

pytestmark = pytest.mark.slow
TUTORIAL = repo_root() / "docs" / "TUTORIAL-plugin.md"


def _blocks(kind: str) -> list[str]:
    return re.findall(rf"```{kind}\n(.*?)```", TUTORIAL.read_text(), re.S)


def test_the_tutorial_runs_as_written(tmp_path: Path) -> None:
    (method,) = _blocks("python")
    assert len(method.strip().splitlines()) <= 22, "the tutorial's method is meant to be about 20 lines"
    (tmp_path / "my_method.py").write_text(method)
    run_cmd, show_cmd = (b.strip() for b in _blocks("sh"))
    (expected,) = _blocks("text")
    # `bracketry` as a reader's shell finds it: the interpreter running the tests' scripts folder first on PATH
    env = {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])}
    env.pop("PYTHONPATH", None)
    res = subprocess.run(run_cmd, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    shown = subprocess.run(show_cmd, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout == expected
    report = tmp_path / "demo-out" / "benchmark"
    assert "mean-target: my_method:MeanTarget, target=0.3" in (report / "report" / "report.md").read_text()
    assert list(report.glob("runs/*/mean-target/ae.csv"))
