"""The emulator of a closed-loop worker: each result computed once per sequence, shared by every method.

Many methods (and, after convergence, many steps) ask for the same target from the same sequence: the step's source
bracket, each side's emulated image and its gray conversions are computed once per (sequence, side, target); each
bracket's saturated fraction once per decoded bracket. Same rules and results as
:meth:`~..emulation.Emulator.select_stereo` and :meth:`~..emulation.Emulator.emulate`.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Mapping

import numpy as np

from ..emulation import EmulatedImage, Emulator, EmulatorConfig
from ..emulation.selection import SatCount, saturation_fraction
from .base import SharedGray, gain_exposure_us


class _SaturationCachingEmulator(Emulator):
    """:class:`Emulator` whose bracket selection reuses each bracket's saturated fraction (keyed by array identity:
    call :meth:`clear` before the arrays are refilled)."""

    def __init__(self, config: EmulatorConfig) -> None:
        super().__init__(config)
        self._sat: dict[tuple[int, str], float] = {}

    def clear(self) -> None:
        self._sat.clear()

    def _saturation(self, image: np.ndarray, count: SatCount) -> float:
        key = (id(image), count)
        val = self._sat.get(key)
        if val is None:
            val = saturation_fraction(image, self.response.saturated_code, count)
            self._sat[key] = val
        return val


class EmulationCache:
    """The emulator plus per-sequence caches: source selection, emulated images and their gray conversions.

    Cache keys use the sequence's position (``seq_index``) and array identity: call :meth:`clear` before the frame
    arrays of another sequence are filled in."""

    def __init__(self, config: EmulatorConfig) -> None:
        self.emulator = _SaturationCachingEmulator(config)
        self._cache: dict[tuple[int, str, float, float | None], EmulatedImage] = {}
        self._gray: dict[tuple[int, str, float, float | None], SharedGray] = {}
        self._source: dict[tuple[int, float], int] = {}

    def clear(self) -> None:
        """Forget the sequence."""
        self._cache.clear()
        self._source.clear()
        self._gray.clear()
        self.emulator.clear()

    def source(self, seq_index: int, images: dict[str, dict[int, np.ndarray]], target_us: float,
               decide: tuple[str, ...] | None) -> int:
        """The step's ONE source bracket (us) for every camera (:meth:`Emulator.select_stereo`), cached per target.

        ``images``: {side: {exposure_us: uint16 HxW}}."""
        key = (seq_index, float(target_us))
        hit = self._source.get(key)
        if hit is None:
            hit = self._source[key] = self.emulator.select_stereo(images, target_us, decide)
        return hit

    def stereo(self, seq_index: int, brackets: dict[str, dict[int, np.ndarray]], target_us: float,
               ae_camera: str, times_ns: Mapping[str, Mapping[int, int]] | None = None,
               gain_db: float | None = None) -> dict[str, EmulatedImage]:
        """Every side of ``brackets`` ({side: {exposure_us: uint16 HxW}}: the sequence's brackets; only those
        :func:`needed_brackets` names are read) emulated at ``target_us``, all from ONE source bracket (one stereo
        capture). With ``parity`` upstream, ``ae_camera`` alone decides the source, as the authors' left emulator
        does (their right emulator decides on its own, which the joint decision corrects). ``times_ns``: {side:
        {exposure_us: mid-exposure stamp ns}} of the brackets, for the emulator's motion blur. ``gain_db``: the gain a
        method set (:meth:`Emulator.emulate`): the source is then chosen for the camera's exposure."""
        cfg = self.emulator.config
        chosen_for = gain_exposure_us(target_us, gain_db)
        needed = needed_brackets(tuple(next(iter(brackets.values()))), chosen_for, cfg.selection)
        subsets = {side: {e: frames[e] for e in needed} for side, frames in brackets.items()}
        decide = (ae_camera,) if cfg.parity == "upstream" else None
        source = self.source(seq_index, subsets, chosen_for, decide)
        return {side: self.emulate(seq_index, side, subsets[side], target_us, source,
                                   None if times_ns is None else times_ns.get(side), gain_db) for side in subsets}

    def ae_choice(self, ae_camera: str) -> Callable[[dict[int, np.ndarray], float], int]:
        """``(ae_images, target_us) -> source bracket (us)``: the decision :meth:`stereo` takes with ``parity``
        upstream, from ``ae_camera``'s brackets alone; callable on any thread (a new emulator per call: this
        cache's emulator belongs to the thread that calls :meth:`stereo`)."""
        config, response = self.emulator.config, self.emulator.response

        def choose(ae_images: dict[int, np.ndarray], target_us: float) -> int:
            return Emulator(config, response).select_stereo({ae_camera: ae_images}, target_us, (ae_camera,))

        return choose

    def emulate(self, seq_index: int, side: str, images: dict[int, np.ndarray], target_us: float,
                source_us: int | None = None, times_ns: Mapping[int, int] | None = None,
                gain_db: float | None = None) -> EmulatedImage:
        """:meth:`Emulator.emulate` of one side's brackets ``{exposure_us: uint16 HxW}``, cached per target (and
        gain a method set)."""
        key = (seq_index, side, float(target_us), gain_db)
        hit = self._cache.get(key)
        if hit is None:
            hit = self.emulator.emulate(images, target_us, source_us, times_ns, gain_db)
            self._cache[key] = hit
        return hit

    def shared_gray(self, seq_index: int, side: str, target_us: float, gain_db: float | None = None) -> SharedGray:
        """The gray-conversion memo of an image emulated by :meth:`emulate` (shared by the methods that see it)."""
        key = (seq_index, side, float(target_us), gain_db)
        shared = self._gray.get(key)
        if shared is None:
            shared = self._gray[key] = SharedGray(self._cache[key].image)
        return shared


def needed_brackets(exposures_us: tuple[int, ...], target_us: float, selection: str) -> tuple[int, ...]:
    """The brackets (us) that the emulation of ``target_us`` can use: all for fusion; for the single-bracket
    selections the nearest one outside the range, the exact match (highernosat), else the bracketing pair. The
    selection rules give the same source on this subset as on every bracket (see :mod:`..emulation.selection`)."""
    exps = sorted(exposures_us)
    if selection not in ("highernosat", "upstream"):
        return tuple(exps)
    i = bisect_left(exps, target_us)
    if i >= len(exps):
        return (exps[-1],)
    if i == 0:
        return (exps[0],)
    if selection == "highernosat" and (exps[i] == target_us or target_us >= exps[-1]):
        return (exps[i],)
    return exps[i - 1], exps[i]
