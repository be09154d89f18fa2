"""`bracketry demo --quick` from end to end: a recording that verifies clean, a report with every method and metric."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

PAPER_METHODS = ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim"]  # + drl with its weights
METRICS = ["RTE (%)", "RRE (deg/m)", "coverage median (%)", "matches median", "time before failure median (s)"]


@pytest.mark.aravis
@pytest.mark.socat
@pytest.mark.slow
def test_demo_quick_records_verifies_and_reports_every_method(tmp_path: Path) -> None:
    from bracketry_emulator.ae.drl import save_random_actor

    out = tmp_path / "demo"
    # DRL joins when its weights are given (a seeded random actor here: the public weights are not shipped)
    weights = save_random_actor(tmp_path / "actor.pth", seed=3)
    env = {**os.environ, "BRACKETRY_DRL_WEIGHTS": str(weights)}
    res = subprocess.run([sys.executable, "-m", "bracketry", "demo", "--quick", "--out", str(out)],
                         capture_output=True, text=True, timeout=1500, env=env)
    assert res.returncode == 0, (res.stdout[-2000:], res.stderr[-3000:])
    assert "Traceback" not in res.stderr
    # progress all the way: the rig's first frame and panel screens, the closed loops' progress, VO per method
    for text in ("[1/3]", "first frame recorded", "|L:REC R:REC TRIG:REC|", "[2/3]", "[3/3]", "emulate",
                 "SLAM + metrics"):
        assert text in res.stderr, text
    summary = json.loads((out / "demo_summary.json").read_text())
    assert summary["recording_verified"] is True
    # where the time went: wall and CPU (every process of the demo, children included) per stage
    for key in ("record", "export", "benchmark", "total"):
        assert summary["timing_s"][key] > 0 and summary["cpu_s"][key] > 0, (key, summary["cpu_s"])
    assert summary["cpu_s"]["total"] >= summary["cpu_s"]["record"] + summary["cpu_s"]["benchmark"] - 0.2
    assert f"CPU {summary['cpu_s']['total']} s (recording " in res.stdout
    assert min(summary["frames"].values()) >= 200  # 10 s at 22 fps per camera
    assert summary["drops"] == {"left": 0, "right": 0}
    for seg in summary["recordings"]:  # the recording verifies clean by the user's own command too
        check = subprocess.run([sys.executable, "-m", "bracketry", "verify", seg], capture_output=True, text=True,
                               timeout=300)
        assert check.returncode == 0, check.stdout[-2000:]
    methods = sorted([*PAPER_METHODS, "drl"])
    assert summary["methods"] == methods
    # every recorded frame carries the rendered frame it shows, both images of a pair the same one: every pose known
    assert summary["frames_without_pose"] == 0, res.stdout[-2000:]
    held = summary["frames_held_for_renderer"]
    if held:  # a renderer behind on a loaded machine: said, and the walk may be too short for the RTE windows
        assert "NOT those of an idle run" in res.stderr and "not an idle run's figures" in res.stdout, res.stdout
        assert set(METRICS) - set(summary["best"]) <= {"RTE (%)", "RRE (deg/m)"}, summary["best"]
        if "RTE (%)" not in summary["best"]:
            assert "RTE/RRE not computed for any method: the world held" in res.stdout, res.stdout
    else:
        assert set(summary["best"]) == set(METRICS), (summary["best"], summary["load_average"], res.stdout[-2000:])
    with open(summary["report"]["summary.csv"], newline="") as f:
        rows = list(csv.reader(f))
    assert rows[0][:6] == ["method", *METRICS]
    assert sorted(r[0] for r in rows[1:]) == methods
    for row in rows[1:]:  # every method has a finite value for every metric (RTE/RRE: unless the world held)
        for metric, value in zip(METRICS, row[1:6], strict=True):
            if held and metric in ("RTE (%)", "RRE (deg/m)"):
                continue
            assert math.isfinite(float(value)), (row[0], metric, value)
    report_md = Path(summary["report"]["report.md"]).read_text()
    for method in methods:
        assert f"| {method} |" in report_md or f"| {method}|" in report_md, method
    for png in ("coverage.png", "matches.png", "failure.png", "qualitative.png"):
        assert Path(summary["report"][png]).stat().st_size > 1000
    # the exported dataset: both cameras, six exposures, ground truth and calibration
    ds = Path(summary["dataset"])
    assert sorted(p.name for p in (ds / "camera_left").iterdir()) == ["1.0", "16.0", "2.0", "32.0", "4.0", "8.0"]
    assert (ds / "groundtruth.txt").is_file() and (ds / "calibration").is_dir()
    assert f"report: {summary['report'].get('report.html')}" in res.stdout
