"""Choosing calibration views while capturing (#35 item 1): the coverage core (ROS camera_calibration's bars),
the capture command over a rendered session, and the monitor's endpoint."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bracketry.cli import main
from bracketry.testing.http import http_json
from bracketry_base.calibration.board import BoardSpec
from bracketry_base.calibration.coverage import MAX_VIEWS_ENOUGH, MIN_DISTANCE, MIN_VIEWS_ENOUGH, Coverage, view_params
from bracketry_base.calibration.detect import Detection
from bracketry_emulator.synth.board_session import write_board_session
from bracketry_emulator.synth.calibration import default_calibration
from bracketry_rig.monitor.calibration_feed import CaptureFeed
from bracketry_rig.monitor.hub import PreviewHub
from bracketry_rig.monitor.server import MonitorServer

SIZE = (640, 400)


def _view(board: BoardSpec, centre: tuple[float, float], side_px: float, shear: float = 0.0,
          blur_px: float = 1.0, ids: np.ndarray | None = None) -> Detection:
    """A fronto-parallel (or sheared) board of ``side_px`` px per square centred at ``centre`` (px)."""
    obj = board.object_points()[:, :2] / board.square_m
    obj = obj - obj.mean(axis=0)
    pts = np.stack([obj[:, 0] + shear * obj[:, 1], obj[:, 1]], axis=1) * side_px + centre
    keep = np.arange(board.n_corners) if ids is None else ids
    return Detection(keep.astype(np.int32), pts[keep].astype(np.float32), blur_px)


def test_view_parameters_are_ros_camera_calibrations() -> None:
    board = BoardSpec()
    x, y, size, skew = view_params(board, _view(board, (320, 200), 20), SIZE)
    assert x == pytest.approx(0.5, abs=1e-6) and y == pytest.approx(0.5, abs=1e-6) and skew == pytest.approx(0)
    assert size == pytest.approx(np.sqrt(6 * 20 * 4 * 20 / (640 * 400)), rel=1e-6)  # 7x5 corners: 6x4 squares
    left = view_params(board, _view(board, (100, 200), 20), SIZE)
    assert left[0] < 0.2 and view_params(board, _view(board, (320, 200), 20, shear=0.5), SIZE)[3] > 0.5
    # a partial view: the outer corners come through the homography of what was seen
    part = view_params(board, _view(board, (320, 200), 20, ids=np.arange(14)), SIZE)
    assert part[2] == pytest.approx(size, rel=1e-4)


def test_the_capture_keeps_new_sharp_views_seen_by_both_and_says_when_enough() -> None:
    board = BoardSpec()
    cov = Coverage(board, SIZE)
    centre = _view(board, (320, 200), 20)
    assert cov.offer(centre, None) == (False, "board not found (right)")
    assert not cov.offer(centre, _view(board, (320, 200), 20, blur_px=4.0))[0]
    assert cov.offer(centre, centre) == (True, "new view")
    ok, why = cov.offer(_view(board, (322, 201), 20), centre)
    assert not ok and "too close" in why and f"{MIN_DISTANCE:g}" in why
    assert not cov.enough and cov.bars()["x"] == 0.0
    # a sweep over the image, near and far, tilted: every bar fills and the set is enough
    for cx in (120, 320, 520):
        for cy in (110, 200, 290):
            for side_px, shear in ((12, 0.0), (45, 0.0), (18, 0.6), (24, -0.6)):
                v = _view(board, (cx, cy), side_px, shear)
                cov.offer(v, v)
    bars = cov.bars()
    assert all(b == 1.0 for b in bars.values()), bars
    assert len(cov.kept) >= MIN_VIEWS_ENOUGH
    assert cov.enough and cov.status()["advice"].startswith("enough")
    # full bars from fewer views than the minimum (picked greedily, each adding the most coverage): keep going
    few = Coverage(board, SIZE, kept=[])
    while not all(b == 1.0 for b in few.bars().values()):
        few.kept.append(max(cov.kept, key=lambda v: sum(Coverage(board, SIZE, kept=[*few.kept, v]).bars().values())))
    assert len(few.kept) < MIN_VIEWS_ENOUGH
    assert not few.enough and few.status()["advice"].startswith("keep going")
    many = Coverage(board, SIZE)
    many.kept = [(0.5, 0.5, 0.1, 0.0)] * MAX_VIEWS_ENOUGH
    assert many.enough and many.bars()["x"] == 0.0  # as ROS: 40 views are enough whatever they cover


def test_capture_command_selects_views_that_solve(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    write_board_session(src, BoardSpec(), default_calibration(*SIZE), 21, 30)
    out = tmp_path / "kept"
    rc = main(["calibrate", "capture", "--from", str(src), "--out", str(out), "-q"])
    rep = json.loads((out / "capture.json").read_text())
    kept = sorted(p.name for p in (out / "left").glob("*.png"))
    assert kept == sorted(p["pair"] for p in rep["pairs"] if p["kept"]) == sorted(p.name for p in
                                                                              (out / "right").glob("*.png"))
    assert rc == (0 if rep["enough"] else 1) and rep["kept"] == len(kept) >= 10
    spoilt = {f"{k:06d}.png" for k, v in enumerate(json.loads((src / "session.json").read_text())["views"])
              if v["blur_len_px"] >= 10}
    assert spoilt and not spoilt & set(kept)
    assert main(["calibrate", "solve", str(out), "--out", str(tmp_path / "cal"), "-q"]) == 0


def test_monitor_serves_the_capture_state(tmp_path: Path) -> None:
    board = BoardSpec()
    feed = CaptureFeed(board, SIZE)
    server = MonitorServer(_NoRig(), PreviewHub(), "127.0.0.1", 0, calibration=feed).start()
    try:
        base = f"http://127.0.0.1:{server.port}"
        assert http_json(base + "/api/calibration")[1]["kept"] == 0
        grey = np.full((400, 640), 128, np.uint8)
        v = _view(board, (320, 200), 20)
        feed.offer((grey, grey), (v, v))
        code, st = http_json(base + "/api/calibration")
        assert code == 200
        assert st["active"] and st["kept"] == 1 and st["last"]["kept"] and len(st["last"]["corners"]["left"]) == 35
        assert st["last"]["corners"]["left"][0] == pytest.approx(list(v.corners_px[0] / SIZE), abs=1e-4)
        assert set(st["bars"]) == {"x", "y", "size", "skew"} and st["enough"] is False
    finally:
        server.close()
    plain = MonitorServer(_NoRig(), PreviewHub(), "127.0.0.1", 0).start()
    try:
        assert http_json(f"http://127.0.0.1:{plain.port}/api/calibration") == (200, {"active": False})
    finally:
        plain.close()


class _NoRig:
    def monitor_status(self) -> dict:
        return {}

    def monitor_action(self, action: str, body: dict) -> dict:
        return {}

    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        return (), 1, 1


def test_a_recording_exported_as_a_borealhdr_tree_gives_the_same_pairs(tmp_path: Path) -> None:
    """``calibrate solve`` / ``capture`` read a board session folder or an exported recording (camera_left/<exp>/,
    camera_right/<exp>/ named by each camera's own stamps): the k-th images of the two sides are a pair."""
    from bracketry_rig.boardcapture.files import image_pairs

    for side in ("left", "right"):
        (tmp_path / "s" / side).mkdir(parents=True)
        (tmp_path / "t" / f"camera_{side}" / "1.0").mkdir(parents=True)
        for k in range(3):
            (tmp_path / "s" / side / f"{k:06d}.png").write_bytes(b"")
            stamp = 1_700_000_000_000_000_000 + k * 45_000_000 + (7 if side == "right" else 0)
            (tmp_path / "t" / f"camera_{side}" / "1.0" / f"{stamp}.png").write_bytes(b"")
    folder = [(a.name, b.name) for a, b in image_pairs(tmp_path / "s")]
    tree = image_pairs(tmp_path / "t")
    assert folder == [(f"{k:06d}.png",) * 2 for k in range(3)]
    assert [(a.parent.parent.name, b.parent.parent.name) for a, b in tree] == [("camera_left", "camera_right")] * 3
    assert [int(b.stem) - int(a.stem) for a, b in tree] == [7, 7, 7]
    tree[0][1].unlink()
    with pytest.raises(Exception, match="give image pairs"):
        image_pairs(tmp_path / "t")
