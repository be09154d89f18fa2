"""The files a calibration is handed on in, as text and dicts (the caller writes them).

- ROS ``camera_info`` YAML per camera, in the layout BorealHDR ships (``narrow_stereo/left``, ``plumb_bob``, K, D,
  R the rectification rotation, P the rectified projection; the right camera's ``P[0, 3] = -fx' * baseline_m``);
- KITTI: the two rectified 3x4 projection matrices, one row each, then each camera's k1 k2 p1 p2 (as the sample's
  ``calib_kitti.txt``);
- the rectified pinhole camera ORB-SLAM3 stereo runs on (fx, fy, cx, cy of P1, the baseline).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml

from bracketry_base.calibration.solve import StereoSolution

SIDES = ("left", "right")


def _data(m: np.ndarray, decimals: int = 8) -> list[float]:
    return [round(float(x), decimals) for x in np.asarray(m, np.float64).ravel()]


def camera_info_fields(size: tuple[int, int], name: str, K: np.ndarray, D: np.ndarray, R: np.ndarray, P: np.ndarray,
                       decimals: int = 8) -> dict[str, Any]:
    """A ROS camera_info in BorealHDR's layout: ``size`` (width, height) px, ``camera_name``, K (3, 3), D (5,)
    plumb_bob, R (3, 3) rectification rotation, P (3, 4) rectified projection, numbers rounded to ``decimals``."""
    return {
        "image_width": int(size[0]),
        "image_height": int(size[1]),
        "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": _data(K, decimals)},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": _data(D, decimals)},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": _data(R, decimals)},
        "projection_matrix": {"rows": 3, "cols": 4, "data": _data(P, decimals)},
    }


def camera_info(sol: StereoSolution, side: str, name_prefix: str = "narrow_stereo") -> dict[str, Any]:
    """The ROS camera_info of ``side`` ("left" or "right")."""
    cam = sol.side(side)
    rect = sol.rectification
    R, P = (rect["R1"], rect["P1"]) if side == "left" else (rect["R2"], rect["P2"])
    return camera_info_fields(sol.size, f"{name_prefix}/{side}", cam.K, cam.D, R, P)


def camera_info_yaml(sol: StereoSolution, side: str) -> str:
    """The camera_info YAML text of ``side``."""
    return yaml.safe_dump(camera_info(sol, side), sort_keys=False, default_flow_style=None)


def kitti_text(sol: StereoSolution) -> str:
    """``calib_kitti.txt``: P1 and P2 (12 numbers a row), then k1 k2 p1 p2 of the left and of the right camera."""
    rows = [" ".join(f"{x:.8e}" for x in sol.rectification[k].ravel()) for k in ("P1", "P2")]
    rows += [" ".join(f"{x:.6f}" for x in sol.side(s).D[:4]) for s in SIDES]
    return "\n".join(rows) + "\n"


def rectified_camera(sol: StereoSolution) -> dict[str, float]:
    """The rectified pinhole pair: fx_px, fy_px, cx_px, cy_px (of P1) and baseline_m (``-P2[0,3] / P2[0,0]``)."""
    P1, P2 = sol.rectification["P1"], sol.rectification["P2"]
    return {"fx_px": float(P1[0, 0]), "fy_px": float(P1[1, 1]), "cx_px": float(P1[0, 2]), "cy_px": float(P1[1, 2]),
            "baseline_m": float(-P2[0, 3] / P2[0, 0])}


def report(sol: StereoSolution, n_views: int, solve_s: float) -> dict[str, Any]:
    """The solve's report (``report.json``): per-camera RMS, per-view errors, dropped views, the scheme, timing."""
    views = []
    for k in range(n_views):
        v: dict[str, Any] = {"view": k, "used": k in sol.used}
        for side in SIDES:
            e = sol.side(side).view_rms_px.get(k)
            v[f"{side}_rms_px"] = None if e is None else round(e, 4)
        e = sol.stereo_view_rms_px.get(k)
        v["stereo_rms_px"] = None if e is None else round(e, 4)
        views.append(v)
    return {
        "size_px": list(sol.size),
        "rms_px": {"left": round(sol.left.rms_px, 4), "right": round(sol.right.rms_px, 4),
                   "stereo": round(sol.stereo_rms_px, 4)},
        "baseline_m": round(sol.baseline_m, 6),
        "rectified": {k: round(v, 6) for k, v in rectified_camera(sol).items()},
        "views_used": {"left": len(sol.left.used), "right": len(sol.right.used), "stereo": len(sol.used)},
        "dropped": [{"view": d.view, "camera": d.camera, "reason": d.reason} for d in sol.dropped],
        "views": views,
        "scheme": sol.scheme,
        "solve_s": round(solve_s, 3),
    }
