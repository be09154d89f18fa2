"""Can ORB-SLAM3 track at all with this vocabulary and calibration? Checked before the AE methods run.

A broken set-up (a vocabulary that loads but does not work, left and right cameras swapped, a calibration that does
not rectify the pair) makes every run lose track on its first frames, and the report would then say that every AE
method "failed at 0.3 s". So before the methods run, ORB-SLAM3 tracks images straight from the dataset, without any
AE method: the middle bracket (the median exposure of the bracket set, fixed), left and right, over the first
:data:`SETUP_SECONDS` seconds of a trajectory, unpaced, in a child process like every run (loop closing on, as in
the runs: ORB-SLAM3 1.0 with ``loopClosing: 0`` crashes with SIGSEGV right after creating its first map on some
trajectories, e.g. the VO tests' toy corridor).

Criterion: the set-up passes when ORB-SLAM3 holds tracking (state OK) for :data:`MIN_TRACKED_FRAMES` consecutive
frames (all of them when the window is shorter) anywhere in that window. Stereo initialisation alone is not enough:
ORB-SLAM3 reports OK on its first frame even when no stereo point was triangulated (swapped cameras) or when the
vocabulary is empty, and loses track on the next. The scene is not judged: the trajectories are tried in
decreasing order of texture (ORB keypoints of the window's middle left image) and the first that passes is enough,
at most :data:`MAX_TRIED` of them, so one hard trajectory (glare, darkness) cannot fail a good set-up.

A trajectory without bracket images (a dataset holding emulated runs only) is tried on one of its runs instead.
When no trajectory passes, :class:`SetupCheckError` is one line naming the likely cause, from what the try showed:
the vocabulary (ORB-SLAM3 refused it), the calibration (few stereo matches on the rectified pair, or most of them
with negative disparity: the cameras look swapped), else both. Cost: one ORB-SLAM3 run of about a dozen frames
(a second or two of CPU at 320x240; the vocabulary load dominates with ORBvoc.txt).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

#: seconds of the trajectory the check tracks (from its start)
SETUP_SECONDS = 4.0
#: consecutive tracked frames the set-up must reach in that window
MIN_TRACKED_FRAMES = 5
#: trajectories tried at most (most textured first)
MAX_TRIED = 3
#: fewer same-row stereo matches than this on the rectified pair of a textured image point at the calibration
MIN_STEREO_MATCHES = 30
#: a "textured" image: at least this many ORB keypoints (paper settings) in the left image
MIN_TEXTURE = 300
#: ORB-SLAM3's distance over the tracked frames may differ from the reference's by this factor either way
MAX_SCALE_RATIO = 1.5
#: the scale is judged only when the reference moved at least this far over those frames (metres)
MIN_REFERENCE_M = 0.5


@dataclass(frozen=True)
class Trajectory:
    """A trajectory to check: its dataset folder, calibration folder, an existing emulated run (used when the
    dataset has no bracket images) and its reference (TUM, left camera; None when it has none)."""

    name: str
    path: Path
    calibration_dir: Path | None
    run_dir: Path | None = None
    reference: Path | None = None


class SetupCheckError(BracketryError):
    """ORB-SLAM3 cannot track with this vocabulary and calibration (one line; exit code 2)."""


@dataclass
class Candidate:
    """One trajectory's check input: stereo frames (t_ns, left, right raw uint16 mosaics) or a run folder."""

    name: str
    calibration_dir: Path
    frames: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    fps: float = 1.0
    run_dir: Path | None = None
    max_frames: int | None = None
    what: str = ""
    texture: int = 0
    reference: Path | None = None


@dataclass
class SetupCheckResult:
    """The trajectory that passed, its longest tracked stretch (frames of how many), the CPU seconds it took."""

    trajectory: str
    what: str
    longest_tracked: int
    n_frames: int
    cpu_s: float
    wall_s: float
    tried: list[str]


