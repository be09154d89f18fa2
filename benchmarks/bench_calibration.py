"""Stereo calibration against the known truth: rendered board sessions (``bracketry synth calibration``'s
renderer) solved by ``bracketry_base.calibration`` (what ``bracketry calibrate solve`` runs), recovered vs true.

Usage: .venv/bin/python benchmarks/bench_calibration.py [--resolution 640x400] [--seeds 0,1,2,3,4] [--views 40]
       [--baseline-m 0.18]

Per seed: the worst focal error of the four (fx, fy of both cameras, %), the worst principal-point error (px), the
baseline error (%), the per-camera and stereo RMS (px), the views used / dropped, and the CPU time of the detection
and of the solve (``time.process_time``; rendering excluded). Then the medians over seeds and the worst case.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / d) for d in ("host", "emulator")]

from bracketry_base.calibration.board import BoardSpec  # noqa: E402
from bracketry_base.calibration.camera_info import rectified_camera  # noqa: E402
from bracketry_base.calibration.detect import detect, to_gray8  # noqa: E402
from bracketry_base.calibration.solve import solve_stereo  # noqa: E402
from bracketry_base.options import parse_resolution  # noqa: E402
from bracketry_emulator.synth.board_session import render_session  # noqa: E402
from bracketry_emulator.synth.calibration import default_calibration  # noqa: E402


def one(seed: int, size: tuple[int, int], n_views: int, baseline_m: float) -> dict[str, float]:
    calib = default_calibration(*size, baseline_m=baseline_m)
    board = BoardSpec()
    _views, frames = render_session(board, calib, seed, n_views)
    t0 = time.process_time()
    left = [detect(to_gray8(a), board) for a, _b in frames]
    right = [detect(to_gray8(b), board) for _a, b in frames]
    t1 = time.process_time()
    sol = solve_stereo(left, right, board, size, seed=0)
    t2 = time.process_time()
    focal = max(abs(sol.side(s).K[i, i] / (calib.side(s).fx, calib.side(s).fy)[i] - 1) * 100
                for s in ("left", "right") for i in (0, 1))
    pp = max(abs(sol.side(s).K[i, 2] - (calib.side(s).cx, calib.side(s).cy)[i]) for s in ("left", "right")
             for i in (0, 1))
    base = rectified_camera(sol)["baseline_m"]
    row = {"seed": seed, "focal_err_pct": focal, "pp_err_px": pp, "baseline_err_pct": (base / baseline_m - 1) * 100,
           "rms_left_px": sol.left.rms_px, "rms_right_px": sol.right.rms_px, "rms_stereo_px": sol.stereo_rms_px,
           "views_used": len(sol.used), "views_dropped": n_views - len(sol.used), "detect_cpu_s": t1 - t0,
           "solve_cpu_s": t2 - t1,
           "fx_left_true": calib.left.fx, "fx_left": sol.left.K[0, 0], "cx_left_true": calib.left.cx,
           "cx_left": sol.left.K[0, 2], "k1_left_true": calib.left.dist[0], "k1_left": sol.left.D[0]}
    print("  ".join(f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()), flush=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--resolution", default="640x400")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--baseline-m", type=float, default=0.18)
    a = ap.parse_args()
    size = parse_resolution(a.resolution)
    rows = [one(int(s), size, a.views, a.baseline_m) for s in a.seeds.split(",")]
    print(f"{a.resolution}, {a.views} views, {len(rows)} seeds, load {os.getloadavg()[0]:.1f}: median (worst)")
    for key in ("focal_err_pct", "pp_err_px", "baseline_err_pct", "rms_stereo_px", "views_used", "detect_cpu_s",
                "solve_cpu_s"):
        vals = [r[key] for r in rows]
        worst = max(vals, key=abs)
        print(f"  {key:18s} {statistics.median(vals):9.4f}  ({worst:.4f})")


if __name__ == "__main__":
    main()
