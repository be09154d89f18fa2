"""Image formation of the synthetic camera: radiance -> photo-electrons -> linear ADC level -> 12-bit codes.

Per pixel (Bayer channel c of the RGGB mosaic, exposure time t in microseconds)::

    mean_e   = radiance * qe[c] * vignetting(pixel) * t                      (photo-electrons)
    e        = mean_e + sqrt(mean_e) * N(0,1)  (or Poisson(mean_e))          shot noise
             + read_noise_e * N(0,1)                                         read noise
    level    = clip(round(black_level_dn + e / gain_e_per_dn), 0, 4095)       linear 12-bit ADC, full well = 4095 levels
    code     = response_lut[level]                                            sRGB-encoded (default), pcalib, or linear

``radiance`` is in scene units where one unit gives one photo-electron per microsecond on a green pixel at the image
centre. The default response reproduces the real sample's codes exactly: code = floor(4095 * sRGB_OETF(k / 4095)) of
the linear level k (2920 distinct codes, saturated code 4094).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bracketry.errors import BracketryError
from bracketry_emulator.synth.kernels import synth_kernels

N_LEVELS = 4096
SATURATED_CODE = 4094
_CHUNK = 65536
#: RGGB: channel index (0 R, 1 G, 2 B) of the Bayer cell (row % 2, col % 2).
BAYER_RGGB = ((0, 1), (1, 2))


def srgb_oetf(x: np.ndarray) -> np.ndarray:
    """sRGB encoding of linear values in [0, 1] (float64 in, float64 out)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - 0.055)


def srgb_lut() -> np.ndarray:
    """Linear level k (0..4095) -> sRGB-encoded code floor(4095 * OETF(k / 4095)), uint16 (4096,), max 4094."""
    lut = np.floor(4095.0 * srgb_oetf(np.arange(N_LEVELS) / 4095.0)).astype(np.int64)
    return np.minimum(lut, SATURATED_CODE).astype(np.uint16)


def pcalib_lut(pcalib: np.ndarray) -> np.ndarray:
    """Response LUT (linear level -> code, truncated, capped at 4094; uint16 (4096,)) of an inverse response.

    256 values (TUM pcalib, 8-bit code -> irradiance 0..255): lifted to 12 bits as the BorealHDR authors do (knots
    linspace(0, 4095, 256), irradiance 16 x pcalib with ends forced to 0 and 4095). 4096 values (the 12-bit variant
    ``bracketry calibrate-crf`` writes: the inverse response of every code): rescaled to 0..4095 and used per code.
    """
    g = np.asarray(pcalib, dtype=np.float64).ravel()
    if g.size not in (256, N_LEVELS) or not np.all(np.isfinite(g)) or np.any(np.diff(g) < 0):
        raise BracketryError("pcalib must hold 256 or 4096 finite non-decreasing values")
    if g.size == 256:
        knots_dn = np.linspace(0.0, 4095.0, 256)
        irr = 16.0 * g
    else:
        span = float(g[-1] - g[0])
        if span <= 0:
            raise BracketryError("pcalib curve is flat")
        knots_dn = np.arange(N_LEVELS, dtype=np.float64)
        irr = (g - g[0]) / span * 4095.0
    irr[0], irr[-1] = 0.0, 4095.0
    codes = np.interp(np.arange(N_LEVELS, dtype=np.float64), irr, knots_dn)
    return np.minimum(np.floor(codes), SATURATED_CODE).astype(np.uint16)


def linear_lut() -> np.ndarray:
    """Identity response (code = linear level), capped at 4094. uint16 (4096,)."""
    return np.minimum(np.arange(N_LEVELS), SATURATED_CODE).astype(np.uint16)


def pcalib_from_lut(lut: np.ndarray) -> np.ndarray:
    """TUM pcalib (256 floats: 8-bit code i -> inverse response in 0..255) of a 12-bit level -> code LUT.

    Entry i is 255/4095 x the mean linear level whose code is nearest 16.0588 * i (linear interpolation of the
    inverse of the LUT)."""
    lut = np.asarray(lut, dtype=np.float64)
    levels = np.arange(N_LEVELS, dtype=np.float64)
    codes, first = np.unique(lut, return_index=True)
    targets = np.linspace(0.0, 4095.0, 256)
    inv = np.interp(targets, codes, levels[first])
    inv[-1] = 4095.0
    return np.maximum.accumulate(inv * 255.0 / 4095.0)