def middle_bracket_frames(dataset_path: str | Path, seconds: float = SETUP_SECONDS
                          ) -> tuple[list[tuple[int, np.ndarray, np.ndarray]], float, int]:
    """The middle bracket's stereo frames (t_ns, left, right: uint16 raw mosaics, straight from the dataset) of the
    first ``seconds``, their rate (frames per second) and the exposure (us)."""
    from bracketry_emulator.dataset import open_dataset

    ds = open_dataset(dataset_path)
    if "left" not in ds.sides or "right" not in ds.sides:
        raise BracketryError(f"{dataset_path}: the set-up check needs left and right images")
    seqs = ds.sequences()
    exposure = ds.exposures_us[len(ds.exposures_us) // 2]
    t0 = seqs[0].timestamps_ns["left"][exposure]
    chosen = [s for s in seqs if s.timestamps_ns["left"][exposure] - t0 <= seconds * 1e9]
    frames = [(int(s.timestamps_ns["left"][exposure]), s.frames["left"][exposure].load(),
               s.frames["right"][exposure].load()) for s in chosen]
    span_s = (frames[-1][0] - frames[0][0]) * 1e-9
    fps = (len(frames) - 1) / span_s if len(frames) > 1 and span_s > 0 else 1.0
    return frames, fps, int(exposure)


def _texture(gray8: np.ndarray) -> int:
    from bracketry_emulator.features.orb import OrbExtractor

    return len(OrbExtractor().detect_xy(gray8))


def candidates(trajectories: list[Trajectory], seconds: float = SETUP_SECONDS) -> list[Candidate]:
    """Check inputs of ``trajectories``, most textured first; trajectories without calibration are left out (the
    benchmark refuses them itself)."""
    from bracketry_emulator.features.demosaic import to_gray8
    from bracketry_emulator.vo.runner import list_side_images, read_gray8

    out = []
    for tr in trajectories:
        name, path, calib, run = tr.name, tr.path, tr.calibration_dir, tr.run_dir
        if calib is None:
            continue
        try:
            frames, fps, exposure = middle_bracket_frames(path, seconds)
        except BracketryError:
            frames = []
        if frames:
            mid = frames[len(frames) // 2][1]
            out.append(Candidate(name, calib, frames, fps, what=f"middle bracket ({exposure / 1000:g} ms)",
                                 texture=_texture(to_gray8(mid, bayer=True)), reference=tr.reference))
            continue
        if run is None:
            continue
        try:
            times = [t for t, _ in list_side_images(run, "left")]
        except BracketryError:
            continue
        if len(times) < 2:
            continue
        n = sum(1 for t in times if t - times[0] <= seconds * 1e9)
        mid_path = list_side_images(run, "left")[n // 2][1]
        try:
            texture = _texture(read_gray8(mid_path, True))
        except Exception:  # an unreadable image: that run's own failure, not the set-up's
            continue
        out.append(Candidate(name, calib, run_dir=run, max_frames=n, what=f"run {run.name}", texture=texture,
                             reference=tr.reference))
    out.sort(key=lambda c: -c.texture)
    return out


def longest_tracked(states: list[str]) -> int:
    """The longest stretch of consecutive tracked frames (our states INIT/OK) in a run's per-frame states."""
    best = cur = 0
    for s in states:
        cur = cur + 1 if s in ("INIT", "OK") else 0
        best = max(best, cur)
    return best


def stereo_evidence(calibration_dir: Path, left: np.ndarray, right: np.ndarray) -> tuple[int, float]:
    """On one rectified pair (gray8; rows corrected as the SLAM child does): (ORB matches on the same row within
    2 px, the fraction of them with positive disparity). A good calibration gives hundreds on a textured image,
    nearly all positive; swapped cameras or a wrong calibration give a handful, or mostly negative ones."""
    import cv2

    from bracketry_emulator.features.orb import OrbExtractor
    from bracketry_emulator.vo.calibration import StereoRectifier
    from bracketry_emulator.vo.runner import estimate_row_offset

    rect = StereoRectifier.from_dir(calibration_dir, left.shape[1], left.shape[0])
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # few matches: the estimate says (0, 0)
        a, b, _n = estimate_row_offset(rect, left, right)  # as the SLAM child does before tracking
    if abs(a) + abs(b) * rect.width_px / 2 > 0.5:
        rect.correct_rows(a, b)
    ex = OrbExtractor()
    mask = rect.valid_mask()
    fl = ex.detect_and_compute(rect.rectify(left, "left"), mask)
    fr = ex.detect_and_compute(rect.rectify(right, "right"), mask)
    if len(fl) < 2 or len(fr) < 2:
        return 0, 0.0
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(fl.descriptors, fr.descriptors, k=2)
    pairs = [(p[0].queryIdx, p[0].trainIdx) for p in knn
             if len(p) == 2 and p[0].distance < 50 and p[0].distance < 0.7 * p[1].distance]
    if not pairs:
        return 0, 0.0
    li, ri = np.array(pairs).T
    same_row = np.abs(fl.xy_px[li, 1] - fr.xy_px[ri, 1]) < 2.0
    disparity = fl.xy_px[li, 0] - fr.xy_px[ri, 0]
    n = int(same_row.sum())
    return n, float((disparity[same_row] > 0).mean()) if n else 0.0


def _try(c: Candidate, vocabulary: str, out_dir: Path, timeout_s: float) -> tuple[list[str], dict | None, str]:
    """One ORB-SLAM3 run of the candidate: (our per-frame states, slam.json or None, the failure's line)."""
    import threading

    from bracketry_emulator.slam.frame_stream import FrameFeed
    from bracketry_emulator.slam.orbslam3 import (
        OrbSlam3Options,
        SlamRunError,
        orbslam3_request,
        start_child,
        wait_child,
    )
    from bracketry_emulator.trajectory_io import read_frames_csv

    opts = OrbSlam3Options(vocabulary, pace_s=0.0, timeout_s=timeout_s)
    out_dir.mkdir(parents=True, exist_ok=True)
    info, error = None, ""
    try:
        if c.run_dir is not None:
            request = orbslam3_request(c.run_dir, c.calibration_dir, opts, c.max_frames)
            info = wait_child(start_child(request, out_dir, timeout_s))
        else:
            fifo = FrameFeed.make_fifo(out_dir / "frames.fifo")
            child = start_child(orbslam3_request(None, c.calibration_dir, opts, None, fifo, c.fps), out_dir,
                                timeout_s)
            feed = FrameFeed(fifo, reader_pid=child.proc.pid)

            def send() -> None:
                for t_ns, left, right in c.frames:
                    feed.send(t_ns, left, right)
                feed.close()

            sender = threading.Thread(target=send, daemon=True)
            sender.start()
            try:
                info = wait_child(child)
            finally:
                sender.join(timeout=10)
                fifo.unlink(missing_ok=True)
    except SlamRunError as exc:
        error = str(exc)
    csv_path = out_dir / "frames.csv"
    states = [f["state"] for f in read_frames_csv(csv_path)] if info is not None and csv_path.is_file() else []
    return states, info, error


def _gray_pairs(c: Candidate) -> list[tuple[np.ndarray, np.ndarray]]:
    """Up to three stereo pairs (gray8) of the window: at a quarter, half and three quarters."""
    from bracketry_emulator.features.demosaic import to_gray8
    from bracketry_emulator.vo.runner import png_frames

    if c.frames:
        picks = sorted({len(c.frames) * q // 4 for q in (1, 2, 3)})
        return [(to_gray8(c.frames[i][1], bayer=True), to_gray8(c.frames[i][2], bayer=True)) for i in picks]
    assert c.run_dir is not None
    n, it = png_frames(c.run_dir, max_frames=c.max_frames)
    wanted = {n * q // 4 for q in (1, 2, 3)}
    return [(left, right) for i, (_t, left, right) in enumerate(it) if i in wanted]


def _stereo_problem(c: Candidate) -> str | None:
    """The calibration's problem seen on the window's stereo pairs (the best of three), or None. Judged only on a
    textured image (:data:`MIN_TEXTURE` keypoints), where a good calibration gives hundreds of matches."""
    if c.texture < MIN_TEXTURE:
        return None
    try:
        best = max((stereo_evidence(c.calibration_dir, left, right) for left, right in _gray_pairs(c)),
                   key=lambda e: e[0])
    except BracketryError as exc:
        return f"the calibration cannot be used ({exc})"
    n_match, positive = best
    if n_match < MIN_STEREO_MATCHES:
        return (f"the calibration: its rectified left/right pair has only {n_match} same-row ORB matches on an "
                f"image with {c.texture} keypoints (cameras swapped, wrong intrinsics, rotation or image size?)")
    if positive < 0.5:
        return (f"the calibration: left and right look swapped ({100 * (1 - positive):.0f} % of {n_match} stereo "
                "matches have negative disparity)")
    return None


def _scale_problem(out_dir: Path, reference: Path | None) -> str | None:
    """ORB-SLAM3's distance over its tracked frames against the reference's over the same times (when there is
    a reference and it moved at least :data:`MIN_REFERENCE_M`): a ratio beyond :data:`MAX_SCALE_RATIO` either way
    is a wrong baseline or focal length (the stereo scale)."""
    from bracketry_emulator.trajectory_io import read_tum

    if reference is None or not Path(reference).is_file():
        return None
    ref_t, ref_pose = read_tum(reference)
    if len(ref_t) < 2:
        return None
    est_m = ref_m = 0.0
    for seg in sorted(out_dir.glob("CameraTrajectory*.txt")):
        t, pose = read_tum(seg)
        inside = (t >= ref_t[0]) & (t <= ref_t[-1])
        t, pose = t[inside], pose[inside]
        if len(t) < 2:
            continue
        est_m += float(np.linalg.norm(np.diff(pose[:, :3, 3], axis=0), axis=1).sum())
        ref_xyz = np.stack([np.interp(t, ref_t, ref_pose[:, i, 3]) for i in range(3)], axis=1)
        ref_m += float(np.linalg.norm(np.diff(ref_xyz, axis=0), axis=1).sum())
    if ref_m < MIN_REFERENCE_M:
        return None
    ratio = est_m / ref_m
    if ratio > MAX_SCALE_RATIO or ratio < 1.0 / MAX_SCALE_RATIO:
        return (f"the calibration's stereo scale: ORB-SLAM3 moved {est_m:.2f} m where the reference moved "
                f"{ref_m:.2f} m ({ratio:.2f}x; wrong baseline or focal length?)")
    return None


def _vocabulary_refused(error: str, log: Path) -> bool:
    text = log.read_text(errors="replace") if log.is_file() else ""
    return ("vocabulary" in error.lower() or "Wrong path to vocabulary" in text
            or "Vocabulary loading failure" in text)


def check_setup(trajectories: list[Trajectory], vocabulary: str | Path, out_dir: str | Path,
                seconds: float = SETUP_SECONDS, min_tracked: int = MIN_TRACKED_FRAMES, max_tried: int = MAX_TRIED,
                timeout_s: float = 600.0) -> SetupCheckResult | None:
    """Run the set-up check (module docstring) on ``trajectories``; its ORB-SLAM3 runs go to
    ``out_dir/<trajectory>/`` (``orbslam3.log``, ``frames.csv``, ...).

    Returns the passing try, or None when there is nothing to try (no trajectory with calibration and images).
    Raises :class:`SetupCheckError` (one line) when no tried trajectory passes.
    """
    t_wall = time.perf_counter()
    cands = candidates(trajectories, seconds)[:max_tried]
    if not cands:
        return None
    failures: list[tuple[Candidate, str, Path]] = []
    cpu_s = 0.0
    for c in cands:
        run_out = Path(out_dir) / c.name
        log = run_out / "orbslam3.log"
        stereo = _stereo_problem(c)
        if stereo is not None:
            failures.append((c, stereo, log))
            continue
        states, info, error = _try(c, str(vocabulary), run_out, timeout_s)
        cpu_s += float(info.get("cpu_s", 0.0)) if info else 0.0
        need = min(min_tracked, len(states)) if states else min_tracked
        best = longest_tracked(states)
        if info is None or not states or best < need:
            why = error.split(" (log:")[0] if error else (f"it tracked at most {best} consecutive frames of "
                                                         f"{len(states)}, needs {need}")
            cause = ("the vocabulary (ORB-SLAM3 could not load it)" if _vocabulary_refused(error, log) else
                     "the vocabulary (the stereo pairs match well, so the calibration looks right), or the "
                     "calibration's focal length or baseline")
            failures.append((c, f"{why}; likely cause: {cause}", log))
            continue
        scale = _scale_problem(run_out, c.reference)
        if scale is not None:
            failures.append((c, scale, log))
            continue
        return SetupCheckResult(c.name, c.what, best, len(states), cpu_s, time.perf_counter() - t_wall,
                                [f.name for f, _w, _l in failures] + [c.name])
    c, why, log = failures[0]
    tried = ", ".join(f.name for f, _w, _l in failures)
    if "likely cause" not in why:
        why = f"likely cause: {why}"
    where = f" (log: {log})" if log.is_file() else ""
    raise SetupCheckError(f"set-up check failed (ORB-SLAM3 on the first {seconds:g} s of the {c.what} of {tried}, "
                          f"no AE method involved): {why}{where}")
