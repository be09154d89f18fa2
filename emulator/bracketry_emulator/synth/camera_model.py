"""Image formation of the synthetic camera: radiance -> photo-electrons -> linear ADC level -> 12-bit codes.

Per pixel (Bayer channel c of the RGGB mosaic, exposure time t in microseconds)::

    rate     = radiance * qe[c] * vignetting(pixel)                          (e-/us; World computes it)
    rate    += veil(rate)                                                    lens veiling glare (World)
    mean_e   = (rate + dark_current) * t + bloom(rate, t)                    (photo-electrons)
    e        = mean_e + sqrt(mean_e) * N(0,1)  (or Poisson(mean_e))          shot and dark-current noise
             + read_noise_e * N(0,1)                                         read noise
    level    = clip(round(black_level_dn + e / gain_e_per_dn), 0, 4095)       linear 12-bit ADC, full well = 4095 levels
    code     = response_lut[level]                                            sRGB-encoded (default), pcalib, or linear

``radiance`` is in scene units where one unit gives one photo-electron per microsecond on a pixel of QE 1 at the image
centre (a green pixel collects ``qe_rgb[1]`` of it). The default response reproduces the real sample's codes exactly:
code = floor(4095 * sRGB_OETF(k / 4095)) of the linear level k (2920 distinct codes, saturated code 4094).

The defaults are the rig's sensor, the Sony IMX392 of the Basler a2A1920-51gcPRO (``hw/bom.csv``; 3.45 um pixels,
12-bit ADC, 0 dB gain as the rig runs it): saturation capacity about 10.5 ke-, temporal dark noise about 2.3 e-
(72 dB), dark current a few e-/s (nothing at <= 32 ms). ``bloom``: a share ``blooming`` of the charge above the full
well spills into the neighbouring pixels (a Gaussian of ``bloom_sigma_px`` at 1920 px across, scaled to the image):
saturated areas grow with the overexposure. ``veil``: the lens's veiling glare, a share ``veiling_glare`` of the
image's light spread over the whole frame (half uniform, half a broad blur of a sixth of the image width), the
stray light that lifts the dark parts beside bright snow, sky or a sun in view (ISO 9358 veiling glare index of
machine-vision lenses: 1-5 %). DATASET.md compares the model with the real sample.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError
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
        qe_rgb: photo-electrons per radiance unit of the R, G, B pixels. Green 0.33 (= 10.5 ke- / 32 ke-, the
            full well the scenes' light was first set for) keeps the views' levels per bracket at the real sample's
            (median linear level at 2 ms: real lawn 83, the campus loop 90-100; DATASET.md).
        vignetting: (a2, a4): relative illumination 1 + a2 r^2 + a4 r^4, r = distance to the principal point / half
            the image diagonal.
        response: "srgb" (the real sample's encoding), "linear", or "pcalib" (then ``pcalib`` holds 256 values).
        poisson: exact Poisson shot noise instead of its Gaussian approximation (slower).
        dark_current_e_per_s: thermal electrons per second per pixel (added to the signal and its shot noise).
        blooming: share of the charge above the full well that spills into the neighbouring pixels (0: none).
        bloom_sigma_px: the spill's Gaussian spread in pixels of a 1920-pixel-wide image (scaled to the width).
        veiling_glare: share of the image's light the lens spreads over the frame (0: none; applied by
            :meth:`veil`, which :class:`~bracketry_emulator.synth.world.World` calls on every frame's rate).
    """

    full_well_e: float = 10500.0
    read_noise_e: float = 2.3
    black_level_dn: float = 0.0
    qe_rgb: tuple[float, float, float] = (0.26, 0.33, 0.18)
    vignetting: tuple[float, float] = (-0.30, 0.05)
    response: str = "srgb"
    pcalib: list[float] | None = field(default=None, repr=False)
    poisson: bool = False
    dark_current_e_per_s: float = 3.0
    blooming: float = 0.3
    bloom_sigma_px: float = 1.5
    veiling_glare: float = 0.03

    def __post_init__(self) -> None:
        if self.full_well_e <= 0 or self.read_noise_e < 0:
            raise BracketryError("camera model: full_well_e must be > 0 and read_noise_e >= 0")
        if not 0 <= self.black_level_dn < 4095:
            raise BracketryError("camera model: black_level_dn must be in [0, 4095)")
        if self.response not in ("srgb", "linear", "pcalib"):
            raise BracketryError(f"camera model: unknown response {self.response!r} (srgb, linear, pcalib)")
        if self.dark_current_e_per_s < 0 or not 0 <= self.blooming <= 1 or self.bloom_sigma_px < 0 \
                or not 0 <= self.veiling_glare < 1:
            raise BracketryError("camera model: dark_current_e_per_s >= 0, blooming and veiling_glare in [0, 1), "
                                 "bloom_sigma_px >= 0 required")
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
        """Exact noise-free image: the response applied to the rounded noise-free level (with the dark current and
        the blooming of :meth:`charge_rate`). uint16 (same shape)."""
        rate = self.charge_rate(rate_e_per_us, exposure_us)
        levels = np.clip(np.rint(self.expected_levels(rate, exposure_us)), 0, N_LEVELS - 1).astype(np.int64)
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
        rate = np.ascontiguousarray(self.charge_rate(rate_e_per_us, exposure_us), dtype=np.float32)
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

    def charge_rate(self, rate_e_per_us: np.ndarray, exposure_us: float) -> np.ndarray:
        """The rate of charge each pixel collects over ``exposure_us``: the light's ``rate_e_per_us`` (float (H, W))
        plus the dark current, plus the charge that blooms in from saturated neighbours (a share ``blooming`` of
        their charge above the full well, spread by :func:`spread_gaussian`), minus what blooms out. float32 (H, W)
        (the input itself when there is neither)."""
        rate = np.asarray(rate_e_per_us)
        dark = np.float32(self.dark_current_e_per_s * 1e-6)
        out = rate.astype(np.float32) + dark if dark > 0 else rate
        if self.blooming <= 0 or rate.ndim != 2:
            return out
        limit = np.float32(self.full_well_e / exposure_us)
        if not float(np.max(out)) > limit:
            return out
        excess = np.maximum(out - limit, np.float32(0.0)) * np.float32(self.blooming)
        sigma = self.bloom_sigma_px * rate.shape[1] / 1920.0
        return (out - excess + spread_gaussian(excess, sigma)).astype(np.float32)

    def veil(self, rate_e_per_us: np.ndarray) -> np.ndarray:
        """The image with the lens's veiling glare: ``(1 - v) rate + v (mean / 2 + broad blur / 2)``, v =
        ``veiling_glare``, per Bayer plane of the mosaic (the light is spread before the colour filters: a pixel
        gets the glare of its own colour); the light it spreads is taken from the image (energy is kept). float32
        (H, W), H and W even."""
        v = self.veiling_glare
        rate = np.asarray(rate_e_per_us, np.float32)
        if v <= 0 or rate.ndim != 2 or rate.shape[0] % 2 or rate.shape[1] % 2:
            return rate
        out = rate * np.float32(1.0 - v)
        for r in (0, 1):
            for c in (0, 1):
                plane = np.ascontiguousarray(rate[r::2, c::2])
                means: list[float] = []
                spread = broad_blur(plane, plane.shape[1] / 6.0, mean_out=means)
                spread += np.float32(means[0])
                spread *= np.float32(0.5 * v)
                out[r::2, c::2] += spread
        return out

    def to_dict(self) -> dict:
        """JSON-serialisable parameters, plus derived constants and the formula."""
        d = asdict(self)
        d["qe_rgb"] = list(self.qe_rgb)
        d["vignetting"] = list(self.vignetting)
        d["gain_e_per_dn"] = self.gain_e_per_dn
        d["saturated_code"] = SATURATED_CODE
        d["bayer"] = "RGGB"
        d["radiance_unit"] = "photo-electrons per microsecond on a pixel of QE 1 at the principal point"
        d["formula"] = ("rate = veil(radiance*qe[c]*vignetting); e = (rate + dark current)*t_us + blooming + shot "
                        "noise + read noise; level = clip(round(black + e/gain_e_per_dn), 0, 4095); code = lut[level] "
                        "(srgb: floor(4095*OETF(level/4095)))")
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