@dataclass
class CameraModel:
    """Parameters of the synthetic camera (all written to ``camera_model.json``).

    Attributes:
        full_well_e: photo-electrons at linear level 4095 above black (saturation).
        read_noise_e: standard deviation of the read noise in electrons.
        black_level_dn: pedestal added in the linear ADC domain before the response (0 like the real camera).
        qe_rgb: relative sensitivity of the R, G, B pixels.
        vignetting: (a2, a4): relative illumination 1 + a2 r^2 + a4 r^4, r = distance to the principal point / half
            the image diagonal.
        response: "srgb" (the real sample's encoding), "linear", or "pcalib" (then ``pcalib`` holds 256 values).
        poisson: exact Poisson shot noise instead of its Gaussian approximation (slower).
    """

    full_well_e: float = 32000.0
    read_noise_e: float = 7.0
    black_level_dn: float = 0.0
    qe_rgb: tuple[float, float, float] = (0.80, 1.0, 0.55)
    vignetting: tuple[float, float] = (-0.30, 0.05)
    response: str = "srgb"
    pcalib: list[float] | None = field(default=None, repr=False)
    poisson: bool = False

    def __post_init__(self) -> None:
        if self.full_well_e <= 0 or self.read_noise_e < 0:
            raise BracketryError("camera model: full_well_e must be > 0 and read_noise_e >= 0")
        if not 0 <= self.black_level_dn < 4095:
            raise BracketryError("camera model: black_level_dn must be in [0, 4095)")
        if self.response not in ("srgb", "linear", "pcalib"):
            raise BracketryError(f"camera model: unknown response {self.response!r} (srgb, linear, pcalib)")
        if self.response == "pcalib" and self.pcalib is None:
            raise BracketryError("camera model: response 'pcalib' needs the 256 pcalib values")
        self._lut = self._build_lut()

    @classmethod
    def with_pcalib_file(cls, path: Path, **kwargs: object) -> CameraModel:
        """A model whose response is the TUM pcalib file at ``path``."""
        try:
            values = np.loadtxt(path, dtype=np.float64).ravel()
        except (OSError, ValueError) as exc:
            raise BracketryError(f"cannot read pcalib {path}: {exc}") from exc
        return cls(response="pcalib", pcalib=[float(x) for x in values], **kwargs)  # type: ignore[arg-type]

    def _build_lut(self) -> np.ndarray:
        if self.response == "srgb":
            return srgb_lut()
        if self.response == "linear":
            return linear_lut()
        return pcalib_lut(np.asarray(self.pcalib))

    @property
    def lut(self) -> np.ndarray:
        """Linear ADC level -> code, uint16 (4096,)."""
        return self._lut

    @property
    def gain_e_per_dn(self) -> float:
        """Electrons per linear ADC level."""
        return self.full_well_e / (4095.0 - self.black_level_dn)

    def vignetting_map(self, width: int, height: int, cx: float, cy: float) -> np.ndarray:
        """Relative illumination of every pixel, float32 (H, W), 1 at the principal point (cx, cy)."""
        a2, a4 = self.vignetting
        v, u = np.mgrid[0:height, 0:width].astype(np.float32)
        r2 = ((u - cx) ** 2 + (v - cy) ** 2) / (0.25 * (width * width + height * height))
        return np.clip(1.0 + r2 * (a2 + a4 * r2), 0.05, None).astype(np.float32)

    def qe_map(self, width: int, height: int) -> np.ndarray:
        """Per-pixel channel sensitivity of the RGGB mosaic, float32 (H, W)."""
        qe = np.asarray(self.qe_rgb, dtype=np.float32)
        cell = np.array([[qe[BAYER_RGGB[0][0]], qe[BAYER_RGGB[0][1]]], [qe[BAYER_RGGB[1][0]], qe[BAYER_RGGB[1][1]]]],
                        dtype=np.float32)
        return np.tile(cell, (height // 2 + 1, width // 2 + 1))[:height, :width].copy()

    def expected_levels(self, rate_e_per_us: np.ndarray, exposure_us: float) -> np.ndarray:
        """Noise-free linear ADC level (float64, unclipped above) of a per-pixel electron rate (e-/us incl. QE and
        vignetting) at ``exposure_us``."""
        e = np.minimum(np.asarray(rate_e_per_us, dtype=np.float64) * exposure_us, self.full_well_e)
        return self.black_level_dn + e / self.gain_e_per_dn

    def noise_free_codes(self, rate_e_per_us: np.ndarray, exposure_us: float) -> np.ndarray:
        """Exact noise-free image: the response applied to the rounded noise-free level. uint16 (same shape)."""
        levels = np.clip(np.rint(self.expected_levels(rate_e_per_us, exposure_us)), 0, N_LEVELS - 1).astype(np.int64)
        return self._lut[levels]

    def expose(self, rate_e_per_us: np.ndarray, exposure_us: float, rng: np.random.Generator | None,
               normal: np.ndarray | None = None) -> np.ndarray:
        """One noisy frame: per-pixel electron rate float32 (H, W) (incl. QE and vignetting) -> uint16 codes (H, W).

        ``rng`` None gives the noise-free image (same as :meth:`noise_free_codes`). ``normal``: standard normal
        variates already drawn, float32 (H * W,) in pixel order, used for the Gaussian noise instead of drawing them
        from ``rng`` (a caller that keeps a bank of them; not with ``poisson``)."""
        if exposure_us <= 0:
            raise BracketryError(f"exposure must be > 0 us (got {exposure_us})")
        if normal is not None and (self.poisson or normal.size != np.size(rate_e_per_us)):
            raise BracketryError("camera model: pre-drawn noise needs the Gaussian model and one value per pixel")
        if rng is None and normal is None:
            return self.noise_free_codes(rate_e_per_us, exposure_us)
        f32 = np.float32
        rate = np.ascontiguousarray(rate_e_per_us, dtype=np.float32)
        flat = rate.reshape(-1)
        out = np.empty(flat.shape, np.uint16)
        read_var = f32(self.read_noise_e ** 2)
        inv_gain = f32(1.0 / self.gain_e_per_dn)
        offset = f32(self.black_level_dn + 0.5)
        kernels = synth_kernels() if normal is not None else None
        if kernels is not None:  # the same codes, compiled (one pass, no temporaries)
            kernels.expose_gaussian(flat, np.ascontiguousarray(normal, np.float32), float(f32(exposure_us)),
                                    float(f32(2.0 * self.full_well_e)), float(read_var), float(inv_gain),
                                    float(offset), np.ascontiguousarray(self._lut, np.uint16), out)
            return out.reshape(rate.shape)
        for s0 in range(0, flat.size, _CHUNK):  # cache-sized chunks; the noise is drawn in pixel order
            mean_e = flat[s0:s0 + _CHUNK] * f32(exposure_us)
            np.minimum(mean_e, f32(2.0 * self.full_well_e), out=mean_e)
            if normal is not None:
                e = normal[s0:s0 + _CHUNK] * np.sqrt(mean_e + read_var)
                e += mean_e
            elif self.poisson:
                assert rng is not None
                e = rng.poisson(mean_e.astype(np.float64)).astype(np.float32)
                if self.read_noise_e > 0:
                    e += rng.standard_normal(mean_e.shape, dtype=np.float32) * f32(self.read_noise_e)
            else:
                assert rng is not None
                e = rng.standard_normal(mean_e.shape, dtype=np.float32)
                sigma = mean_e + read_var
                np.sqrt(sigma, out=sigma)
                e *= sigma
                e += mean_e
            e *= inv_gain
            e += offset
            np.clip(e, 0.0, N_LEVELS - 1, out=e)
            np.take(self._lut, e.astype(np.uint16), out=out[s0:s0 + _CHUNK])
        return out.reshape(rate.shape)

    def to_dict(self) -> dict:
        """JSON-serialisable parameters, plus derived constants and the formula."""
        d = asdict(self)
        d["qe_rgb"] = list(self.qe_rgb)
        d["vignetting"] = list(self.vignetting)
        d["gain_e_per_dn"] = self.gain_e_per_dn
        d["saturated_code"] = SATURATED_CODE
        d["bayer"] = "RGGB"
        d["radiance_unit"] = "photo-electrons per microsecond on a green pixel at the principal point"
        d["formula"] = ("e = radiance*qe[c]*vignetting*t_us + shot noise + read noise; level = clip(round(black + "
                        "e/gain_e_per_dn), 0, 4095); code = lut[level] (srgb: floor(4095*OETF(level/4095)))")
        return d

    def write_json(self, path: Path, extra: dict | None = None) -> None:
        """Write the parameters (and ``extra`` keys) as JSON."""
        d = self.to_dict()
        if extra:
            d.update(extra)
        Path(path).write_text(json.dumps(d, indent=2) + "\n")

    def write_pcalib(self, path: Path) -> None:
        """Write the response as a TUM pcalib file (one line of 256 values)."""
        values = np.asarray(self.pcalib) if self.response == "pcalib" else pcalib_from_lut(self._lut)
        Path(path).write_text(" ".join(f"{x:.9g}" for x in values) + "\n")
