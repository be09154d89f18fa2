"""Child process of :func:`bracketry_emulator.slam.orbslam3.run_orbslam3`: ``python -m ... REQUEST.json``.

Reads the run's pairs, rectifies them as the built-in VO does (same row correction), feeds ORB-SLAM3 at the requested
pace, and writes ``frames.csv``, ``CameraTrajectory<n>.txt``, ``settings.yaml`` and, last, ``slam.json`` (its
presence tells the parent the run finished). Exit code 0 on success, 1 with a one-line message otherwise.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _track(request: dict) -> dict:
    import cv2

    from bracketry.errors import BracketryError
    from bracketry_emulator.features.coverage import grid_coverage
    from bracketry_emulator.features.orb import OrbExtractor
    from bracketry_emulator.slam.orbslam3 import map_states
    from bracketry_emulator.slam.settings import OrbSlamCamera, settings_yaml
    from bracketry_emulator.vo.calibration import StereoRectifier
    from bracketry_emulator.vo.runner import FRAME_FIELDS, estimate_row_offset, list_side_images, read_gray8
    from bracketry_emulator.vo.tum import write_tum

    cv2.setNumThreads(1)
    opts = request["options"]
    out = Path(request["out_dir"])
    left = list_side_images(request["run_dir"], "left")
    right = list_side_images(request["run_dir"], "right")
    if not left or len(left) != len(right):
        raise BracketryError(f"{request['run_dir']}: {len(left)} left and {len(right)} right images")
    if request.get("max_frames"):
        left, right = left[:request["max_frames"]], right[:request["max_frames"]]
    first_l, first_r = read_gray8(left[0][1]), read_gray8(right[0][1])
    rect = StereoRectifier.from_dir(request["calibration_dir"], first_l.shape[1], first_l.shape[0])
    a, b, _n = estimate_row_offset(rect, first_l, first_r)
    if abs(a) + abs(b) * rect.width_px / 2 > 0.5:
        rect.correct_rows(a, b)
    times_ns = [t for t, _ in left]
    span_s = (times_ns[-1] - times_ns[0]) * 1e-9
    fps = (len(times_ns) - 1) / span_s if len(times_ns) > 1 and span_s > 0 else 1.0
    cam = OrbSlamCamera(rect.fx, rect.fy, rect.cx, rect.cy, rect.baseline_m, rect.width_px, rect.height_px)
    settings_file = out / "settings.yaml"
    settings_file.write_text(settings_yaml(cam, fps, loop_closing=opts["loop_closing"], th_depth=opts["th_depth"]))

    import pyorbslam3

    t_load = time.perf_counter()
    slam = pyorbslam3.Slam(opts["vocabulary"], str(settings_file), pyorbslam3.Sensor.STEREO)
    load_s = time.perf_counter() - t_load
    extractor = OrbExtractor()
    mask = rect.valid_mask()
    raw_states: list[str] = []
    poses: list[np.ndarray | None] = []
    kp: list[int] = []
    cov: list[float] = []
    matches: list[int] = []
    track_s: list[float] = []
    pace = opts["pace_s"]
    t_start = time.perf_counter()
    for k, ((t_ns, pl), (_tr, pr)) in enumerate(zip(left, right)):
        gl = rect.rectify(read_gray8(pl), "left")
        gr = rect.rectify(read_gray8(pr), "right")
        feats = extractor.detect_and_compute(gl, mask)
        kp.append(len(feats))
        cov.append(grid_coverage(feats.xy_px, feats.width_px, feats.height_px, 20))
        due = t_start + ((t_ns - times_ns[0]) * 1e-9 if pace is None else k * float(pace))
        wait = due - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        t0 = time.perf_counter()
        res = slam.track_stereo(np.ascontiguousarray(gl), np.ascontiguousarray(gr), t_ns * 1e-9)
        track_s.append(time.perf_counter() - t0)
        name = res.state.name if hasattr(res.state, "name") else str(res.state).rsplit(".", 1)[-1]
        raw_states.append(name)
        ok = name in ("OK", "OK_KLT") and bool(res.pose_valid)
        poses.append(np.asarray(res.pose_wc, np.float64).reshape(4, 4) if ok else None)
        matches.append(len(slam.tracked_map_points()) if ok else 0)
    slam.shutdown()
    states, segments = map_states([r if p is not None else "LOST" for r, p in zip(raw_states, poses)])
    with (out / "frames.csv").open("w") as fh:
        fh.write(",".join(FRAME_FIELDS) + "\n")
        for i, t_ns in enumerate(times_ns):
            reason = "" if states[i] != "LOST" else f"ORB-SLAM3 {raw_states[i]}"
            fh.write(f"{t_ns},{states[i]},{segments[i]},{kp[i]},{cov[i]:.6f},nan,nan,{matches[i]},{reason}\n")
    for seg in sorted({s for s in segments if s >= 0}):
        idx = [i for i, s in enumerate(segments) if s == seg]
        write_tum(out / f"CameraTrajectory{seg}.txt", [times_ns[i] * 1e-9 for i in idx],
                  [p for p in (poses[i] for i in idx) if p is not None])
    summary = {"backend": "orbslam3", "pyorbslam3": _version(), "vocabulary": opts["vocabulary"],
               "pace_s": pace, "loop_closing": opts["loop_closing"], "settings": str(settings_file),
               "fps_settings": max(1, round(fps)), "n_frames": len(times_ns), "vocabulary_load_s": load_s,
               "track_s_median": float(np.median(track_s)) if track_s else float("nan"),
               "track_s_mean": float(np.mean(track_s)) if track_s else float("nan"),
               "raw_states": {s: raw_states.count(s) for s in sorted(set(raw_states))}}
    return summary


def _version() -> str:
    import importlib.metadata

    try:
        return importlib.metadata.version("pyorbslam3")
    except importlib.metadata.PackageNotFoundError:
        return "?"


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m bracketry_emulator.slam.orbslam3_child REQUEST.json", file=sys.stderr)
        return 2
    request = json.loads(Path(argv[0]).read_text())
    try:
        summary = _track(request)
    except Exception as exc:  # one line for the parent's report; the C++ side printed its own story above
        print(f"error: {type(exc).__name__}: {exc}".replace("\n", " "), file=sys.stderr, flush=True)
        return 1
    out = Path(request["out_dir"])
    tmp = out / ".slam.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1))
    tmp.replace(out / "slam.json")
    return 0


if __name__ == "__main__":
    rc = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(rc)  # no interpreter teardown: ORB-SLAM3's static destructors have crashed after a finished run
