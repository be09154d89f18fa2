"""The rendered board session (``bracketry synth calibration``): its files, and corners where the true camera puts
them."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from bracketry.cli import main
from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.detect import detect, to_gray8
from bracketry_emulator.synth.board_session import BoardRenderer, background_field, random_views
from bracketry_emulator.synth.calibration import default_calibration, load_calibration
from bracketry_emulator.vo.calibration import StereoRectifier


def test_rendered_corners_lie_where_the_true_camera_projects_them() -> None:
    """Corners detected in rendered views are the board's corners projected through the true distorted camera
    (median error well under a pixel; a renderer off by a pixel convention or a distortion sign fails)."""
    calib = default_calibration(640, 400)
    board = BoardSpec()
    rng = np.random.default_rng(5)
    views = [v for v in random_views(board, calib.left, 8, rng, heavy_blur=0, blur_frac=0, partial_frac=0)]
    renderer = BoardRenderer(board, calib)
    errors = []
    for view in views:
        bg = background_field(640, 400, rng)
        for side in ("left", "right"):
            det = detect(to_gray8(renderer.render(side, view, bg, rng)), board)
            if det is None:
                continue
            pts = (view.R_cb @ board.object_points()[det.ids].T.astype(np.float64)).T + view.t_cb
            pts -= calib.offset_m(side)
            errors.append(np.linalg.norm(det.corners_px - calib.side(side).project(pts), axis=1))
    e = np.concatenate(errors)
    assert len(errors) >= 10
    assert np.median(e) < 0.15 and np.percentile(e, 95) < 0.6, (np.median(e), np.percentile(e, 95))


def test_synth_calibration_writes_the_session_and_its_truth(tmp_path: Path) -> None:
    out = tmp_path / "cal"
    assert main(["synth", "calibration", "--out", str(out), "--seed", "4", "--views", "6", "--resolution", "320x200",
                 "--baseline-m", "0.12", "-q"]) == 0
    lefts, rights = sorted((out / "left").glob("*.png")), sorted((out / "right").glob("*.png"))
    assert [p.name for p in lefts] == [p.name for p in rights] and len(lefts) == 6
    img = cv2.imread(str(lefts[0]), cv2.IMREAD_UNCHANGED)
    assert img.shape == (200, 320) and img.dtype == np.uint16 and img.max() <= 4094
    assert BoardSpec.from_dict(yaml.safe_load((out / "board.yaml").read_text())) == BoardSpec()
    truth = load_calibration(out / "truth", 320, 200)
    want = default_calibration(320, 200)
    assert truth.left.fx == pytest.approx(want.left.fx, rel=1e-6)
    assert truth.right.dist == pytest.approx(want.right.dist, abs=1e-6)
    rect = StereoRectifier.from_dir(out / "truth")
    assert rect.baseline_m == pytest.approx(0.12, rel=1e-5)  # P[0,3] = -fx' * baseline, as ROS writes it
    # the same seed renders the same session; nothing is overwritten without --overwrite
    again = tmp_path / "again"
    assert main(["synth", "calibration", "--out", str(again), "--seed", "4", "--views", "6", "--resolution",
                 "320x200", "--baseline-m", "0.12", "-q"]) == 0
    assert (again / "right" / rights[-1].name).read_bytes() == rights[-1].read_bytes()
    assert main(["synth", "calibration", "--out", str(out), "--views", "6", "-q"]) == 2
