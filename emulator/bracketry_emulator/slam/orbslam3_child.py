"""A SLAM run's child process (:func:`bracketry_emulator.slam.orbslam3.start_child`): ``python -m ... REQUEST.json``.

Reads the run's pairs (a run folder's PNGs, or the closed loop's images through ``frames_fifo``, a FIFO or a spool file,
see :mod:`.frame_stream`), rectifies them as the built-in VO does (same row correction), feeds ORB-SLAM3 at the
requested pace or in lockstep (each frame once ORB-SLAM3's own threads are idle, :mod:`.quiescence`) (or, ``backend:
builtin``, tracks them with the built-in VO), and writes ``frames.csv``, ``CameraTrajectory<n>.txt``, ``settings.yaml``
and, last, ``slam.json`` (its presence tells the parent the run finished). Exit code 0 on success, 1 with a one-line
message otherwise.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np


def _frames(request: dict) -> tuple[Iterator[tuple[int, np.ndarray, np.ndarray]], float | None]:
    """The run's stereo frames as (t_ns, left gray8, right gray8) and, from a run folder, its frame rate (a stream's
    comes with the request): from ``frames_fifo`` (a FIFO or a spool file of frame records, see :mod:`.frame_stream`) or
    ``run_dir`` (PNGs)."""
    from bracketry_emulator.vo.runner import png_frames, raw_to_gray8

    if request.get("frames_fifo"):
        from bracketry_emulator.slam.frame_stream import read_stream

        frames = raw_to_gray8(read_stream(request["frames_fifo"]))
        if request.get("preview_index") is not None:
            frames = _keep_preview(frames, int(request["preview_index"]), Path(request["out_dir"]) / PREVIEW_NAME)
        return frames, None
    n, frames = png_frames(request["run_dir"], max_frames=request.get("max_frames"))
    times = _times(request["run_dir"], n)
    span_s = (times[-1] - times[0]) * 1e-9
    fps = (len(times) - 1) / span_s if len(times) > 1 and span_s > 0 else 1.0
    return frames, fps


#: the left gray image of one frame (the run's middle one), kept when the run's images exist only in memory (the
#: report's qualitative figure)
PREVIEW_NAME = "preview_left.png"


def _keep_preview(frames: Iterator[tuple[int, np.ndarray, np.ndarray]], index: int, path: Path
                  ) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    import cv2

    for k, frame in enumerate(frames):
        if k == index:
            cv2.imwrite(str(path), frame[1])
        yield frame


def _times(run_dir: str, n: int) -> list[int]:
    from bracketry_emulator.vo.runner import list_side_images

    return [t for t, _ in list_side_images(run_dir, "left")][:n]


def _track_builtin(request: dict) -> dict:
    """The built-in VO over the run's frames (no pacing: it is deterministic)."""
    from bracketry_emulator.vo.runner import track_frames

    frames, _fps = _frames(request)
    t0 = time.perf_counter()
    vo = track_frames(frames, request["calibration_dir"], request["out_dir"], max_frames=request.get("max_frames"))
    return {"backend": "builtin", "n_frames": len(vo.frames),
            "s_per_frame": (time.perf_counter() - t0) / max(len(vo.frames), 1),
            "source": "stream" if request.get("frames_fifo") else "png"}


