"""The board capture driving the simulated rig in calibration mode (#35 item 1): two fake GigE cameras (Aravis, in a
private network namespace) serving a board moved by hand, one fixed exposure and zero gain, triggered together; the
kept set is enough and solves within the issue's tolerances."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_emulator.synth.calibration import default_calibration
from bracketry_emulator.vo.calibration import CameraInfo, StereoRectifier
from bracketry_rig.cameras.netns import netns_available
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US
from bracketry_testkit import missing_component

pytestmark = [pytest.mark.aravis, pytest.mark.slow]

#: the issue's tolerances
FOCAL_REL, PP_PX, BASELINE_REL = 0.005, 2.0, 0.01


def test_capture_from_the_simulated_rig_keeps_an_enough_set_that_solves(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    kept = tmp_path / "kept"
    res = subprocess.run([sys.executable, "-m", "bracketry", "calibrate", "capture", "--rig", "sim", "--out",
                          str(kept), "--seed", "1", "--max-pairs", "60", "--exposure-us", "800", "--quiet"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    cap = json.loads((kept / "capture.json").read_text())
    assert cap["enough"] and cap["kept"] >= 15, cap["advice"]
    assert cap["source"] == "rig sim" and cap["gain"] == 0 and cap["pairs_not_matched"] == 0
    # calibration mode: every frame each camera served after the priming trigger was at the one fixed exposure
    for side in ("left", "right"):
        served = cap["served_exposures_us"][side]
        assert [e for e in served if e != PRIMING_EXPOSURE_US] == [800] * len(cap["pairs"])
    names = sorted(p.name for p in (kept / "left").glob("*.png"))
    assert names == sorted(p.name for p in (kept / "right").glob("*.png"))
    assert len(names) == cap["kept"] == sum(p["kept"] for p in cap["pairs"])
    # the capture stops at "enough": its last pair was kept
    assert cap["pairs"][-1]["kept"] and len(cap["pairs"]) < 60

    cal = tmp_path / "cal"
    assert main(["calibrate", "solve", str(kept), "--out", str(cal), "--quiet"]) == 0
    truth = default_calibration(640, 400)
    assert CameraInfo.from_yaml(kept / "truth" / "left.yaml").K[0, 0] == pytest.approx(truth.left.fx)
    for side in ("left", "right"):
        info, cam = CameraInfo.from_yaml(cal / f"{side}.yaml"), truth.side(side)
        assert abs(info.K[0, 0] / cam.fx - 1) < FOCAL_REL and abs(info.K[1, 1] / cam.fy - 1) < FOCAL_REL
        assert abs(info.K[0, 2] - cam.cx) < PP_PX and abs(info.K[1, 2] - cam.cy) < PP_PX
    assert abs(StereoRectifier.from_dir(cal).baseline_m / truth.baseline_m - 1) < BASELINE_REL
