"""Group frames into complete, time-ordered bracket sequences and match the camera sides by timestamp.

Rules (the authors group by sorted file index instead, which misaligns left and right on their own sample):
- per side, frames are sorted by timestamp; a sequence starts at a frame of the cycle's first bracket (the shortest
  exposure, or ``bracket_index == 0`` when the source records it) and takes the next N-1 frames (N = bracket count);
- it is complete when those N frames hold every exposure exactly once, in the cycle order, and no gap between two
  consecutive frames exceeds ``max_gap_factor`` x the median frame spacing;
- sides are matched by the timestamp of every bracket, within ``tolerance_ns``.
Anything that does not form a complete matched sequence is reported in ``problems`` (never silently dropped).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from .model import BracketSequence, DatasetError, Frame


def _median_spacing_ns(frames: Sequence[Frame]) -> float:
    if len(frames) < 2:
        return 0.0
    t = np.array([f.t_ns for f in frames], dtype=np.int64)
    return float(np.median(np.diff(t)))


def cycle_order(frames_by_side: dict[str, list[Frame]], exposures_us: Sequence[int]) -> tuple[int, ...]:
    """The order in time of the exposures in one cycle, starting with the shortest.

    Estimated as the most common successor of each exposure in the time-sorted frames of every side (data recorded
    1,2,4,...,32 gives the ascending order; a rig with another bracket table gives its order).
    """
    succ: dict[int, dict[int, int]] = {e: {} for e in exposures_us}
    for frames in frames_by_side.values():
        for a, b in itertools.pairwise(frames):
            succ[a.exposure_us][b.exposure_us] = succ[a.exposure_us].get(b.exposure_us, 0) + 1
    order = [min(exposures_us)]
    while len(order) < len(exposures_us):
        options = succ[order[-1]]
        nxt = max(options, key=lambda e: options[e]) if options else None
        if nxt is None or nxt in order:
            return tuple(sorted(exposures_us))  # no consistent cycle: fall back to ascending
        order.append(nxt)
    return tuple(order)


def split_side(frames: list[Frame], order: tuple[int, ...], max_gap_factor: float = 1.6
               ) -> tuple[list[list[Frame]], list[str]]:
    """Cut one side's time-sorted frames into complete cycles (each in ``order``); returns (cycles, problems)."""
    n = len(order)
    spacing = _median_spacing_ns(frames)
    cycles: list[list[Frame]] = []
    problems: list[str] = []
    i = 0
    orphans: list[Frame] = []
    while i < len(frames):
        f = frames[i]
        if f.exposure_us != order[0]:
            orphans.append(f)
            i += 1
            continue
        window = frames[i:i + n]
        exps = tuple(w.exposure_us for w in window)
        gaps_ok = all(spacing <= 0 or (b.t_ns - a.t_ns) <= max_gap_factor * spacing
                      for a, b in itertools.pairwise(window))
        if exps == order and gaps_ok:
            if orphans:
                problems.append(_orphan_message(orphans))
                orphans = []
            cycles.append(window)
            i += n
        else:
            orphans.append(f)
            i += 1
    if orphans:
        problems.append(_orphan_message(orphans))
    return cycles, problems


def _orphan_message(orphans: list[Frame]) -> str:
    side = orphans[0].side
    exps = ",".join(f"{o.exposure_us / 1000:g}" for o in orphans)
    return (f"{side}: incomplete sequence, {len(orphans)} frame(s) not in a complete cycle "
            f"(t_ns {orphans[0].t_ns}..{orphans[-1].t_ns}, exposures ms {exps})")


def group_sequences(frames_by_side: dict[str, list[Frame]], *, tolerance_ns: int = 2_000_000,
                    max_gap_factor: float = 1.6, order: tuple[int, ...] | None = None
                    ) -> tuple[list[BracketSequence], list[str]]:
    """Complete sequences present on every side, matched by timestamp; returns (sequences, problems).

    ``frames_by_side``: ``{side: [Frame, ...]}`` in any order. ``order``: the cycle order of the exposures when the
    source knows it (bracket_index), else it is estimated. Raises DatasetError when no side has frames or the
    sides use different bracket sets.
    """
    sides = [s for s, fr in frames_by_side.items() if fr]
    if not sides:
        raise DatasetError("no frames found")
    sets = {s: sorted({f.exposure_us for f in frames_by_side[s]}) for s in sides}
    exposures = sets[sides[0]]
    for s in sides[1:]:
        if sets[s] != exposures:
            raise DatasetError(f"sides use different bracket sets: {sides[0]} {exposures} vs {s} {sets[s]} (us)")
    if len(exposures) < 2:
        raise DatasetError(f"need at least 2 bracket exposures, found {exposures} us")
    ordered = {s: sorted(frames_by_side[s], key=lambda f: (f.t_ns, f.exposure_us)) for s in sides}
    if order is None or sorted(order) != list(exposures):
        order = cycle_order(ordered, exposures)
    problems: list[str] = []
    cycles_by_side: dict[str, list[list[Frame]]] = {}
    for s in sides:
        cycles, probs = split_side(ordered[s], order, max_gap_factor)
        cycles_by_side[s] = cycles
        problems.extend(probs)
    ref = sides[0]
    sequences: list[BracketSequence] = []
    used: dict[str, set[int]] = {s: set() for s in sides[1:]}
    for cyc in cycles_by_side[ref]:
        matched: dict[str, list[Frame]] = {ref: cyc}
        for s in sides[1:]:
            for j, other in enumerate(cycles_by_side[s]):
                if j in used[s]:
                    continue
                if all(abs(a.t_ns - b.t_ns) <= tolerance_ns for a, b in zip(cyc, other, strict=True)):
                    matched[s] = other
                    used[s].add(j)
                    break
        if len(matched) != len(sides):
            missing = [s for s in sides if s not in matched]
            problems.append(f"{ref}: sequence starting at t_ns {cyc[0].t_ns} has no match on {', '.join(missing)}")
            continue
        frames = {s: {f.exposure_us: f for f in fr} for s, fr in matched.items()}
        stamps = {s: {f.exposure_us: f.t_ns for f in fr} for s, fr in matched.items()}
        sequences.append(BracketSequence(len(sequences), tuple(exposures), stamps, frames))
    for s in sides[1:]:
        for j, other in enumerate(cycles_by_side[s]):
            if j not in used[s]:
                problems.append(f"{s}: sequence starting at t_ns {other[0].t_ns} has no match on {ref}")
    return sequences, problems
