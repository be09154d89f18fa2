"""The exposure emulator: I_target = f((t_target / t_source) * f^-1(I_source)) on the raw Bayer mosaic.

Python API::

    from bracketry_emulator.emulation import Emulator, EmulatorConfig
    emu = Emulator(EmulatorConfig(selection="highernosat"))         # or "upstream", "fusion"
    out = emu.emulate(seq.load("left"), target_us=6000.0)
    out.image            # uint16 HxW Bayer codes 0..4095
    out.source_exposure_us, out.factor, out.selection

Selection modes: ``highernosat`` (the paper, default), ``upstream`` (the authors' closer_least_sat), ``fusion``
(per-pixel noise-weighted irradiance from the bounding brackets or all brackets, zero weight at saturation, optional
global motion compensation; see :mod:`.fusion`).

Gain: a target beyond the longest bracket is emulated as the camera would take it with that bracket's exposure and
an analog gain (``beyond="gain"``, the default): exposure = the longest bracket, gain = target / longest (times any
``gain_db``), the image's signal scaled by the gain and the noise the sensor's noise model gives at that exposure and
gain (the scaled longest bracket already has it; fusion's less noisy irradiance gets the missing part added).
``EmulatedImage.exposure_us`` / ``gain_db`` record what the camera would have been set to (steps.csv).
``beyond="extrapolate"`` records the target as an exposure (the signal is the same).

Motion blur (``blur=True``, given the brackets' mid-exposure stamps): a camera exposure longer than the source
bracket gets the blur of the missing time from the image velocity between the source and its nearest bracket in time
(:mod:`.blur`).

``parity="upstream"`` reproduces the authors' output bit-exactly
(with ``crf`` = their pcalib file: upstream lifting, truncation, no cap at the saturated code).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from bracketry_base.errors import BracketryError

from ..crf import Lifting, Response, load_response
from ..crf.response import Rounding
from ..dataset.model import BracketSequence
from ..defaults import FUSION_BRACKETS, SELECTIONS
from .align import Motion
from .blur import STEP_PX, Velocity, add_motion_blur, image_velocity
from .fusion import FusionBrackets, FusionResult, fuse, fusion_brackets
from .kernel import LutCache, apply_lut
from .noise import NoiseModel
from .selection import SatCount, saturation_fraction, select_highernosat, select_upstream

Selection = Literal["highernosat", "upstream", "fusion"]
Parity = Literal["default", "upstream"]


@dataclass(frozen=True)
class EmulatorConfig:
    """Emulator settings.

    Attributes:
        selection: "highernosat" | "upstream" | "fusion".
        crf: "srgb" (the sample's sRGB-encoded codes) or a path to a pcalib.txt (256 or 4096 values).
        parity: "default" (round to the nearest code, cap at the saturated code) or "upstream" (the authors'
            formula: pcalib upstream lifting, truncation, 4094 as the saturated code for selection).
        gain_db: emulated analog gain in dB (0 = none); scales the signal and adds the missing noise.
        depth: 12 or 8, the bit depth of written images (emulation itself is always on 12-bit codes).
        alpha: HigherNoSat saturation threshold (fraction of pixels).
        sat_count: HigherNoSat saturation count: "over" (code >= saturated code) or "both" (also code 0).
        fusion_brackets: "longer" (the pair around the target and every longer bracket), "bounding" (the pair) or
            "all".
        motion: fusion motion compensation between brackets: "none", "translation" or "homography".
        deghost_sigma: fusion: drop a non-reference bracket's pixel that disagrees with the reference bracket by more
            than this many noise standard deviations (None = off).
        noise: camera noise model (linear DN); used by fusion weights and gain emulation.
        add_noise: add the noise the emulated image lacks (default: only when gain_db != 0).
        seed: seed of the added noise (deterministic per call).
        beyond: a target beyond the longest bracket: "gain" (the longest bracket's exposure plus analog gain, with
            the noise model's noise) or "extrapolate" (recorded as the target exposure).
        blur: emulate the motion blur of a camera exposure longer than the source bracket (needs the brackets'
            timestamps: ``times_ns`` of :meth:`Emulator.emulate`).
    """

    selection: Selection = "highernosat"
    crf: str | Path = "srgb"
    parity: Parity = "default"
    gain_db: float = 0.0
    depth: int = 12
    alpha: float = 0.01
    sat_count: SatCount = "over"
    fusion_brackets: FusionBrackets = "longer"
    motion: Motion = "none"
    deghost_sigma: float | None = None
    noise: NoiseModel = field(default_factory=NoiseModel)
    add_noise: bool | None = None
    seed: int = 0
    beyond: Literal["gain", "extrapolate"] = "gain"
    blur: bool = False

    def validate(self) -> None:
        """Raise BracketryError on an invalid combination (one clear line)."""
        if self.selection not in SELECTIONS:
            raise BracketryError(f"unknown selection {self.selection!r} (use {', '.join(SELECTIONS)})")
        if self.parity not in ("default", "upstream"):
            raise BracketryError(f"unknown parity {self.parity!r} (use default or upstream)")
        if self.depth not in (8, 12):
            raise BracketryError(f"depth must be 12 or 8, got {self.depth}")
        if not 0.0 <= self.alpha <= 1.0:
            raise BracketryError(f"alpha must be in [0, 1], got {self.alpha}")
        if self.motion not in ("none", "translation", "homography"):
            raise BracketryError(f"unknown motion compensation {self.motion!r}")
        if self.fusion_brackets not in FUSION_BRACKETS:
            raise BracketryError(f"unknown fusion bracket set {self.fusion_brackets!r}")
        if self.beyond not in ("gain", "extrapolate"):
            raise BracketryError(f"unknown rule beyond the longest bracket {self.beyond!r} (use gain or extrapolate)")
        if self.parity == "upstream" and self.selection == "fusion":
            raise BracketryError("--parity upstream reproduces single-bracket emulation; it cannot be used with fusion")


@dataclass(frozen=True)
class EmulatedImage:
    """One emulated image.

    Attributes:
        image: np.ndarray uint16 HxW, raw RGGB Bayer codes 0..4095.
        target_us: requested exposure time (us).
        source_exposure_us: the bracket used (fusion: the reference bracket, whose geometry and timestamp the
            image has).
        factor: target_us / source_exposure_us (times the gain when gain_db != 0).
        selection: the selection mode that produced it.
        brackets_us: every bracket that contributed (one for single-bracket modes).
        exposure_us: the camera exposure the image stands for (us; ``target_us`` unless gain stands in for the
            exposure beyond the longest bracket); 0 = ``target_us``.
        gain_db: the analog gain the image stands for (dB; 0 = none).
    """

    image: np.ndarray
    target_us: float
    source_exposure_us: int
    factor: float
    selection: str
    brackets_us: tuple[int, ...] = ()
    exposure_us: float = 0.0
    gain_db: float = 0.0

    @property
    def camera_exposure_us(self) -> float:
        """The camera exposure (us) the image stands for."""
        return self.exposure_us or self.target_us

    def to_depth(self, depth: int) -> np.ndarray:
        """The image at ``depth`` bits: 12 -> uint16 codes as is; 8 -> uint8(code / 16) (truncation, as upstream)."""
        if depth == 12:
            return self.image
        if depth == 8:
            return (self.image >> 4).astype(np.uint8)
        raise ValueError(f"depth must be 12 or 8, got {depth}")


class Emulator:
    """Emulates images at any exposure from one sequence's brackets (see the module docstring)."""

    def __init__(self, config: EmulatorConfig | None = None, response: Response | None = None) -> None:
        self.config = config or EmulatorConfig()
        self.config.validate()
        lifting: Lifting = "upstream" if self.config.parity == "upstream" else "tum"
        if response is None:
            try:
                response = load_response(self.config.crf, lifting=lifting)
            except ValueError as exc:
                raise BracketryError(f"bad camera response {self.config.crf}: {exc}") from exc
        self.response = response
        self.rounding: Rounding = "trunc" if self.config.parity == "upstream" else "round"
        self._luts = LutCache(response)
        # fused irradiance per (bracket images, reference): independent of the target, reused across targets. The
        # cache holds the arrays themselves so their ids stay unique while cached.
        self._fusion_cache: list[tuple[tuple[np.ndarray, ...], int, FusionResult]] = []
        self._sat_cache: list[tuple[np.ndarray, str, float]] = []
        self._velocity_cache: list[tuple[np.ndarray, np.ndarray, Velocity]] = []

    @property
    def gain(self) -> float:
        """Linear gain 10^(gain_db / 20)."""
        return float(10.0 ** (self.config.gain_db / 20.0))

    @property
    def adds_noise(self) -> bool:
        """True when emulated images get the missing noise added (gain emulation)."""
        return self.config.add_noise if self.config.add_noise is not None else self.config.gain_db != 0.0

    def select(self, images: dict[int, np.ndarray], target_us: float) -> int:
        """The source bracket (exposure_us) of a single-bracket selection mode for ``target_us``."""
        exps = sorted(images)
        count: SatCount = "both" if self.config.selection == "upstream" else self.config.sat_count
        fractions = {e: self._saturation(images[e], count) for e in exps}
        if self.config.selection == "upstream":
            return select_upstream(exps, target_us, fractions)
        return select_highernosat(exps, target_us, fractions, self.config.alpha)

    def _saturation(self, image: np.ndarray, count: SatCount) -> float:
        """Saturated fraction of one bracket, cached per array (the cache holds the array, so ids stay unique)."""
        for arr, cached_count, value in self._sat_cache:
            if arr is image and cached_count == count:
                return value
        value = saturation_fraction(image, self.response.saturated_code, count)
        self._sat_cache.append((image, count, value))
        del self._sat_cache[:-32]
        return value

    def _rng(self, target_us: float, source_us: int) -> np.random.Generator:
        return np.random.default_rng([self.config.seed, round(target_us * 1000), int(source_us)])

    def select_stereo(self, images: dict[str, dict[int, np.ndarray]], target_us: float,
                      decide: tuple[str, ...] | None = None) -> int:
        """ONE source bracket (exposure_us) for every camera of a stereo step, so that the step's left and right
        images come from the same capture (same bracket, same timestamp; also the fusion reference).

        ``images``: {side: {exposure_us: uint16 HxW}} (the same bracket set per side). The decision uses, per
        bracket, the LARGEST saturated fraction over the cameras in ``decide`` (default: every side), so a bracket
        is only used when it is acceptable for both cameras. ``decide=("left",)`` reproduces a single camera's own
        decision (the authors' left emulator, ``--parity upstream``).
        """
        sides = tuple(decide) if decide else tuple(images)
        per_side = {side: images[side] for side in sides}
        exps = sorted(next(iter(per_side.values())))
        if any(sorted(imgs) != exps for imgs in per_side.values()):
            raise BracketryError("the cameras of a stereo step have different bracket sets")
        if len(exps) == 1:
            return exps[0]
        count: SatCount = "both" if self.config.selection == "upstream" else self.config.sat_count
        fractions = {e: max(self._saturation(imgs[e], count) for imgs in per_side.values()) for e in exps}
        if self.config.selection == "upstream":
            return select_upstream(exps, target_us, fractions)
        return select_highernosat(exps, target_us, fractions, self.config.alpha)

    def emulate(self, images: dict[int, np.ndarray], target_us: float, source_us: int | None = None,
                times_ns: Mapping[int, int] | None = None, gain_db: float | None = None) -> EmulatedImage:
        """Emulate the image at ``target_us`` from ``{exposure_us: uint16 HxW Bayer codes}`` (one sequence).

        ``source_us``: the source bracket (fusion: the reference bracket) decided by the caller, e.g. once for both
        cameras by :meth:`select_stereo`; None = this camera's own selection. ``times_ns``: {exposure_us:
        mid-exposure stamp (ns)} of the brackets, for ``blur`` (without it no blur is emulated). ``gain_db``: the analog
        gain the camera takes for ``target_us`` (an exposure-equivalent: the camera exposes ``target_us`` /
        10^(gain_db / 20)), as a method that asks for gain sets it; the source is chosen for that exposure and the
        image amplified by the gain with the sensor's noise (:meth:`exposure_and_gain`). None: the emulator's own split.
        Do not modify the bracket arrays in place between calls (fusion caches its irradiance map per array set).
        Raises BracketryError for no brackets, a non-positive target, mismatched image shapes or a ``source_us``
        that is not among the brackets.
        """
        if not images:
            raise BracketryError("no bracket images to emulate from")
        if not target_us > 0 or not np.isfinite(target_us):
            raise BracketryError(f"target exposure must be a positive number of us, got {target_us}")
        if len({img.shape for img in images.values()}) != 1:
            raise BracketryError("bracket images have different shapes")
        if source_us is not None and source_us not in images:
            raise BracketryError(f"source bracket {source_us} us is not among the brackets {sorted(images)}")
        if self.config.selection == "fusion" and len(images) >= 2:
            return self._emulate_fusion(images, target_us, source_us, times_ns, gain_db)
        exposure_us, gain = self.exposure_and_gain(images, target_us, gain_db)
        if source_us is not None:
            source = int(source_us)
        else:
            chosen_for = target_us if gain_db is None else exposure_us
            source = self.select(images, chosen_for) if len(images) > 1 else next(iter(images))
        factor = exposure_us / source
        total = factor * gain
        src = images[source]
        velocity = self._velocity(images, source, times_ns) if exposure_us > source else None
        if velocity is not None and velocity.max_px((exposure_us - source) * 1e-6) >= STEP_PX:
            blurred = add_motion_blur(self.response.icrf[src], velocity, (exposure_us - source) * 1e-6,
                                      source * 1e-6)
            linear = total * blurred.astype(np.float64)
            if self._adds_noise(gain):
                missing = self._missing_variance(blurred, factor, gain)
                linear += self._rng(target_us, source).standard_normal(src.shape) * np.sqrt(missing)
            image = self.response.encode(linear, self.rounding)
        elif self._adds_noise(gain) and not (factor == 1.0 and self.config.add_noise is None):
            linear = total * self.response.icrf[src]
            missing = self._missing_variance(self.response.icrf[src], factor, gain)
            linear += self._rng(target_us, source).standard_normal(src.shape) * np.sqrt(missing)
            image = self.response.encode(linear, self.rounding)
        else:  # the source bracket's own noise, scaled, is the camera's at this exposure and gain
            image = apply_lut(self._luts.get(total, self.rounding), src)
        return EmulatedImage(image, float(target_us), int(source), float(total), self.config.selection, (int(source),),
                             float(exposure_us), _db(gain))

    def exposure_and_gain(self, images: dict[int, np.ndarray], target_us: float,
                          gain_db: float | None = None) -> tuple[float, float]:
        """(camera exposure us, linear analog gain) that stand for ``target_us``: beyond the longest bracket with
        ``beyond="gain"``, the longest bracket's exposure and the rest as gain; times the configured gain. With
        ``gain_db`` (a method's own request, >= 0): ``target_us`` / 10^(gain_db / 20) and that gain (and beyond the
        longest bracket, under ``beyond="gain"``, the rest as more gain)."""
        longest = max(images)
        asked = 1.0 if gain_db is None else float(10.0 ** (float(gain_db) / 20.0))
        exposure = target_us / asked
        if self.config.beyond == "gain" and exposure > longest:
            return float(longest), self.gain * target_us / longest
        return float(exposure), self.gain * asked

    def _velocity(self, images: dict[int, np.ndarray], source: int, times_ns: Mapping[int, int] | None
                  ) -> Velocity | None:
        """The image velocity of bracket ``source`` from the bracket nearest to it in time (None without ``blur``,
        stamps or another bracket); cached per pair of arrays."""
        if not self.config.blur or times_ns is None or source not in times_ns:
            return None
        others = [e for e in images if e != source and e in times_ns and times_ns[e] != times_ns[source]]
        if not others:
            return None
        other = min(others, key=lambda e: (abs(times_ns[e] - times_ns[source]), e))
        a, b = images[source], images[other]
        for ca, cb, v in self._velocity_cache:
            if ca is a and cb is b:
                return v
        sat = self.response.saturated_code
        v = image_velocity(self.response.icrf[a], source, times_ns[source], a < sat,
                           self.response.icrf[b], other, times_ns[other], b < sat)
        self._velocity_cache.append((a, b, v))
        del self._velocity_cache[:-8]
        return v

    def _adds_noise(self, gain: float) -> bool:
        return self.config.add_noise if self.config.add_noise is not None else gain != 1.0

    def emulate_sequence(self, seq: BracketSequence, target_us: float, sides: tuple[str, ...] | None = None
                         ) -> dict[str, EmulatedImage]:
        """Load one sequence's brackets and emulate every side at ``target_us``: {side: EmulatedImage}, all sides
        from ONE source bracket (:meth:`select_stereo`).

        Ready for :meth:`RunWriter.write_step`. Loads the PNGs each call; keep ``seq.load(side)`` yourself and call
        :meth:`emulate` to emulate several targets from the same brackets.
        """
        loaded = {side: seq.load(side) for side in (sides or seq.sides)}
        source = self.select_stereo(loaded, target_us)
        return {side: self.emulate(imgs, target_us, source) for side, imgs in loaded.items()}

    def _missing_variance(self, source_linear: np.ndarray, factor: float, gain: float | None = None) -> np.ndarray:
        """Variance (DN^2) the target frame (exposure ``factor`` x the source's, linear ``gain``; default the
        configured one) has but the scaled source lacks (>= 0), per pixel."""
        g = self.gain if gain is None else gain
        nm = self.config.noise
        target_var = nm.variance(factor * source_linear, g)
        have = (g * factor) ** 2 * nm.variance(source_linear)
        return np.maximum(target_var - have, 0.0)

    def _emulate_fusion(self, images: dict[int, np.ndarray], target_us: float, ref_us: int | None = None,
                        times_ns: Mapping[int, int] | None = None, gain_db: float | None = None) -> EmulatedImage:
        exposure_us, g = self.exposure_and_gain(images, target_us, gain_db)
        chosen_for = target_us if gain_db is None else exposure_us  # the brackets of the camera's own exposure
        ref = int(ref_us) if ref_us is not None else self.select(images, chosen_for)
        used = fusion_brackets(list(images), chosen_for, self.config.fusion_brackets)
        key = tuple(images[e] for e in sorted({*used, ref}))
        result = None
        for arrays, cached_ref, cached in self._fusion_cache:
            if cached_ref == ref and len(arrays) == len(key) and all(a is b for a, b in zip(arrays, key, strict=True)):
                result = cached
                break
        if result is None:
            result = fuse(images, chosen_for, self.response, self.config.noise, reference_us=ref,
                          brackets=self.config.fusion_brackets, motion=self.config.motion,
                          deghost_sigma=self.config.deghost_sigma)
            self._fusion_cache.append((key, ref, result))
            del self._fusion_cache[:-4]
        irradiance = result.irradiance
        velocity = self._velocity(images, ref, times_ns) if exposure_us > ref else None
        if velocity is not None:
            irradiance = add_motion_blur(irradiance, velocity, (exposure_us - ref) * 1e-6, ref * 1e-6)
        linear = irradiance * (exposure_us * g)
        if self._adds_noise(g):
            target_var = self.config.noise.variance(irradiance * exposure_us, g)
            have = (g * exposure_us) ** 2 * result.variance
            missing = np.maximum(target_var - have, 0.0)
            linear = linear + self._rng(target_us, ref).standard_normal(linear.shape) * np.sqrt(missing)
        image = self.response.encode(linear, self.rounding)
        return EmulatedImage(image, float(target_us), int(ref), float(exposure_us / ref * g), "fusion",
                             result.brackets_us, float(exposure_us), _db(g))


def _db(gain: float) -> float:
    """A linear gain in dB (0.0 for unity, exactly)."""
    return 0.0 if gain == 1.0 else float(20.0 * np.log10(gain))