def _blur_rows(a: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Rows of ``a`` (float32 (H, W)) convolved with symmetric ``taps`` (odd length), edges replicated: elementwise
    sums in a fixed order (the same bits on every CPU)."""
    r = taps.size // 2
    padded = np.pad(a, ((0, 0), (r, r)), mode="edge")
    w = a.shape[1]
    out = padded[:, 0:w] * np.float32(taps[0])
    for k in range(1, taps.size):
        out += padded[:, k:k + w] * np.float32(taps[k])
    return out


def spread_gaussian(a: np.ndarray, sigma_px: float) -> np.ndarray:
    """``a`` (float32 (H, W)) blurred by a Gaussian of ``sigma_px`` (sampled over +-3 sigma, at least the 3 taps of
    a 0.5 px one, normalised: the sum is kept). float32 (H, W)."""
    s = max(float(sigma_px), 0.5)
    r = max(1, int(np.ceil(3.0 * s)))
    weights = [math.exp(-0.5 * (k / s) ** 2) for k in range(-r, r + 1)]  # libm: the same on every CPU
    total = sum(weights)
    taps = np.array([w / total for w in weights])
    a = np.asarray(a, np.float32)
    return _blur_rows(_blur_rows(a, taps).T.copy(), taps).T.copy()


def broad_blur(a: np.ndarray, sigma_px: float, cells: int = 32, mean_out: list[float] | None = None) -> np.ndarray:
    """A broad Gaussian blur of ``a`` (float32 (H, W)) cheaply: block means on a grid about ``cells`` blocks across,
    blurred there by ``sigma_px`` (in image pixels), then bilinearly interpolated back to every pixel. float32 (H, W).
    ``mean_out``: a list the mean of the block means is appended to (summed in order)."""
    a = np.asarray(a, np.float32)
    h, w = a.shape
    b = max(1, w // cells)
    gh, gw = max(1, h // b), max(1, w // b)
    crop = a[:gh * b, :gw * b].astype(np.float64)
    cols = crop[:, 0::b].copy()
    for k in range(1, b):  # elementwise sums in a fixed order: the same bits on every CPU
        cols += crop[:, k::b]
    grid = cols[0::b].copy()
    for k in range(1, b):
        grid += cols[k::b]
    grid *= 1.0 / (b * b)
    if mean_out is not None:
        total = 0.0
        for x in grid.ravel().tolist():
            total += x
        mean_out.append(total / grid.size)
    small = spread_gaussian(grid.astype(np.float32), sigma_px / b)
    # bilinear interpolation of the block centres ((i + 0.5) b - 0.5 in pixels) at every pixel, edges clamped
    def axis(n: int, g: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos = np.clip((np.arange(n, dtype=np.float64) + 0.5) / b - 0.5, 0.0, g - 1.0)
        i0 = np.minimum(np.floor(pos).astype(np.int64), max(g - 2, 0))
        f = (pos - i0).astype(np.float32) if g > 1 else np.zeros(n, np.float32)
        return i0, np.minimum(i0 + 1, g - 1), f

    r0, r1, fr = axis(h, gh)
    c0, c1, fc = axis(w, gw)
    top = small[r0][:, c0] * (np.float32(1.0) - fc) + small[r0][:, c1] * fc
    bottom = small[r1][:, c0] * (np.float32(1.0) - fc) + small[r1][:, c1] * fc
    return (top * (np.float32(1.0) - fr)[:, None] + bottom * fr[:, None]).astype(np.float32)
