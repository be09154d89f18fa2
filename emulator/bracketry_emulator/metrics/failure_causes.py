"""Why a run lost track: a cause for its first lost frame from per-frame data.

Per frame (one per closed-loop step) the classifier gets: the saturated and dark shares of the image the method and
SLAM got (the closed loop's ``ae.csv``, :func:`~bracketry_emulator.ae.loop.image_shares`), the rotation blur length
in pixels over the camera's exposure (from the reference trajectory, :func:`rotation_blur_px`), the exposure ratio
to the previous frame (target exposure x gain, i.e. the image's brightness ratio), and the keypoints and map matches
of the localisation (``frames.csv``; the keypoints are the localisation's own, ``n_slam_keypoints``: ORB-SLAM3's
stereo start and its tracking count those, not the paper-setting extractor's ``n_keypoints``, which stand in only
where the localisation's are unknown). It looks at the lost frame and the :data:`LOOKBACK` frames before it (a
tracker often reports the loss a frame after the image that broke it) and names the first cause that holds, in this
order:

=================  ===================================================================================================
``saturation``     a frame of the window has at least :data:`SATURATED_SHARE` of its pixels saturated
``underexposure``  a frame of the window has at least :data:`DARK_SHARE` of its pixels dark
``blur``           a frame of the window is blurred over at least :data:`BLUR_PX` pixels
``exposure_jump``  the exposure changed by a factor of at least 2 ** :data:`JUMP_STOPS` between two frames of the
                   window (or into its first frame): :func:`window_change_stops`
``texture``        none of the above, and the lost frame has at most :data:`TEXTURE_KEYPOINTS` keypoints
``other``          none of the above (e.g. too few map matches in a view with enough keypoints: parallax, a turn)
=================  ===================================================================================================

The order puts what makes the image itself unusable (clipped, black, smeared) before what makes it differ from the
map (a jump in brightness) and before what the view lacks whatever the exposure (texture). These are the paper's
readings of its own failures: saturation once a method converges too high, abrupt exposure changes (Kim's
exploration, Wang's jumps), blur at the longest exposures; glare shows as saturation.
"""

from __future__ import annotations

import contextlib
import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

#: the causes, in the order the classifier tries them (``other`` last)
CAUSES = ("saturation", "underexposure", "blur", "exposure_jump", "texture", "other")
#: frames before the lost one that the classifier looks at too
LOOKBACK = 1
#: saturated share of a frame from which it counts as saturated (a quarter of the view holds no corner)
SATURATED_SHARE = 0.25
#: dark share of a frame from which it counts as underexposed (half the view within noise of black)
DARK_SHARE = 0.5
#: blur length (px) from which a frame counts as blurred: FAST's test circle has radius 3 px, a corner smeared
#: over more than that no longer passes it
BLUR_PX = 3.0
#: an exposure change of at least this many stops between consecutive frames is a jump (a factor of sqrt 2): on the
#: full-size suite a tracked frame after such a change is lost about twice as often as one at a steady exposure
#: under the same turn (from a quarter stop 1.5 times, from one stop 3.8 times), so such a change more likely than
#: not took part in the loss (docs/RESULTS.md, "What loses track"; benchmarks/bench_loss_hazard.py)
JUMP_STOPS = 0.5
#: keypoints up to which a view lacks texture: ORB-SLAM's stereo initialisation needs more than 500
TEXTURE_KEYPOINTS = 500


def first_loss_index(states: list[str]) -> int | None:
    """Index of the first frame not tracked (state not ``OK``/``INIT``), None when every frame is tracked."""
    return next((k for k, s in enumerate(states) if s not in ("OK", "INIT")), None)


def classify_loss(saturated_share: np.ndarray, dark_share: np.ndarray, blur_px: np.ndarray,
                  exposure_ratio: np.ndarray, keypoints: np.ndarray, map_matches: np.ndarray, loss_index: int) -> str:
    """The cause (one of :data:`CAUSES`) of the loss at frame ``loss_index`` (module docstring).

    Args:
        saturated_share, dark_share: float (N,) shares of each frame's pixels in [0, 1] (NaN: unknown).
        blur_px: float (N,) blur length of each frame over its exposure, pixels (NaN: unknown).
        exposure_ratio: float (N,) each frame's exposure over the previous frame's (NaN for the first).
        keypoints, map_matches: float (N,) counts of the localisation per frame (NaN: unknown). Map matches are
            not a cause by themselves (every loss has few): a loss with enough keypoints and none of the image
            causes is ``other``.
        loss_index: the first lost frame, 0 <= loss_index < N.
    Returns:
        the cause, a str of :data:`CAUSES`.
    """
    n = len(saturated_share)
    if not 0 <= loss_index < n:
        raise ValueError(f"loss_index {loss_index} outside the {n} frames")
    window = slice(max(0, loss_index - LOOKBACK), loss_index + 1)

    def peak(values: np.ndarray) -> float:
        v = np.asarray(values, np.float64)[window]
        v = v[np.isfinite(v)]
        return float(v.max()) if v.size else math.nan

    if peak(saturated_share) >= SATURATED_SHARE:
        return "saturation"
    if peak(dark_share) >= DARK_SHARE:
        return "underexposure"
    if peak(blur_px) >= BLUR_PX:
        return "blur"
    if window_change_stops(exposure_ratio)[loss_index] >= JUMP_STOPS - 1e-9:
        return "exposure_jump"
    kp = float(np.asarray(keypoints, np.float64)[loss_index])
    if math.isfinite(kp) and kp <= TEXTURE_KEYPOINTS:
        return "texture"
    return "other"