def _track(request: dict) -> dict:
    from bracketry_base.errors import BracketryError
    from bracketry_emulator.features.coverage import grid_coverage
    from bracketry_emulator.features.orb import OrbExtractor
    from bracketry_emulator.slam.orbslam3 import map_states
    from bracketry_emulator.slam.settings import OrbSlamCamera, camera_fps, settings_yaml
    from bracketry_emulator.trajectory_io import FRAME_FIELDS, write_tum
    from bracketry_emulator.vo.calibration import StereoRectifier
    from bracketry_emulator.vo.runner import estimate_row_offset

    opts = request["options"]
    out = Path(request["out_dir"])
    frames, fps_run = _frames(request)
    it = iter(frames)
    first = next(it, None)
    if first is None:
        raise BracketryError("no stereo frame to track")
    _t_first, first_l, first_r = first
    rect = StereoRectifier.from_dir(request["calibration_dir"], first_l.shape[1], first_l.shape[0])
    a, b, _n = estimate_row_offset(rect, first_l, first_r)
    if abs(a) + abs(b) * rect.width_px / 2 > 0.5:
        rect.correct_rows(a, b)
    fps = float(request["fps"]) if request.get("fps") else (fps_run or 1.0)
    cam = OrbSlamCamera(rect.fx, rect.fy, rect.cx, rect.cy, rect.baseline_m, rect.width_px, rect.height_px)
    settings_file = out / "settings.yaml"
    settings_file.write_text(settings_yaml(cam, fps, loop_closing=opts["loop_closing"], th_depth=opts["th_depth"]))

    import pyorbslam3

    from bracketry_emulator.slam.quiescence import LockstepStats, ThreadSampler, thread_ids, wait_idle

    own_threads = thread_ids()  # ours (and the frame reader's): every thread born after them is ORB-SLAM3's
    lockstep = bool(opts.get("lockstep"))
    waits = LockstepStats()
    sampler = ThreadSampler(own_threads)  # its descriptors stay open across the run's waits
    t_load = time.perf_counter()
    slam = pyorbslam3.Slam(opts["vocabulary"], str(settings_file), pyorbslam3.Sensor.STEREO)
    load_s = time.perf_counter() - t_load
    extractor = OrbExtractor()
    mask = rect.valid_mask()
    raw_states: list[str] = []
    poses: list[np.ndarray | None] = []
    kp: list[int] = []
    slam_kp: list[int] = []
    cov: list[float] = []
    matches: list[int] = []
    track_s: list[float] = []
    times_ns: list[int] = []
    pace = opts["pace_s"]
    max_frames = request.get("max_frames")
    late_s = 0.0
    t_start = time.perf_counter()
    for k, (t_ns, left_gray, right_gray) in enumerate(itertools.chain([first], it)):
        if max_frames and k >= max_frames:
            continue  # read to the end: the producer is not held up
        times_ns.append(t_ns)
        gl = rect.rectify(left_gray, "left")
        gr = rect.rectify(right_gray, "right")
        xy = extractor.detect_xy(gl, mask)  # our keypoints at the paper's settings: count and coverage only
        kp.append(len(xy))
        cov.append(grid_coverage(xy, gl.shape[1], gl.shape[0], 20))
        if lockstep and k == 0:  # each frame meets the map its predecessors left: ORB-SLAM3's own threads idle
            wait_idle(own_threads, waits, sample=sampler)
        elif not lockstep:
            due = t_start + ((t_ns - times_ns[0]) * 1e-9 if pace is None else k * float(pace))
            wait = due - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            else:
                late_s = max(late_s, -wait)
        t0 = time.perf_counter()
        res = slam.track_stereo(np.ascontiguousarray(gl), np.ascontiguousarray(gr), t_ns * 1e-9)
        track_s.append(time.perf_counter() - t0)
        name = res.state.name if hasattr(res.state, "name") else str(res.state).rsplit(".", 1)[-1]
        raw_states.append(name)
        slam_kp.append(len(slam.tracked_keypoints()))  # ORB-SLAM3's own keypoints in this frame (all, tracked or not)
        ok = name in ("OK", "OK_KLT") and bool(res.pose_valid)
        poses.append(np.asarray(res.pose_wc, np.float64).reshape(4, 4) if ok else None)
        # The tracked points still in the map: read while local mapping works on this frame's keyframe (it starts
        # at once and culls points) the count races it (574 or 573 for the same frame). In lockstep it is read
        # once that work is done (and the next frame meets the same map); else as the track call returns.
        if lockstep:
            wait_idle(own_threads, waits, sample=sampler)
        matches.append((len(slam.tracked_map_points()) if lockstep else int(res.num_tracked_points)) if ok else 0)
    slam.shutdown()
    sampler.close()
    states, segments = map_states([r if p is not None else "LOST" for r, p in zip(raw_states, poses)])
    with (out / "frames.csv").open("w") as fh:
        fh.write(",".join(FRAME_FIELDS) + "\n")
        for i, t_ns in enumerate(times_ns):
            reason = "" if states[i] != "LOST" else f"ORB-SLAM3 {raw_states[i]}"
            fh.write(f"{t_ns},{states[i]},{segments[i]},{kp[i]},{cov[i]:.6f},nan,nan,{matches[i]},{slam_kp[i]},{reason}\n")
    for seg in sorted({s for s in segments if s >= 0}):
        idx = [i for i, s in enumerate(segments) if s == seg]
        write_tum(out / f"CameraTrajectory{seg}.txt", [times_ns[i] * 1e-9 for i in idx],
                  [p for p in (poses[i] for i in idx) if p is not None])
    summary = {"backend": "orbslam3", "pyorbslam3": _version(), "vocabulary": opts["vocabulary"],
               "pace_s": pace, "lockstep": lockstep, "loop_closing": opts["loop_closing"],
               "settings": str(settings_file),
               "fps_settings": camera_fps(fps), "n_frames": len(times_ns), "vocabulary_load_s": load_s,
               "track_s_median": float(np.median(track_s)) if track_s else float("nan"),
               "track_s_mean": float(np.mean(track_s)) if track_s else float("nan"),
               "raw_states": {s: raw_states.count(s) for s in sorted(set(raw_states))},
               "max_late_s": late_s,
               **({"lockstep_wait_s": waits.wait_s, "lockstep_timeouts": waits.timeouts,
                   "lockstep_polls": waits.polls} if lockstep else {}),
               "source": "stream" if request.get("frames_fifo") else "png"}
    return summary


def _version() -> str:
    import importlib.metadata

    try:
        return importlib.metadata.version("pyorbslam3")
    except importlib.metadata.PackageNotFoundError:
        return "?"


def preload() -> None:
    """Import what a child imports, with its runtime profile applied in its order (the SLAM fork server,
    :mod:`.launcher`, calls this once before it forks children that run :func:`main`)."""
    import numpy  # noqa: F401

    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("slam_child")
    import bracketry_base.errors  # noqa: F401
    import bracketry_emulator.features.coverage
    import bracketry_emulator.features.orb
    import bracketry_emulator.slam.frame_stream
    import bracketry_emulator.slam.orbslam3
    import bracketry_emulator.slam.settings
    import bracketry_emulator.trajectory_io
    import bracketry_emulator.vo.calibration
    import bracketry_emulator.vo.runner  # noqa: F401

    with contextlib.suppress(ImportError):  # the built-in VO's runs need no ORB-SLAM3
        import pyorbslam3  # noqa: F401


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m bracketry_emulator.slam.orbslam3_child REQUEST.json", file=sys.stderr)
        return 2
    request = json.loads(Path(argv[0]).read_text())
    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("slam_child")
    try:
        summary = _track_builtin(request) if request.get("backend") == "builtin" else _track(request)
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
