"""How a camera's frames look, measured the same way on real and synthetic brackets (DATASET.md's comparison).

Per raw frame (uint16 (H, W) RGGB 12-bit codes, sRGB-encoded as the BorealHDR camera and the synthetic camera write
them): the noise floor in flat dark areas (linear ADC levels), the saturated and dark shares, and the ORB keypoints.
``python -m bracketry_emulator.synth.realism SAMPLE_RECORDING`` prints the side-by-side table of the real sample and
a synthetic view of the same kind (the campus loop at 15:00, 960x600; both measured at 640x400 for ORB).
"""

from __future__ import annotations

import cv2
import numpy as np

from bracketry_emulator.synth.camera_model import SATURATED_CODE, srgb_lut

#: a pixel is dark when its 8-bit code (code >> 4) is below this (FAST at threshold 15 finds no corner there)
DARK_CODE8 = 16
_BLOCK = 16


def linear_levels(codes: np.ndarray) -> np.ndarray:
    """Linear ADC level (float64, same shape) of sRGB-encoded 12-bit codes: the mean level of each code's levels."""
    lut = srgb_lut().astype(np.int64)
    levels = np.arange(lut.size, dtype=np.float64)
    sums = np.bincount(lut, weights=levels, minlength=4096)
    counts = np.bincount(lut, minlength=4096)
    inv = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    known = np.nonzero(counts)[0]
    inv = np.interp(np.arange(4096), known, inv[known])
    return inv[np.asarray(codes, np.int64)]


def dark_noise_floor(codes: np.ndarray, dark_pct: float = 10.0) -> tuple[float, float]:
    """Noise floor of the flat dark areas of a raw frame: (median level, median noise std), linear ADC levels.

    The two green pixels of each RGGB cell are diagonal neighbours that see (almost) the same light: the std of their
    difference / sqrt(2) is the temporal noise of one pixel (plus the texture between them, small in flat areas).
    Per 16x16 block of cells: the mean green level and the robust std (1.4826 x MAD) of the differences; the blocks
    in the darkest ``dark_pct`` % by level, whose level is below 200, with the flattest half of them by the block's
    spread of levels, give the medians."""
    lev = linear_levels(codes)
    h, w = lev.shape
    g1 = lev[0:h - h % 2:2, 1:w - w % 2:2]
    g2 = lev[1:h - h % 2:2, 0:w - w % 2:2]
    bh, bw = g1.shape[0] // _BLOCK, g1.shape[1] // _BLOCK

    def blocks(a: np.ndarray) -> np.ndarray:
        return a[:bh * _BLOCK, :bw * _BLOCK].reshape(bh, _BLOCK, bw, _BLOCK).transpose(0, 2, 1, 3).reshape(
            bh * bw, _BLOCK * _BLOCK)

    d = blocks((g1 - g2) / np.sqrt(2.0))
    m = blocks(0.5 * (g1 + g2))
    level = m.mean(axis=1)
    noise = 1.4826 * np.median(np.abs(d - np.median(d, axis=1, keepdims=True)), axis=1)
    spread = np.percentile(m, 90, axis=1) - np.percentile(m, 10, axis=1)
    dark = (level <= np.percentile(level, dark_pct)) & (level < 200.0)
    if not np.any(dark):
        return float("nan"), float("nan")
    flat = dark & (spread <= np.median(spread[dark]))
    return float(np.median(level[flat])), float(np.median(noise[flat]))


def model_noise_dn(level_dn: float, gain_e_per_dn: float, read_noise_e: float) -> float:
    """The camera model's temporal noise std (linear ADC levels) at ``level_dn``: shot + read noise + quantisation."""
    return float(np.sqrt((max(level_dn, 0.0) * gain_e_per_dn + read_noise_e ** 2) / gain_e_per_dn ** 2 + 1 / 12))


def shares(codes: np.ndarray) -> tuple[float, float]:
    """(saturated share: codes >= 4094, dark share: 8-bit code below :data:`DARK_CODE8`) of a raw frame."""
    c = np.asarray(codes)
    return float(np.mean(c >= SATURATED_CODE)), float(np.mean((c >> 4) < DARK_CODE8))


def orb_keypoints(codes: np.ndarray, size: tuple[int, int] = (640, 400), n_features: int = 3000,
                  fast_threshold: int = 15) -> int:
    """ORB keypoints of a raw frame (8-bit gray of the demosaiced mosaic, resized to ``size``)."""
    gray = cv2.cvtColor((np.asarray(codes) >> 4).astype(np.uint8), cv2.COLOR_BayerBG2GRAY)
    if gray.shape[::-1] != tuple(size):
        gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
    orb = cv2.ORB_create(nfeatures=n_features, fastThreshold=fast_threshold)  # type: ignore[attr-defined]
    return len(orb.detect(gray, None))


def frame_stats(codes: np.ndarray) -> dict:
    """Every measure of one raw frame."""
    level, noise = dark_noise_floor(codes)
    sat, dark = shares(codes)
    return {"dark_level_dn": level, "dark_noise_dn": noise, "saturated": sat, "dark": dark,
            "keypoints": orb_keypoints(codes)}


def _main(sample: str) -> None:  # pragma: no cover - prints DATASET.md's table
    from pathlib import Path

    from bracketry_emulator.synth.scenario import (
        merge,
        read_scenario_doc,
        scenario_from_dict,
        shipped_scenarios,
    )
    from bracketry_emulator.synth.world import world_from_scenario

    root = Path(sample)
    doc = merge(read_scenario_doc(shipped_scenarios()["day-cycle"]), {"sun": {"hour": 15.0}})
    world = world_from_scenario(scenario_from_dict(doc), seed=3, resolution=(960, 600), detail=0.5)
    cam = world.camera
    print("| bracket ms | real: dark level / noise (DN) | synthetic: dark level / noise (DN) | model noise at the "
          "synthetic level | saturated real / synth | dark real / synth | ORB keypoints real / synth |")
    print("|---|---|---|---|---|---|---|")
    for ms in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        files = sorted((next(root.glob("*/camera_left")) / f"{ms:.1f}").glob("*.png"))
        real = [frame_stats(np.asarray(cv2.imread(str(f), cv2.IMREAD_UNCHANGED))) for f in files]
        syn = [frame_stats(world.render("left", t, ms * 1000.0)) for t in (2.0, 6.0, 10.0)]

        def med(rows: list[dict], key: str) -> float:
            return float(np.nanmedian([r[key] for r in rows]))

        print(f"| {ms:g} | {med(real, 'dark_level_dn'):.1f} / {med(real, 'dark_noise_dn'):.2f} | "
              f"{med(syn, 'dark_level_dn'):.1f} / {med(syn, 'dark_noise_dn'):.2f} | "
              f"{model_noise_dn(med(syn, 'dark_level_dn'), cam.gain_e_per_dn, cam.read_noise_e):.2f} | "
              f"{100 * med(real, 'saturated'):.1f} / {100 * med(syn, 'saturated'):.1f} % | "
              f"{100 * med(real, 'dark'):.1f} / {100 * med(syn, 'dark'):.1f} % | "
              f"{med(real, 'keypoints'):.0f} / {med(syn, 'keypoints'):.0f} |", flush=True)


if __name__ == "__main__":  # pragma: no cover
    import sys

    _main(sys.argv[1])
