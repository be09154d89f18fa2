"""Stereo VO on a rendered corridor with ground truth: tracks at a good exposure, loses track when saturated."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.metrics import evaluate_run, read_segments
from bracketry_emulator.vo import StereoRectifier, read_frames_csv, run_vo


@pytest.fixture(scope="module")
def world_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("toyworld")
    w = ToyWorld()
    w.write_calibration(d)
    times = w.write_run(d / "runs", "good", 30)
    w.write_groundtruth(d / "groundtruth.txt", times)
    gains = [1.0] * 10 + [12.0] * 5 + [1.0] * 8
    w.write_run(d / "runs", "saturated", len(gains), gain=gains)
    return d


@pytest.mark.realdata
def test_bench_rectifier_from_sample_calibration(borealhdr_sample) -> None:
    rect = StereoRectifier.from_dir(borealhdr_sample / "calibration")
    assert rect.baseline_m == pytest.approx(180.0 / 1009.76978, rel=1e-6)  # -P[0,3] / P[0,0]
    assert not rect.identity
    small = StereoRectifier.from_dir(borealhdr_sample / "calibration", 480, 300)
    assert small.fx == pytest.approx(rect.fx / 4, rel=0.01) and small.baseline_m == pytest.approx(rect.baseline_m)
    mask = small.valid_mask()
    assert mask.shape == (300, 480) and 0.5 < (mask > 0).mean() < 1.0


def test_bench_vo_tracks_whole_sequence_with_bounded_rte(world_dir: Path, tmp_path: Path) -> None:
    run = run_vo(world_dir / "runs" / "good", world_dir / "calibration", tmp_path / "vo")
    states = [f.state for f in run.frames]
    assert states[0] == "INIT" and all(s == "OK" for s in states[1:])
    assert run.n_segments == 1 and (tmp_path / "vo" / "CameraTrajectory0.txt").is_file()
    assert min(f.n_map_matches for f in run.frames[1:]) >= 100
    m = evaluate_run(tmp_path / "vo", world_dir / "groundtruth.txt", tuple(float(w) for w in range(5, 9)))
    assert m["success"] and m["tracked_fraction"] == 1.0
    # Bound: noise-free 320x240 scene, fx 240 px, 0.18 m baseline -> disparity ~8.6 px at 5 m, so a 0.1 px
    # disparity error is a ~1.2 % depth (scale) error per frame; without bundle adjustment such errors accumulate.
    # Measured ~1.8 %; 5 % leaves margin yet is 4x below the paper's best ORB-SLAM2 RTE on field data (18.4 %).
    assert all(w["n_pairs"] > 0 for w in m["windows"])
    assert m["rte_pct"] < 5.0
    assert m["rre_deg_per_m"] < 1.0


def test_bench_vo_loses_track_on_saturation_and_reinitialises(world_dir: Path, tmp_path: Path) -> None:
    run = run_vo(world_dir / "runs" / "saturated", world_dir / "calibration", tmp_path / "vo")
    states = [f.state for f in run.frames]
    assert states[:10] == ["INIT"] + ["OK"] * 9
    assert states[10] == "LOST"  # reported on the first saturated frame
    assert all(s in ("LOST", "NO_INIT") for s in states[10:15])
    assert "INIT" in states[15:]  # back to a good exposure: a new segment starts
    assert run.n_segments == 2 and len(read_segments(tmp_path / "vo")) == 2
    rows = read_frames_csv(tmp_path / "vo" / "frames.csv")
    assert [r["state"] for r in rows] == states
    m = evaluate_run(tmp_path / "vo", None)
    assert not m["success"] and m["n_failures"] == 5
    assert m["time_before_failure_s"] == pytest.approx(10 / ToyWorld().fps, abs=1e-3)
    assert np.isnan(m["rte_pct"])


@pytest.mark.realdata
def test_bench_vo_on_real_sample_fixes_rows(borealhdr_sample: Path, borealhdr_sequence: Path, tmp_path: Path) -> None:
    """The sample's camera_info are not a rectified pair: rows disagree by ~15 px until corrected from matches."""
    import json
    import os

    run = tmp_path / "b8"
    for side in ("left", "right"):
        (run / f"images_{side}").mkdir(parents=True)
        for f in sorted((borealhdr_sequence / f"camera_{side}" / "8.0").glob("*.png")):
            os.symlink(f, run / f"images_{side}" / f.name)
    result = run_vo(run, borealhdr_sample / "calibration", tmp_path / "vo")
    info = json.loads((tmp_path / "vo" / "rectification.json").read_text())
    assert info["row_corrected"] and -20.0 < info["row_offset_px"] < -10.0 and info["row_matches"] >= 100
    assert all(f.tracked for f in result.frames)
    assert min(f.n_stereo for f in result.frames) > 400  # ~100 without the row correction
    assert min(f.coverage for f in result.frames) > 0.9
