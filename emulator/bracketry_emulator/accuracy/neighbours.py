"""Neighbour protocol on real moving data: emulate bracket k from its neighbours k-1 and k+1 and compare with the
real bracket k (captured ~46 ms away from each neighbour on a walking backpack).

Modes: ``from-lower`` (k-1 only, f = t_k / t_(k-1)), ``from-higher`` (k+1 only), ``highernosat`` and ``upstream``
(selection between k-1 and k+1), ``fusion`` (both). Each with ``none`` (raw frames) and with global alignment of
the neighbours onto frame k (``homography`` or ``translation``, estimated on linearized images, applied to the
linear mosaic plane by plane; pixels that leave the frame are excluded). Metrics per emulated frame: RMSE (DN) and
mean bias (emulated - real, DN) over the valid pixels. Motion (parallax, moving objects) remains in the RMSE; the
mean bias is motion-robust and checks the photometry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..crf import Response
from ..dataset import Dataset
from ..emulation import Emulator, EmulatorConfig, estimate_motion, warp_mosaic
from ..emulation.align import Motion
from .metrics import bias_dn, rmse_dn

MODES: tuple[str, ...] = ("from-lower", "from-higher", "highernosat", "upstream", "fusion")
Progress = Callable[[int, int], None]


def align_to(images: dict[int, np.ndarray], ref_us: int, ref: np.ndarray, response: Response, motion: Motion
             ) -> tuple[dict[int, np.ndarray], np.ndarray]:
    """Warp every bracket in ``images`` onto the geometry of ``ref`` (a uint16 frame at ``ref_us``).

    Returns (aligned uint16 codes per exposure, bool valid mask HxW). Saturated pixels stay saturated (an output
    pixel is saturated when saturated source pixels carry at least half of its interpolation weight).
    """
    valid = np.ones(ref.shape, dtype=bool)
    if motion == "none":
        return dict(images), valid
    sat_code = response.saturated_code
    ref_irr = response.icrf[ref] / ref_us
    out: dict[int, np.ndarray] = {}
    for e, img in images.items():
        lin = response.icrf[img]
        ok = (img < sat_code) & (ref < sat_code)
        half_ok = ok[0::2, 0::2] & ok[1::2, 1::2]
        h = estimate_motion(np.where(ok, lin / e, 0.0), np.where(ok, ref_irr, 0.0), motion, half_ok)
        warped = warp_mosaic(lin, h)
        sat = warp_mosaic((img >= sat_code).astype(np.float32), h, border_value=0.0) >= 0.5
        inside = ~np.isnan(warped)
        codes = response.encode(np.nan_to_num(warped), "round")
        codes[sat] = sat_code
        out[e] = codes
        valid &= inside
    return out, valid


def _stats(values: list[float]) -> dict[str, float]:
    arr = np.array([v for v in values if np.isfinite(v)], dtype=np.float64)
    if arr.size == 0:
        return {"median": float("nan"), "mean": float("nan"), "max": float("nan"), "n": 0}
    return {"median": float(np.median(arr)), "mean": float(arr.mean()), "max": float(arr.max()), "n": int(arr.size)}


def run_neighbours(dataset: Dataset, sides: Sequence[str] | None = None, crf: str = "srgb",
                   response: Response | None = None, modes: Sequence[str] = MODES,
                   alignments: Sequence[Motion] = ("none", "homography"), max_sequences: int | None = None,
                   crop: tuple[int, int] | None = None, progress: Progress | None = None) -> dict:
    """Run the neighbour protocol on a dataset; returns a JSON-ready dict (per-frame rows, summaries, goals).

    ``crop``: optional (height, width) of a centred crop (even numbers) to speed the run up.
    """
    base = Emulator(EmulatorConfig(crf=crf), response=response)
    resp = base.response
    emus = {"highernosat": base, "upstream": Emulator(EmulatorConfig(selection="upstream"), response=resp),
            "fusion": Emulator(EmulatorConfig(selection="fusion"), response=resp)}
    use_sides = tuple(sides) if sides else dataset.sides
    seqs = dataset.sequences()[:max_sequences] if max_sequences else dataset.sequences()
    rows: list[dict] = []
    total = len(seqs) * len(use_sides)
    done = 0
    for seq in seqs:
        for side in use_sides:
            imgs = seq.load(side)
            if crop is not None:
                imgs = {e: _crop(i, crop) for e, i in imgs.items()}
            exps = sorted(imgs)
            for i in range(1, len(exps) - 1):
                k, lo, hi = exps[i], exps[i - 1], exps[i + 1]
                real = imgs[k]
                for al in alignments:
                    src, valid = align_to({lo: imgs[lo], hi: imgs[hi]}, k, real, resp, al)
                    row: dict = {"sequence": seq.index, "side": side, "target_us": k, "alignment": al, "modes": {}}
                    for mode in modes:
                        if mode == "from-lower":
                            out = base.emulate({lo: src[lo]}, float(k))
                        elif mode == "from-higher":
                            out = base.emulate({hi: src[hi]}, float(k))
                        else:
                            out = emus[mode].emulate(src, float(k))
                        row["modes"][mode] = {"rmse_dn": rmse_dn(out.image, real, valid),
                                              "bias_dn": bias_dn(out.image, real, valid),
                                              "source_us": out.source_exposure_us}
                    row["valid_fraction"] = float(valid.mean())
                    rows.append(row)
            done += 1
            if progress is not None:
                progress(done, total)
    summary: dict = {}
    for al in alignments:
        summary[al] = {}
        for mode in modes:
            sel = [r["modes"][mode] for r in rows if r["alignment"] == al]
            summary[al][mode] = {"rmse_dn": _stats([s["rmse_dn"] for s in sel]),
                                 "bias_dn": _stats([s["bias_dn"] for s in sel]),
                                 "abs_bias_dn": _stats([abs(s["bias_dn"]) for s in sel])}
    goals = {}
    if "fusion" in modes and "highernosat" in modes:
        for al in alignments:
            f = summary[al]["fusion"]["rmse_dn"]["median"]
            h = summary[al]["highernosat"]["rmse_dn"]["median"]
            goals[f"fusion_below_highernosat_{al}"] = {"fusion_median_rmse_dn": f, "highernosat_median_rmse_dn": h,
                                                       "met": bool(f < h)}
    return {"protocol": "neighbours", "dataset": str(dataset.path), "crf": resp.name, "sides": list(use_sides),
            "n_sequences": len(seqs), "n_pairs": len(rows) // max(len(alignments), 1), "crop": crop,
            "rows": rows, "summary": summary, "goals": goals}


def _crop(img: np.ndarray, crop: tuple[int, int]) -> np.ndarray:
    h, w = crop
    y0 = ((img.shape[0] - h) // 2) & ~1
    x0 = ((img.shape[1] - w) // 2) & ~1
    return np.ascontiguousarray(img[y0:y0 + h, x0:x0 + w])
