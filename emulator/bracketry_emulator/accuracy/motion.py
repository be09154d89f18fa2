"""The motion protocol: emulated long exposures of a moving camera against the world's true renders.

On a synthetic walk (:class:`~bracketry_emulator.synth.World`, motion blur integrated over each exposure) at each
speed (km/h; 0 = the camera held still: no walk, no gait), at ``n_instants`` trigger instants t: the source bracket
S (1, 2, 4, 8 ms) is rendered triggered at t, the next bracket of the cycle (2 S) one frame period later (22 fps, as
``bracketry synth trajectory`` writes them), and the target T (16, 32 ms) is emulated from S by HigherNoSat's
arithmetic (the source given) without and with motion-blur emulation (:mod:`..emulation.blur`: optical flow between
S and 2 S). Each is compared with the exact render of T triggered at t. Every render is noise-free: emulating 16 ms
from 1 ms multiplies the source's noise by 16 (300-450 DN RMSE at 1 ms -> 16/32 ms on a static view), which would
hide what motion does; the emulator's noise is the static protocol's (``bracketry accuracy static``). Figures:

- ``rmse_dn``: RMSE (12-bit DN) against the true render over the pixels the source exposes well (linear level >=
  ``MIN_SOURCE_LEVEL``) and that neither the truth nor the scaled source saturates: elsewhere a short source cannot
  give the target at all (a level of 0.4 at 1 ms reads 0, x16 is still 0 where the truth has 6: ~300 DN in sRGB codes)
  and those few pixels would decide the RMSE;
- sharpness: the mean gradient magnitude of the half-resolution gray linear image (``sharpness_*``, the true one
  and each emulation's), and its relative error ``sharpness_error_* = |emulated / true - 1|``.

One row per (speed, source, target), each figure the median over the instants. Summary per speed: the median over
the rows of the RMSE reduction ``1 - rmse_blur / rmse_plain``. Goals: >= 30 % lower RMSE with blur emulation on the
moving walks, and never worse (per row, 0.1 % relative tie) on the still camera.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from ..crf import Response
from ..emulation import Emulator, EmulatorConfig, NoiseModel
from ..emulation.align import bayer_gray_half
from ..synth import LoopTrajectory, World
from .metrics import rmse_dn

SPEEDS_KMH: tuple[float, ...] = (0.0, 2.0, 5.0)
SOURCES_MS: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0)
TARGETS_MS: tuple[float, ...] = (16.0, 32.0)
#: the frame period of a written synthetic trajectory (22 fps)
PERIOD_S = 1.0 / 22.0
#: goal: at least this RMSE reduction (median over the moving rows) with blur emulation
BLUR_REDUCTION_GOAL = 0.30
#: "not worse" on the still camera allows this relative tie
NOT_WORSE_REL_TOL = 1e-3

#: the lowest linear level (DN) of a source pixel counted in the RMSE (quantization below 3 %)
MIN_SOURCE_LEVEL = 16.0

Progress = Callable[[int, int], None]


def well_exposed(source: np.ndarray, truth: np.ndarray, factor: float, response: Response) -> np.ndarray:
    """bool HxW: source linear level >= :data:`MIN_SOURCE_LEVEL`, the level x ``factor`` below the saturated
    level, and the truth (uint16 codes) below the saturated code."""
    level = response.icrf[source]
    sat_level = float(response.icrf[response.saturated_code - 1])
    return (level >= MIN_SOURCE_LEVEL) & (level * factor < sat_level) & (truth < response.saturated_code)


def sharpness(image: np.ndarray, response_icrf: np.ndarray) -> float:
    """Mean gradient magnitude (linear DN per half-resolution pixel, 3x3 Sobel / 8) of the half-resolution gray
    linear image of a mosaic (uint16 HxW codes)."""
    gray = bayer_gray_half(response_icrf[image].astype(np.float32))
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return float(np.mean(np.sqrt(gx * gx + gy * gy)))


def _world(preset: str, seed: int, resolution: tuple[int, int], speed_kmh: float) -> World:
    """The walk at ``speed_kmh``; at 0 the camera held still (no walk, no gait: the same view at every instant)."""
    if speed_kmh > 0:
        return World(preset, seed, resolution, trajectory=LoopTrajectory(speed_kmh=speed_kmh), motion_blur=True)
    still = LoopTrajectory(speed_kmh=1e-9, bounce_m=0.0, roll_deg=0.0, sway_m=0.0, yaw_deg=0.0, nod_deg=0.0)
    return World(preset, seed, resolution, trajectory=still, motion_blur=False)


def run_motion(seed: int = 0, preset: str = "forest-winter", resolution: tuple[int, int] = (640, 400),
               speeds_kmh: Sequence[float] = SPEEDS_KMH, sources_ms: Sequence[float] = SOURCES_MS,
               targets_ms: Sequence[float] = TARGETS_MS, n_instants: int = 3, first_s: float = 2.0,
               spacing_s: float = 3.1, progress: Progress | None = None) -> dict:
    """Run the protocol (module docstring); returns a JSON-ready dict ``{"rows": [...], "summary": ..., "goals":
    ..., "settings": ...}``. ``first_s``, ``spacing_s``: the trigger instants first_s + i spacing_s (s)."""
    rows: list[dict] = []
    total = len(speeds_kmh) * n_instants
    done = 0
    for speed in speeds_kmh:
        world = _world(preset, seed, resolution, float(speed))
        noise = NoiseModel.from_mapping({"read_noise_e": world.camera.read_noise_e,
                                         "gain_e_per_dn": world.camera.gain_e_per_dn})
        # only the source and its neighbour are given: the target is above both, an exposure (not gain) here
        plain = Emulator(EmulatorConfig(noise=noise, beyond="extrapolate"))
        blurred = Emulator(EmulatorConfig(noise=noise, beyond="extrapolate", blur=True), response=plain.response)
        resp_icrf = plain.response.icrf
        per_case: dict[tuple[float, float], list[tuple[float, ...]]] = {}
        for i in range(n_instants):
            t = first_s + i * spacing_s
            t_next = t + PERIOD_S  # the next bracket's trigger (a still camera sees the same view then)
            truths = {tm: world.render("left", t, tm * 1000.0, noise=False) for tm in targets_ms}
            sharp_true = {tm: sharpness(img, resp_icrf) for tm, img in truths.items()}
            for sm in sources_ms:
                s_us, n_us = round(sm * 1000), round(2 * sm * 1000)
                src = world.render("left", t, s_us, noise=False)
                nxt = world.render("left", t_next if speed > 0 else t, n_us, noise=False)
                images = {s_us: src, n_us: nxt}
                times = {s_us: round(world.mid_exposure_s(t, s_us) * 1e9),
                         n_us: round(world.mid_exposure_s(t_next, n_us) * 1e9)}
                for tm in targets_ms:
                    t_us = tm * 1000.0
                    a = plain.emulate(images, t_us, source_us=s_us, times_ns=times)
                    b = blurred.emulate(images, t_us, source_us=s_us, times_ns=times)
                    sa, sb = sharpness(a.image, resp_icrf), sharpness(b.image, resp_icrf)
                    st = sharp_true[tm]
                    mask = well_exposed(src, truths[tm], tm / sm, plain.response)
                    per_case.setdefault((sm, tm), []).append(
                        (rmse_dn(a.image, truths[tm], mask), rmse_dn(b.image, truths[tm], mask), st, sa, sb,
                         abs(sa / st - 1.0) if st > 0 else float("nan"),
                         abs(sb / st - 1.0) if st > 0 else float("nan")))
            done += 1
            if progress is not None:
                progress(done, total)
        for (sm, tm), vals in per_case.items():
            med = np.median(np.array(vals, dtype=np.float64), axis=0)
            rows.append({"speed_kmh": float(speed), "source_ms": float(sm), "target_ms": float(tm),
                         "rmse_dn_plain": float(med[0]), "rmse_dn_blur": float(med[1]),
                         "sharpness_true": float(med[2]), "sharpness_plain": float(med[3]),
                         "sharpness_blur": float(med[4]), "sharpness_error_plain": float(med[5]),
                         "sharpness_error_blur": float(med[6]), "n_instants": len(vals)})
    summary = _summary(rows)
    return {"protocol": "motion", "settings": {"seed": seed, "preset": preset, "resolution": list(resolution),
                                               "speeds_kmh": list(speeds_kmh), "sources_ms": list(sources_ms),
                                               "targets_ms": list(targets_ms), "n_instants": n_instants,
                                               "instants_s": [first_s + i * spacing_s for i in range(n_instants)],
                                               "period_s": PERIOD_S},
            "rows": rows, "summary": summary, "goals": goals(rows, summary)}


def _summary(rows: list[dict]) -> dict:
    out: dict = {}
    for speed in sorted({r["speed_kmh"] for r in rows}):
        rs = [r for r in rows if r["speed_kmh"] == speed]
        red = [1.0 - r["rmse_dn_blur"] / r["rmse_dn_plain"] for r in rs if r["rmse_dn_plain"] > 0]
        out[f"{speed:g}"] = {
            "rmse_dn_plain_median": float(np.median([r["rmse_dn_plain"] for r in rs])),
            "rmse_dn_blur_median": float(np.median([r["rmse_dn_blur"] for r in rs])),
            "rmse_reduction_median": float(np.median(red)) if red else float("nan"),
            "sharpness_error_plain_median": float(np.median([r["sharpness_error_plain"] for r in rs])),
            "sharpness_error_blur_median": float(np.median([r["sharpness_error_blur"] for r in rs])),
            "n_rows": len(rs)}
    return out


def goals(rows: list[dict], summary: dict) -> dict:
    """>= 30 % lower RMSE (median over the moving rows) with blur emulation; never worse on the still camera."""
    moving = [1.0 - r["rmse_dn_blur"] / r["rmse_dn_plain"] for r in rows
              if r["speed_kmh"] > 0 and r["rmse_dn_plain"] > 0]
    still = [r for r in rows if r["speed_kmh"] == 0]
    worse = [r for r in still if r["rmse_dn_blur"] > r["rmse_dn_plain"] * (1 + NOT_WORSE_REL_TOL) + 1e-9]
    red = float(np.median(moving)) if moving else float("nan")
    return {"blur_rmse_reduction_moving": {"value": red, "met": bool(red >= BLUR_REDUCTION_GOAL)},
            "blur_not_worse_still": {"n_worse": len(worse), "met": not worse and bool(still)}}
