"""The closed loop of one AE method, as a pure function: arrays in, steps out (no files, no processes, no plots).

Python API::

    from bracketry_emulator.ae.loop import Frame, run_loop
    steps = run_loop(method, sequences, lambda seq, target_us: Frame(emulated_uint16, seq.ts_ns, source_us))

At step k the method's current target exposure is emulated from ``sequences[k]`` (``emulate``), the method sees
that image and returns the next target, which is clamped to ``[min_exposure_us, max_exposure_us]``. A method that
sets the gain itself returns a :class:`~.base.CameraSetting`: its exposure is clamped to the same bounds, its gain to
``[0, max_gain_db]``, the next target is exposure x gain and ``emulate`` gets that gain too
(``emulate(sequence, target_us, gain_db)``; a method that returns exposures only never makes that call). The first
target is ``init_exposure_us``, or the method's own ``init_exposure_us`` attribute when it declares one
(``constant-<ms>``). With ``warmup_steps`` = n > 0 the method first takes n steps on the first sequence's view
(``warmup(target_us) -> Frame``, images not recorded, no :class:`Step` yielded): the walk then begins with a camera
that was already running, as a rig recording before the stretch being benchmarked (a short walk measures how a
method follows the light along it, not how fast it converges from the first target). How images are decoded,
cached, shared between methods or written is the caller's business (:mod:`.scheduler`, :mod:`.writers`);
:func:`iter_loop` yields each step as soon as it is taken, so a caller can interleave many methods over the same
sequence.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from bracketry_base.errors import BracketryError

from ..defaults import DEFAULT_INIT_EXPOSURE_US, DEFAULT_MAX_EXPOSURE_US, DEFAULT_MAX_GAIN_DB, DEFAULT_MIN_EXPOSURE_US
from .base import AEMethod, gain_exposure_us

S = TypeVar("S")


@dataclass(frozen=True)
class Frame:
    """The image the AE camera delivers at one step (what ``emulate`` returns).

    Attributes:
        image: np.ndarray uint16 HxW, raw RGGB Bayer codes 0..4095, emulated at the requested target exposure.
        timestamp_ns: int, timestamp of the frame (ns; that of its source bracket frame).
        source_exposure_us: int, the recorded bracket (us) the image was emulated from.
        sequence_index: int, the dataset's index of the bracket sequence (-1 when unknown).
        meta: further entries of the method's ``meta`` (e.g. ``response``, ``side``, ``shared_gray``; see
            :mod:`.base`).
        gain_db: float, the analog gain the image stands for (dB; beyond the longest bracket the emulator takes
            that bracket's exposure and the rest as gain, see :mod:`..emulation.emulator`).
    """

    image: np.ndarray
    timestamp_ns: int
    source_exposure_us: int
    sequence_index: int = -1
    meta: Mapping[str, Any] = field(default_factory=dict)
    gain_db: float = 0.0


@dataclass(frozen=True)
class Step:
    """One closed-loop step of one method.

    Attributes:
        step: int, 0-based position of the sequence in the run.
        sequence_index: int, the dataset's index of the sequence.
        timestamp_ns: int, timestamp of the frame the method saw (ns).
        exposure_us: float, the target exposure of this step (us), the one the image was emulated at.
        next_exposure_us: float, the method's answer after clamping to the bounds (us): the next step's target.
        source_exposure_us: int, the bracket the image was emulated from (us).
        ae_s: float, wall time of the method's ``next_exposure_us`` call (s; the only non-deterministic field).
        gain_db: float, the analog gain the step's image stands for (dB): the camera's exposure was
            ``exposure_us / 10**(gain_db / 20)``.
        next_gain_db: float | None, the gain the method set for the next step (dB, after clamping;
            ``next_exposure_us`` is then exposure x gain); None: it returned an exposure only.
        saturated_share, dark_share: float, the shares of the step's image at or above :data:`SATURATED_CODE` and
            below :data:`DARK_CODE` (:func:`image_shares`; NaN when not measured).
    """

    step: int
    sequence_index: int
    timestamp_ns: int
    exposure_us: float
    next_exposure_us: float
    source_exposure_us: int
    ae_s: float
    gain_db: float = 0.0
    next_gain_db: float | None = None
    saturated_share: float = float("nan")
    dark_share: float = float("nan")

    @property
    def next_camera_exposure_us(self) -> float:
        """The exposure (us) the next step's camera takes when the method set the gain (``next_exposure_us`` /
        10^(next_gain_db / 20)); else ``next_exposure_us`` (the emulator splits it)."""
        return gain_exposure_us(self.next_exposure_us, self.next_gain_db)


#: 12-bit code from which a pixel counts as saturated (8-bit 252 and up: the image's top few levels, where the
#: response has clipped and no gradient survives)
SATURATED_CODE = 4032
#: 12-bit code below which a pixel counts as dark (8-bit below 10: within twice FAST's smallest threshold, 5, of
#: black, where noise is most of what a corner test sees)
DARK_CODE = 160


def image_shares(image: np.ndarray) -> tuple[float, float]:
    """(saturated share, dark share) of a uint16 HxW 12-bit mosaic: the fractions of its pixels at or above
    :data:`SATURATED_CODE` and below :data:`DARK_CODE` (floats in [0, 1]; NaN for an empty image)."""
    n = image.size
    if n == 0:
        return float("nan"), float("nan")
    return (float(np.count_nonzero(image >= SATURATED_CODE)) / n, float(np.count_nonzero(image < DARK_CODE)) / n)


def initial_exposure_us(method: AEMethod, default_us: float = DEFAULT_INIT_EXPOSURE_US) -> float:
    """The first target (us) of ``method``: its own ``init_exposure_us`` attribute when set, else ``default_us``."""
    return float(getattr(method, "init_exposure_us", None) or default_us)


def iter_loop(method: AEMethod, sequences: Iterable[S], emulate: Callable[..., Frame], *,
              init_exposure_us: float = DEFAULT_INIT_EXPOSURE_US,
              min_exposure_us: float = DEFAULT_MIN_EXPOSURE_US, max_exposure_us: float = DEFAULT_MAX_EXPOSURE_US,
              name: str | None = None, start: int = 0, warmup_steps: int = 0,
              warmup: Callable[..., Frame] | None = None,
              max_gain_db: float = DEFAULT_MAX_GAIN_DB) -> Iterator[Step]:
    """The closed loop of ``method`` over ``sequences``, one :class:`Step` per sequence, lazily.

    ``emulate(sequence, target_us) -> Frame`` gives the image the camera would deliver at ``target_us``; it is
    called once per step, before the method (``emulate(sequence, target_us, gain_db)`` after a method set the gain,
    see the module docstring). The method is ``reset`` to its first target (see :func:`initial_exposure_us`). Its
    ``meta`` holds ``step``, ``timestamp_ns``, ``sequence_index``, ``source_exposure_us``, ``bounds_us``,
    ``gain_db``, ``camera_exposure_us`` and the frame's own ``meta`` entries. ``name`` (default: the method's
    ``name``) is used in error messages; ``start`` numbers the first step. ``warmup_steps`` > 0 needs ``warmup``:
    the first sequence's image at a target (called as ``emulate`` is, without the sequence; those calls' ``meta``
    have ``warmup`` True and negative ``step``).

    Raises BracketryError (one line) when the method raises or returns a non-finite exposure or gain.
    """
    label = name or getattr(method, "name", "?")
    target = initial_exposure_us(method, init_exposure_us)
    gain: float | None = None  # the gain the method set (dB); None: it sets exposures only
    method.reset(target)
    bounds = (min_exposure_us, max_exposure_us)
    if warmup_steps > 0 and warmup is None:
        raise ValueError("warmup_steps > 0 needs a warmup function (the first view at a target)")

    def answer(frame: Frame, target_us: float, k: int, extra: dict[str, Any]) -> tuple[float, float | None, float]:
        meta = {"step": k, "timestamp_ns": frame.timestamp_ns, "sequence_index": frame.sequence_index,
                "source_exposure_us": frame.source_exposure_us, "bounds_us": bounds, "gain_db": frame.gain_db,
                "camera_exposure_us": gain_exposure_us(target_us, frame.gain_db), **frame.meta, **extra}
        t0 = time.perf_counter()
        try:
            raw = method.next_exposure_us(frame.image, target_us, meta)
            exposure, asked = (float(raw[0]), float(raw[1])) if isinstance(raw, tuple) else (float(raw), None)
        except BracketryError:
            raise
        except Exception as exc:
            raise BracketryError(f"AE method {label} failed at step {k}: {type(exc).__name__}: {exc}") from exc
        ae_s = time.perf_counter() - t0
        if not np.isfinite(exposure):
            raise BracketryError(f"AE method {label} returned a non-finite exposure at step {k}")
        if asked is not None and not np.isfinite(asked):
            raise BracketryError(f"AE method {label} returned a non-finite gain at step {k}")
        exposure = float(np.clip(exposure, min_exposure_us, max_exposure_us))
        if asked is None:
            return exposure, None, ae_s
        asked = float(np.clip(asked, 0.0, max_gain_db))
        return exposure * float(10.0 ** (asked / 20.0)), asked, ae_s

    def take(shoot: Callable[..., Frame], *args: Any) -> Frame:
        return shoot(*args, target) if gain is None else shoot(*args, target, gain)

    it = iter(sequences)
    if warmup_steps > 0:
        assert warmup is not None
        for w in range(warmup_steps):  # on the first view, before the walk: nothing recorded
            target, gain, _ = answer(take(warmup), target, start - warmup_steps + w, {"warmup": True})
    for k, seq in enumerate(it, start):
        frame = take(emulate, seq)
        nxt, nxt_gain, ae_s = answer(frame, target, k, {})
        yield Step(k, frame.sequence_index, frame.timestamp_ns, target, nxt, frame.source_exposure_us, ae_s,
                   frame.gain_db, nxt_gain, *image_shares(frame.image))
        target, gain = nxt, nxt_gain


def run_loop(method: AEMethod, sequences: Iterable[S], emulate: Callable[..., Frame], *,
             init_exposure_us: float = DEFAULT_INIT_EXPOSURE_US, min_exposure_us: float = DEFAULT_MIN_EXPOSURE_US,
             max_exposure_us: float = DEFAULT_MAX_EXPOSURE_US, name: str | None = None,
             warmup_steps: int = 0, max_gain_db: float = DEFAULT_MAX_GAIN_DB) -> list[Step]:
    """Every :class:`Step` of ``method`` over ``sequences`` (see :func:`iter_loop`; the warm-up, if any, on the
    first sequence through ``emulate``)."""
    seqs = list(sequences)

    def first_view(*request: float) -> Frame:
        return emulate(seqs[0], *request)

    return list(iter_loop(method, seqs, emulate, init_exposure_us=init_exposure_us,
                          min_exposure_us=min_exposure_us, max_exposure_us=max_exposure_us, name=name,
                          warmup_steps=warmup_steps if seqs else 0, warmup=first_view, max_gain_db=max_gain_db))


@dataclass
class MethodRun:
    """The result of one method: its steps, and their summary."""

    method: str
    steps: list[Step] = field(default_factory=list)

    @property
    def exposures_ms(self) -> list[float]:
        """The target exposure of every step (ms)."""
        return [s.exposure_us / 1000.0 for s in self.steps]

    def summary(self) -> dict[str, Any]:
        """Step count, exposure (ms: first, last, mean, min, max) and AE cost per step (ms: median, mean)."""
        exp = np.array(self.exposures_ms) if self.steps else np.zeros(0)
        cost = np.array([s.ae_s for s in self.steps]) * 1000.0 if self.steps else np.zeros(0)
        return {"method": self.method, "steps": len(self.steps),
                "exposure_ms": {"first": float(exp[0]) if exp.size else None,
                                "last": float(exp[-1]) if exp.size else None,
                                "mean": float(exp.mean()) if exp.size else None,
                                "min": float(exp.min()) if exp.size else None,
                                "max": float(exp.max()) if exp.size else None},
                "ae_ms_per_step": {"median": float(np.median(cost)) if cost.size else None,
                                   "mean": float(cost.mean()) if cost.size else None}}
