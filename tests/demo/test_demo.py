"""`bracketry demo --quick` from end to end: a recording that verifies clean, a report with every method and metric."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

PAPER_METHODS = ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "zhang"]
METRICS = ["RTE (%)", "RRE (deg/m)", "coverage median (%)", "matches median", "time before failure median (s)"]


@pytest.mark.aravis
@pytest.mark.socat
@pytest.mark.slow
def test_demo_quick_records_verifies_and_reports_every_method(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    res = subprocess.run([sys.executable, "-m", "bracketry", "demo", "--quick", "--out", str(out)],
                         capture_output=True, text=True, timeout=1500)
    assert res.returncode == 0, (res.stdout[-2000:], res.stderr[-3000:])
    assert "Traceback" not in res.stderr
    summary = json.loads((out / "demo_summary.json").read_text())
    assert summary["recording_verified"] is True
    assert min(summary["frames"].values()) >= 150  # 8 s at 22 fps per camera
    assert summary["drops"] == {"left": 0, "right": 0}
    assert summary["methods"] == sorted(PAPER_METHODS)
    assert set(summary["best"]) == set(METRICS)
    report_md = Path(summary["report"]["report.md"]).read_text()
    for method in PAPER_METHODS:
        assert method in report_md
    summary_csv = Path(summary["report"]["summary.csv"]).read_text().splitlines()
    assert summary_csv[0].split(",")[:6] == ["method", *METRICS]
    assert sorted(line.split(",")[0] for line in summary_csv[1:]) == sorted(PAPER_METHODS)
    for png in ("coverage.png", "matches.png", "failure.png", "qualitative.png"):
        assert Path(summary["report"][png]).stat().st_size > 1000
    # the exported dataset: both cameras, six exposures, ground truth and calibration
    ds = Path(summary["dataset"])
    assert sorted(p.name for p in (ds / "camera_left").iterdir()) == ["1.0", "16.0", "2.0", "32.0", "4.0", "8.0"]
    assert (ds / "groundtruth.txt").is_file() and (ds / "calibration").is_dir()
    assert f"report: {summary['report'].get('report.html')}" in res.stdout
