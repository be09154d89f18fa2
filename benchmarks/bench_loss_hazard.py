"""What loses track: losses per tracked frame by the exposure change into it and by the turn the localisation's
constant-velocity prediction misses, over the runs of a benchmark; and the causes of the runs' first losses.

Usage:
    .venv/bin/python benchmarks/bench_loss_hazard.py OUT MANIFEST [MANIFEST ...]

OUT: a ``bracketry benchmark`` output folder (its ``cache/*/*.json`` name each run's closed loop and SLAM log);
MANIFEST: the dataset arguments it was run on (for the walks' references and calibrations). A frame is *at risk*
when the frame before it was tracked (``OK``); it is a *loss* when it is not tracked. Per frame:

- the exposure change, stops: the largest change into it or into the frame before it
  (:func:`~bracketry_emulator.metrics.failure_causes.window_change_stops`, the failure classifier's window);
- the turn change, degrees: what a constant-velocity prediction misses
  (:func:`~bracketry_emulator.metrics.cycle_rotation.frame_turn_change_deg`, from the reference).

Prints a Markdown table of at-risk frames, losses and losses per 1000 frames for each turn band and exposure band,
with the rate over the same turn band's steady frames (below a quarter stop); the same ratio pooled over the turn
bands; then the first losses' causes per method (the oracle's: its step search's own run) by the classifier of this
checkout (:mod:`~bracketry_emulator.metrics.failure_causes`), so a benchmark run
under another rule is read again without running SLAM. docs/RESULTS.md ("What loses track") quotes its output.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark.failure_analysis import blur_of, run_frame_log
from bracketry_emulator.metrics.cycle_rotation import frame_turn_change_deg
from bracketry_emulator.metrics.failure_causes import CAUSES, loss_cause, window_change_stops
from bracketry_emulator.metrics.manifest import expand_datasets
from bracketry_emulator.trajectory_io import read_tum

#: exposure bands, stops (the first is "steady")
STOP_EDGES = (0.0, 0.25, 0.5, 1.0, math.inf)
#: turn-change bands, degrees (the real backpack's median change per bracket cycle is 3.2, its 90th percentile 4.8:
#: emulator/DATASET.md, the gait table)
TURN_EDGES = (0.0, 3.0, 4.5, math.inf)


def band_counts(states: list[str], change_stops: np.ndarray, turn_deg: np.ndarray) -> np.ndarray:
    """Frames after a tracked one (both changes known), kept and lost, per turn band and exposure band: int
    (len(TURN_EDGES) - 1, len(STOP_EDGES) - 1, 2)."""
    ok = np.array([s == "OK" for s in states], bool)
    lost = ~np.array([s in ("OK", "INIT") for s in states], bool)
    at_risk = np.r_[False, ok[:-1]] & np.isfinite(change_stops) & np.isfinite(turn_deg)
    t = np.searchsorted(np.asarray(TURN_EDGES[1:-1]), turn_deg[at_risk], side="right")
    s = np.searchsorted(np.asarray(STOP_EDGES[1:-1]), change_stops[at_risk], side="right")
    counts = np.zeros((len(TURN_EDGES) - 1, len(STOP_EDGES) - 1, 2), int)
    np.add.at(counts, (t, s, lost[at_risk].astype(int)), 1)
    return counts


def pooled_ratio(counts: np.ndarray, stop_band: int) -> tuple[int, float]:
    """(losses, losses expected) of an exposure band over all turn bands, each turn band's frames at its steady rate
    (exposure band 0). ``counts``: int (turn bands, exposure bands, 2) frames kept / lost."""
    observed = int(counts[:, stop_band, 1].sum())
    steady = counts[:, 0, 1] / np.maximum(counts[:, 0].sum(axis=1), 1)
    return observed, float((counts[:, stop_band].sum(axis=1) * steady).sum())


def _label(edges: tuple[float, ...], i: int, unit: str) -> str:
    hi = edges[i + 1]
    return f">= {edges[i]:g} {unit}" if math.isinf(hi) else f"{edges[i]:g}-{hi:g} {unit}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path, help="a bracketry benchmark output folder")
    ap.add_argument("manifests", nargs="+", help="the dataset arguments it was run on")
    args = ap.parse_args(argv)
    try:
        specs = {s.name: s for s in expand_datasets(args.manifests)}
    except BracketryError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    cached = sorted((args.out / "cache").glob("*/*.json"))
    if not cached:
        print(f"error: no cached runs in {args.out / 'cache'} (a bracketry benchmark --out folder?)", file=sys.stderr)
        return 1
    counts = np.zeros((len(TURN_EDGES) - 1, len(STOP_EDGES) - 1, 2), int)
    causes: dict[str, Counter] = defaultdict(Counter)
    n_runs = 0
    for path in cached:
        doc = json.loads(path.read_text())
        spec = specs.get(doc.get("trajectory", ""))
        log = run_frame_log(Path(doc.get("vo_dir", "")), Path(doc.get("run_dir", ""))) if spec else None
        if spec is None or log is None:
            continue
        gt, cal = spec.groundtruth_path(), spec.calibration_dir()
        turn = (frame_turn_change_deg(*read_tum(gt), log.times_s) if gt else np.full(len(log.states), np.nan))
        counts += band_counts(log.states, window_change_stops(log.exposure_ratio), turn)
        cause = loss_cause(log, blur_of(log, str(gt) if gt else None, str(cal) if cal else None))
        causes[doc["method"]][cause or "kept"] += 1
        n_runs += 1
    if not counts.any():
        print(f"error: none of the {len(cached)} cached runs in {args.out} has a frame log of a manifest's walk",
              file=sys.stderr)
        return 1
    print(f"{n_runs} runs, {counts.sum()} frames after a tracked one, {counts[..., 1].sum()} losses\n")
    print("| turn change | exposure change | frames | losses | per 1000 frames | over steady |")
    print("|---|---|---|---|---|---|")
    for t in range(counts.shape[0]):
        n0, l0 = counts[t, 0, 0] + counts[t, 0, 1], counts[t, 0, 1]
        steady = l0 / n0 if n0 else math.nan
        for s in range(counts.shape[1]):
            n, n_lost = int(counts[t, s].sum()), int(counts[t, s, 1])
            rate = n_lost / n if n else math.nan
            ratio = rate / steady if steady > 0 else math.nan
            print(f"| {_label(TURN_EDGES, t, 'deg')} | {_label(STOP_EDGES, s, 'stops')} | {n} | {n_lost} | "
                  f"{1000 * rate:.2f} | {ratio:.1f} |")
    print("\nPooled over the turn bands (losses over those the bands' steady rates expect):\n")
    print("| exposure change | losses | expected at a steady exposure | ratio |")
    print("|---|---|---|---|")
    for s in range(1, counts.shape[1]):
        observed, expected = pooled_ratio(counts, s)
        ratio = observed / expected if expected > 0 else math.nan
        print(f"| {_label(STOP_EDGES, s, 'stops')} | {observed} | {expected:.1f} | {ratio:.1f} |")
    print("\n| method | " + " | ".join(CAUSES) + " | kept |")
    print("|---|" + "---|" * (len(CAUSES) + 1))
    for method in sorted(causes):
        c = causes[method]
        print(f"| {method} | " + " | ".join(str(c[k]) for k in (*CAUSES, "kept")) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
