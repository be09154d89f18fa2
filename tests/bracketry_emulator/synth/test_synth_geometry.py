"""Geometry of the synthetic world: ground-truth poses + written calibration reproduce what the renderer draws."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from bracketry_emulator.synth import World, write_trajectory
from bracketry_emulator.synth.trajectory import matrix_from_quat

W, H = 320, 200


@pytest.fixture(scope="module")
def world() -> World:
    return World("forest-winter", seed=3, resolution=(W, H))


@pytest.fixture(scope="module")
def walk(world: World, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("walk")
    write_trajectory(world, out, seconds=0.55, fps=22.0)
    return out


def _camera_info(path: Path) -> dict[str, np.ndarray]:
    info = yaml.safe_load(path.read_text())
    return {"K": np.array(info["camera_matrix"]["data"], float).reshape(3, 3),
            "D": np.array(info["distortion_coefficients"]["data"], float),
            "R": np.array(info["rectification_matrix"]["data"], float).reshape(3, 3),
            "P": np.array(info["projection_matrix"]["data"], float).reshape(3, 4)}


def _read_tum(path: Path) -> list[tuple[float, np.ndarray]]:
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        v = [float(x) for x in line.split()]
        T = np.eye(4)
        T[:3, :3] = matrix_from_quat(np.array(v[4:8]))
        T[:3, 3] = v[1:4]
        rows.append((v[0], T))
    return rows


def _surface_points(world: World, side: str, t_s: float, n: int, rng: np.random.Generator,
                    max_range_m: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """Random pixels whose 3-D point is known from the rendered range: pixels (n, 2), camera-frame points (n, 3)."""
    rng_map = world.radiance(side, t_s).range_m
    v, u = np.nonzero(np.isfinite(rng_map) & (rng_map < max_range_m))
    pick = rng.choice(len(u), size=n, replace=False)
    u, v = u[pick], v[pick]
    intr = world.calibration.side(side)
    xn, yn = intr.undistort(u.astype(float), v.astype(float))
    rays = np.stack([xn, yn, np.ones_like(xn)], 1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return np.stack([u, v], 1).astype(float), rays * rng_map[v, u][:, None]


def _check_lands(world: World, side: str, t_s: float, points_cam: np.ndarray, cal: dict[str, np.ndarray]) -> float:
    """Fraction of points that land on a pixel whose rendered range equals their distance (1.5 %)."""
    uv, _ = cv2.projectPoints(points_cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cal["K"], cal["D"])
    uv = uv.reshape(-1, 2)
    ui, vi = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H) & (points_cam[:, 2] > 0.1)
    rng_map = world.radiance(side, t_s).range_m
    dist = np.linalg.norm(points_cam, axis=1)
    ok = inside & (np.abs(rng_map[np.clip(vi, 0, H - 1), np.clip(ui, 0, W - 1)] - dist) < 0.015 * dist)
    assert inside.sum() > 50
    return float(ok.sum() / inside.sum())


def test_synth_point_reprojects_into_other_camera_and_time(world: World, walk: Path) -> None:
    """A surface point seen by the left camera, moved with the TUM ground truth and projected with the written
    camera_info, lands where the right camera (same time) and the left camera 0.5 s later draw that same point."""
    gt = _read_tum(walk / "groundtruth.txt")
    left = _camera_info(walk / "calibration" / "left.yaml")
    right = _camera_info(walk / "calibration" / "right.yaml")
    baseline_m = -right["P"][0, 3] / right["P"][0, 0]
    assert baseline_m == pytest.approx(0.18, abs=1e-4)
    rng = np.random.default_rng(0)
    # each ground-truth line is the pose at its frame's mid-exposure (frame 11: the 32 ms bracket, 16 ms after its
    # trigger; the backpack's gait turns at up to ~20 deg/s, so the render is taken at that instant too)
    t_a, T_a = World.mid_exposure_s(0.0, 1000.0), gt[0][1]
    k_b = 11
    t_b, T_b = World.mid_exposure_s(k_b / 22.0, 32000.0), gt[k_b][1]
    _, pts_a = _surface_points(world, "left", t_a, 400, rng)
    # right camera at the same time: a pure translation along the left camera's x axis
    frac_right = _check_lands(world, "right", t_a, pts_a - np.array([baseline_m, 0.0, 0.0]), right)
    # left camera at t_b, through the ground-truth poses
    pts_gt = pts_a @ T_a[:3, :3].T + T_a[:3, 3]
    T_inv = np.linalg.inv(T_b)
    pts_b = pts_gt @ T_inv[:3, :3].T + T_inv[:3, 3]
    frac_time = _check_lands(world, "left", t_b, pts_b, left)
    # points may be hidden in the other view (parallax around trunks): most must land exactly
    assert frac_right > 0.9
    assert frac_time > 0.85


def test_synth_world_points_project_where_the_renderer_draws_them(world: World) -> None:
    """Known scene geometry: the point of a tree trunk facing the camera at 1 m height is drawn at its projection."""
    t_s = 2.0
    R, p = world.world_pose(t_s, "left")
    cyl = world.scene.prims.cylinders
    checked = 0
    for x, y, r, h in cyl:
        to_cam = p[:2] - np.array([x, y])
        dist = np.linalg.norm(to_cam)
        if not 3.0 < dist < 15.0 or h < 2:
            continue
        pt_w = np.array([x, y, 1.0])
        pt_w[:2] += to_cam / dist * r
        pc = (pt_w - p) @ R
        if pc[2] < 0.5:
            continue
        u, v = world.calibration.left.project(pc[None])[0]
        if not (2 <= u < W - 2 and 2 <= v < H - 2):
            continue
        rng_map = world.radiance("left", t_s).range_m
        drawn = rng_map[round(v), round(u)]
        if drawn < np.linalg.norm(pc) - 0.05:
            continue  # hidden behind a nearer object
        assert drawn == pytest.approx(np.linalg.norm(pc), rel=0.02)
        checked += 1
    assert checked >= 3


def test_synth_stereo_disparity_matches_depth(world: World, walk: Path) -> None:
    """Rectified with the written calibration, the stereo images have disparity fx_rect * 0.18 / Z."""
    left = _camera_info(walk / "calibration" / "left.yaml")
    right = _camera_info(walk / "calibration" / "right.yaml")
    t_s = 0.0
    maps = {}
    for side, cal in (("left", left), ("right", right)):
        maps[side] = cv2.initUndistortRectifyMap(cal["K"], cal["D"], cal["R"], cal["P"], (W, H), cv2.CV_32FC1)
    imgs = {}
    for side in ("left", "right"):
        raw = world.render(side, t_s, 4000.0, noise=False)
        gray = cv2.cvtColor(raw, cv2.COLOR_BAYER_RG2GRAY).astype(np.float32)
        imgs[side] = cv2.remap(gray, *maps[side], cv2.INTER_LINEAR)
    rng_rect = cv2.remap(world.radiance("left", t_s).range_m, *maps["left"], cv2.INTER_NEAREST)
    P = left["P"]
    fx, cx, cy = P[0, 0], P[0, 2], P[1, 2]
    v, u = np.mgrid[0:H, 0:W].astype(float)
    xr, yr = (u - cx) / fx, (v - cy) / P[1, 1]
    Z = rng_rect / np.sqrt(xr * xr + yr * yr + 1.0)
    expected = fx * 0.18 / Z
    to8 = {s: np.clip(imgs[s] / 16.0, 0, 255).astype(np.uint8) for s in imgs}
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=32, blockSize=5, P1=8 * 25, P2=32 * 25,
                                 uniquenessRatio=10, mode=cv2.STEREO_SGBM_MODE_HH)
    disp = sgbm.compute(to8["left"], to8["right"]).astype(np.float32) / 16.0
    valid = (disp > 0.5) & np.isfinite(Z) & (Z > 1.5) & (Z < 20.0)
    valid[:, :40] = False
    assert valid.sum() > 2000
    err = disp[valid] - expected[valid]
    assert abs(float(np.median(err))) < 0.3
    assert float(np.mean(np.abs(err) < 1.0)) > 0.8


def test_synth_poses_follow_requested_speed() -> None:
    for speed_kmh in (2.0, 4.0):
        from bracketry_emulator.synth import LoopTrajectory

        traj = LoopTrajectory(speed_kmh=speed_kmh)
        t = np.arange(0.0, 20.0, 1.0 / 22.0)
        pos = np.array([traj.pose(ti)[1] for ti in t])
        # average over whole strides removes the gait sway from the speed estimate
        stride_s = 2.0 / traj.step_hz
        n = round(stride_s * 22.0 * 8)
        speed = np.linalg.norm(pos[n] - pos[0]) / t[n]
        path = np.sum(np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)) / t[-1]
        assert path == pytest.approx(speed_kmh / 3.6, rel=0.05)
        assert speed == pytest.approx(speed_kmh / 3.6, rel=0.1)


def test_synth_gait_bounce_and_roll(world: World) -> None:
    t = np.arange(0.0, 6.0, 0.01)
    T = [world.pose(ti) for ti in t]
    heights = np.array([world.world_pose(ti)[1][2] for ti in t])
    # the backpack's gait (LoopTrajectory's defaults): +-2.5 cm bounce, +-2 degrees of roll
    assert 0.04 < np.ptp(heights) < 0.06
    # roll: angle of the camera x axis out of the horizontal plane (scene frame)
    roll = np.degrees(np.array([np.arcsin(world.world_pose(ti)[0][2, 0]) for ti in t]))
    assert 3.0 < np.ptp(roll) < 5.0
    assert np.allclose(T[0], np.eye(4))


def test_synth_loop_is_closed(world: World) -> None:
    tr = world.trajectory
    period_s = tr.length_m / tr.speed_mps
    _R0, p0 = tr.pose(0.0)
    # the gait phase differs after one loop; the centre line is closed
    _R1, p1 = tr.pose(period_s)
    assert np.linalg.norm(p1[:2] - p0[:2]) < 0.05


def test_synth_campus_buildings_and_crowns_reproject() -> None:
    """Boxes (buildings) and spheres (tree crowns) of the campus world obey the same geometry."""
    world = World("campus-summer", seed=5, resolution=(W, H))
    rng = np.random.default_rng(1)
    right = {"K": world.calibration.right.K, "D": world.calibration.right.D}
    fracs = []
    for t_s in (0.0, 30.0, 70.0):
        _, pts = _surface_points(world, "left", t_s, 300, rng, max_range_m=60.0)
        fracs.append(_check_lands(world, "right", t_s, pts - np.array([0.18, 0.0, 0.0]), right))
    assert min(fracs) > 0.9
    # the views do contain buildings and crowns
    res = world.radiance("left", 30.0)
    assert np.isfinite(res.range_m).mean() > 0.5