def window_change_stops(exposure_ratio: np.ndarray) -> np.ndarray:
    """Per frame, the largest exposure change (stops, up or down) into it or into one of the :data:`LOOKBACK` frames
    before it: what :func:`classify_loss` compares with :data:`JUMP_STOPS`.

    Args:
        exposure_ratio: float (N,) each frame's exposure over the previous frame's (NaN or <= 0: unknown).
    Returns:
        float (N,) stops >= 0; NaN where every ratio of the window is unknown.
    """
    r = np.asarray(exposure_ratio, np.float64)
    stops = np.full(r.shape, np.nan)
    known = np.isfinite(r) & (r > 0)
    stops[known] = np.abs(np.log2(r[known]))
    out = stops.copy()
    for lag in range(1, LOOKBACK + 1):  # fmax: the larger of two, the known one when the other is NaN
        out[lag:] = np.fmax(out[lag:], stops[:-lag])
    return out


def rotation_blur_px(gt_times_s: np.ndarray, gt_poses_wc: np.ndarray, frame_times_s: np.ndarray,
                     exposure_s: np.ndarray, fx_px: float) -> np.ndarray:
    """Blur length (px) from the camera's rotation over each frame's exposure: the angle between its orientations at
    ``t - exposure/2`` and ``t + exposure/2`` (the frame stamped at mid-exposure), times ``fx_px``.

    Args:
        gt_times_s: float (M,) reference times, increasing; gt_poses_wc: float (M, 4, 4) camera-to-world poses.
        frame_times_s, exposure_s: float (N,) frame stamps and camera exposures, seconds.
        fx_px: focal length in pixels of the image the localisation sees.
    Returns:
        float (N,) pixels; NaN for frames outside the reference's time span (or with fewer than 2 poses).
    """
    t = np.asarray(frame_times_s, np.float64)
    e = np.asarray(exposure_s, np.float64)
    out = np.full(t.shape, np.nan)
    gt_t = np.asarray(gt_times_s, np.float64)
    if len(gt_t) < 2:
        return out
    slerp = Slerp(gt_t, Rotation.from_matrix(np.asarray(gt_poses_wc, np.float64)[:, :3, :3]))
    a, b = t - e / 2, t + e / 2
    inside = (a >= gt_t[0]) & (b <= gt_t[-1])
    if np.any(inside):
        ra, rb = slerp(a[inside]), slerp(b[inside])
        out[inside] = (ra.inv() * rb).magnitude() * float(fx_px)
    return out


@dataclass(frozen=True)
class FrameLog:
    """Per-frame inputs of :func:`classify_loss` for one run (float64 arrays of one length, NaN where unknown) and
    the frames' states and stamps (s)."""

    states: list[str]
    times_s: np.ndarray
    saturated_share: np.ndarray
    dark_share: np.ndarray
    camera_exposure_s: np.ndarray
    exposure_ratio: np.ndarray
    keypoints: np.ndarray
    map_matches: np.ndarray


def _floats(rows: list[dict], key: str, n: int) -> np.ndarray:
    out = np.full(n, np.nan)
    for k, r in enumerate(rows[:n]):
        text = r.get(key)
        if text is None or text == "":
            continue
        with contextlib.suppress(ValueError):
            out[k] = float(text)
    return out


def _own_keypoints(frame: dict) -> float:
    """The localisation's own keypoint count of a ``frames.csv`` row (``n_slam_keypoints``), else ``n_keypoints``."""
    own = float(frame.get("n_slam_keypoints", math.nan))
    return own if math.isfinite(own) else float(frame["n_keypoints"])


def frame_log(frames: list[dict], ae_csv: Path | None) -> FrameLog:
    """The frame log of a run: ``frames`` (rows of its ``frames.csv``, one per closed-loop step) joined by position
    with its closed loop's ``ae.csv`` rows (exposure_ms, gain_db, saturated_share, dark_share; missing file or
    columns: NaN)."""
    n = len(frames)
    rows: list[dict] = []
    if ae_csv is not None and Path(ae_csv).is_file():
        with Path(ae_csv).open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    exposure_ms = _floats(rows, "exposure_ms", n)
    gain_db = np.nan_to_num(_floats(rows, "gain_db", n), nan=0.0)
    ratio = np.full(n, np.nan)
    if n > 1:
        ratio[1:] = exposure_ms[1:] / exposure_ms[:-1]
    return FrameLog(
        states=[f["state"] for f in frames],
        times_s=np.array([f["t_ns"] for f in frames], np.float64) * 1e-9,
        saturated_share=_floats(rows, "saturated_share", n), dark_share=_floats(rows, "dark_share", n),
        camera_exposure_s=exposure_ms * 1e-3 / 10.0 ** (gain_db / 20.0), exposure_ratio=ratio,
        keypoints=np.array([_own_keypoints(f) for f in frames], np.float64),
        map_matches=np.array([f["n_map_matches"] for f in frames], np.float64))


def loss_cause(log: FrameLog, blur_px: np.ndarray) -> str | None:
    """The cause (:func:`classify_loss`) of the run's first loss, None when it never lost track."""
    i = first_loss_index(log.states)
    if i is None:
        return None
    return classify_loss(log.saturated_share, log.dark_share, blur_px, log.exposure_ratio, log.keypoints,
                         log.map_matches, i)


def failure_rows(result: dict) -> list[dict]:
    """``{"repeat", "time_s", "cause"}`` of every failed run of one benchmark result (its JSON form): the repeats
    listed in ``failure_runs`` (results combined over repeats), else the run itself when it has a
    ``failure_cause``."""
    if "failure_runs" in result:
        return [dict(r) for r in result["failure_runs"]]
    if result.get("failure_cause"):
        return [{"repeat": int(result.get("repeat", 0)), "time_s": float(result["time_before_failure_s"]),
                 "cause": str(result["failure_cause"])}]
    return []
