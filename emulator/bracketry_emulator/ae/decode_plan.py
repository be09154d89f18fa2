"""What a worker decodes for its methods' targets: a pure plan from a step's targets and a sequence's brackets to the
frames to decode.

A frame is ``(side index, exposure index)`` in the run's emulated sides and the sequence's ``exposures_us``. The
emulation of a target can use only some brackets (:func:`~.emulation_cache.needed_brackets`); a strategy turns the
targets into the frames that must be in the buffer before the step (:attr:`FramePlan.frames`) and, where one camera
alone decides the step's source bracket, the frames that wait for that decision (:attr:`FramePlan.picks`):

- :class:`EveryCamera`: every emulated camera decodes every bracket a target can use;
- :class:`AECameraPicks` (``--parity upstream`` with a single-bracket selection and more than one camera): the AE
  camera alone picks the source bracket of a pair, as the authors' emulator does, so the other cameras decode only
  the bracket it picks (:meth:`Pick.frames`, once the AE camera's pair is decoded and the pick is known).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

from .emulation_cache import needed_brackets

#: (side index, exposure index) of one frame of a sequence
FrameKey = tuple[int, int]

#: the selections whose source is one bracket (a target needs one bracket or the pair around it)
SINGLE_BRACKET_SELECTIONS = ("upstream", "highernosat")


@dataclass(frozen=True)
class Pick:
    """A target whose source bracket the AE camera picks from its candidates ``ae_frames`` (a pair); the other
    cameras then need that one bracket."""

    target_us: float
    ae_frames: tuple[FrameKey, ...]
    other_sides: tuple[int, ...]

    def frames(self, exp_i: int) -> tuple[FrameKey, ...]:
        """The other cameras' frames once the AE camera picked the bracket of exposure index ``exp_i``."""
        return tuple((si, exp_i) for si in self.other_sides)


@dataclass(frozen=True)
class FramePlan:
    """``frames``: to decode now (in this order, no repeats); ``picks``: decoded once the AE camera picked."""

    frames: tuple[FrameKey, ...]
    picks: tuple[Pick, ...] = ()


class DecodeStrategy(Protocol):
    def plan(self, exposures_us: tuple[int, ...], targets_us: Iterable[float]) -> FramePlan:
        """The frames of a sequence with brackets ``exposures_us`` that emulating ``targets_us`` needs."""
        ...


@dataclass(frozen=True)
class EveryCamera:
    """Every one of ``n_sides`` cameras decodes each bracket that a target can use (``selection``)."""

    selection: str
    n_sides: int

    def plan(self, exposures_us: tuple[int, ...], targets_us: Iterable[float]) -> FramePlan:
        exps = {e for t in targets_us for e in needed_brackets(exposures_us, t, self.selection)}
        return FramePlan(tuple((si, ei) for si in range(self.n_sides) for ei, e in enumerate(exposures_us)
                               if e in exps))


@dataclass(frozen=True)
class AECameraPicks:
    """The AE camera (side index ``ae_side``) decodes each bracket a target can use; a target with a pair of
    candidates becomes a :class:`Pick` for the other cameras, one with a single candidate is decoded by all."""

    selection: str
    n_sides: int
    ae_side: int

    def plan(self, exposures_us: tuple[int, ...], targets_us: Iterable[float]) -> FramePlan:
        every = EveryCamera(self.selection, self.n_sides)
        others = tuple(si for si in range(self.n_sides) if si != self.ae_side)
        frames: list[FrameKey] = []
        picks: list[Pick] = []
        for t in dict.fromkeys(float(t) for t in targets_us):
            keys = every.plan(exposures_us, (t,)).frames
            if len({ei for _, ei in keys}) > 1:
                ae = tuple(k for k in keys if k[0] == self.ae_side)
                frames += ae
                picks.append(Pick(t, ae, others))
            else:
                frames += keys
        return FramePlan(tuple(dict.fromkeys(frames)), tuple(picks))


def decode_strategy(selection: str, parity: str, n_sides: int, ae_side: int) -> DecodeStrategy:
    """The strategy of a run: :class:`AECameraPicks` where the AE camera alone decides the source bracket
    (``parity`` upstream, a single-bracket ``selection``, more than one camera), else :class:`EveryCamera`."""
    if parity == "upstream" and selection in SINGLE_BRACKET_SELECTIONS and n_sides > 1:
        return AECameraPicks(selection, n_sides, ae_side)
    return EveryCamera(selection, n_sides)
