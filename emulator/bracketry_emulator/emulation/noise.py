"""Camera noise model (shot + read noise, photon-transfer style) and its calibration from static repeats.

In linear DN at unity gain (the 12-bit linear level before the response curve), a pixel with mean signal S has
variance ``var(S) = read_dn**2 + dn_per_e * S`` (+ quantization). With an analog gain G = 10^(gain_db / 20) both
terms are amplified: ``var_G(S) = G**2 * var(S)`` around a mean ``G * S`` (EMVA 1288 linear model).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

from ..crf.response import Response


@dataclass(frozen=True)
class NoiseModel:
    """Temporal noise in linear DN: ``read_dn`` (read noise std, DN) and ``dn_per_e`` (system gain, DN per
    photo-electron, the slope of variance vs signal). Defaults are typical of a 2.3 MP global-shutter CMOS
    (full well ~10 ke-, read noise ~2.5 e-) on 12 bits; calibrate your camera with :func:`calibrate_noise`."""

    read_dn: float = 1.0
    dn_per_e: float = 0.4

    def variance(self, signal_dn: np.ndarray | float, gain: float = 1.0) -> np.ndarray:
        """Variance (DN^2) of a pixel of mean linear ``signal_dn`` (at unity gain) read out with linear ``gain``."""
        s = np.maximum(np.asarray(signal_dn, dtype=np.float64), 0.0)
        return np.asarray(gain * gain * (self.read_dn ** 2 + self.dn_per_e * s))

    def to_json(self, path: Path) -> None:
        """Write the model as JSON ({"read_dn": ..., "dn_per_e": ...})."""
        path.write_text(json.dumps(asdict(self), indent=2) + "\n")

    @classmethod
    def from_mapping(cls, data: Mapping[str, float]) -> NoiseModel:
        """From a mapping with keys read_dn and dn_per_e (as written by ``calibrate-crf --noise-out``), or a
        synthetic world's ``camera_model.json`` content (read_noise_e, gain_e_per_dn)."""
        if "read_dn" in data:
            return cls(read_dn=float(data["read_dn"]), dn_per_e=float(data["dn_per_e"]))
        if "read_noise_e" in data and "gain_e_per_dn" in data:
            gain = float(data["gain_e_per_dn"])
            return cls(read_dn=float(data["read_noise_e"]) / gain, dn_per_e=1.0 / gain)
        raise ValueError("noise model needs read_dn + dn_per_e, or read_noise_e + gain_e_per_dn")

    @classmethod
    def from_json(cls, path: str | Path) -> NoiseModel:
        """Load :meth:`from_mapping` data from a JSON file (a top-level "camera" object is looked into too)."""
        data = json.loads(Path(path).read_text())
        if "read_dn" not in data and "read_noise_e" not in data and isinstance(data.get("camera"), dict):
            data = data["camera"]
        return cls.from_mapping(data)


def resolve_noise_model(explicit: str | Path | None, dataset_dir: str | Path | None = None
                        ) -> tuple[NoiseModel, str]:
    """The camera noise model to use and where it came from: ``explicit`` (a ``calibrate-crf --noise-out`` JSON or
    a ``camera_model.json``), else ``camera_model.json`` at the top of ``dataset_dir`` (a synthetic world or stack
    writes it), else the built-in default. Raises BracketryError (one line) for an unreadable explicit file."""
    if explicit is not None:
        p = Path(explicit)
        try:
            return NoiseModel.from_json(p), str(p)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise BracketryError(f"--noise {p}: not a noise model ({exc})") from exc
    if dataset_dir is not None:
        p = Path(dataset_dir) / "camera_model.json"
        if p.is_file():
            try:
                return NoiseModel.from_json(p), str(p)
            except (OSError, ValueError, KeyError, TypeError):
                pass  # a camera_model.json without noise terms: the default applies
    return NoiseModel(), "default"


def photon_transfer(repeats: Sequence[np.ndarray], response: Response, max_pixels: int = 400_000,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel (mean, variance) in linear DN of a stack of repeated frames of a static scene.

    ``repeats``: >= 2 uint16 HxW frames at the same exposure. Pixels saturated or at 0 in any frame are dropped.
    Returns float64 arrays (n,), subsampled to at most ``max_pixels`` pixels (fixed seed).
    """
    stack = np.stack([np.asarray(r).reshape(-1) for r in repeats])
    rng = np.random.default_rng(seed)
    if stack.shape[1] > max_pixels:
        stack = stack[:, rng.choice(stack.shape[1], max_pixels, replace=False)]
    ok = np.all((stack > 0) & (stack < response.saturated_code), axis=0)
    lin = response.icrf[stack[:, ok]]
    return lin.mean(axis=0), lin.var(axis=0, ddof=1)


def calibrate_noise(repeat_stacks: Mapping[int, Sequence[np.ndarray]], response: Response) -> NoiseModel:
    """Fit ``var = read_dn**2 + dn_per_e * S`` to the photon-transfer points of one or more exposures.

    ``repeat_stacks``: {exposure_us: [uint16 HxW frames]}. Points are binned by signal (64 bins, medians) so the
    many dark pixels do not dominate; the fit is least squares on the bin medians, with non-negative terms.
    """
    means, vars_ = [], []
    for frames in repeat_stacks.values():
        m, v = photon_transfer(frames, response)
        means.append(m)
        vars_.append(v)
    s = np.concatenate(means)
    v = np.concatenate(vars_)
    if s.size < 10:
        raise ValueError("not enough unsaturated pixels to calibrate the noise model")
    edges = np.quantile(s, np.linspace(0, 1, 65))
    idx = np.clip(np.searchsorted(edges, s, side="right") - 1, 0, 63)
    xs, ys = [], []
    for b in range(64):
        sel = idx == b
        if np.count_nonzero(sel) >= 20:
            xs.append(float(np.median(s[sel])))
            ys.append(float(np.mean(v[sel])))
    x, y = np.array(xs), np.array(ys)
    a = np.vstack([np.ones_like(x), x]).T
    (c0, c1), *_ = np.linalg.lstsq(a, y, rcond=None)
    return NoiseModel(read_dn=float(np.sqrt(max(c0 - 1.0 / 12.0, 0.0))), dn_per_e=float(max(c1, 0.0)))
