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
from bracketry_emulator.benchmark.failure_analysis import blur_of
from bracketry_emulator.metrics.cycle_rotation import frame_turn_change_deg
from bracketry_emulator.metrics.failure_causes import CAUSES, frame_log, loss_cause, window_change_stops
from bracketry_emulator.metrics.manifest import expand_datasets
from bracketry_emulator.trajectory_io import read_frames_csv, read_tum

#: exposure bands, stops (the first is "steady")
STOP_EDGES = (0.0, 0.25, 0.5, 1.0, math.inf)
#: turn-change bands, degrees (the real backpack's median change per bracket cycle is 3.2, its 90th percentile 4.8:
#: emulator/DATASET.md, the gait table)
TURN_EDGES = (0.0, 3.0, 4.5, math.inf)


def at_risk_frames(states: list[str], change_stops: np.ndarray,
                   turn_deg: np.ndarray) -> list[tuple[float, float, bool]]:
    """(exposure change, turn change, lost) of every frame after a tracked one, with both changes known."""
    out = []
    for k in range(1, len(states)):
        if states[k - 1] == "OK" and math.isfinite(change_stops[k]) and math.isfinite(turn_deg[k]):
            out.append((float(change_stops[k]), float(turn_deg[k]), states[k] not in ("OK", "INIT")))
    return out


def pooled_ratio(counts: np.ndarray, stop_band: int) -> tuple[int, float]:
    """(losses, losses expected) of an exposure band over all turn bands, each turn band's frames at its steady rate
    (exposure band 0). ``counts``: int (turn bands, exposure bands, 2) frames kept / lost."""
    observed = int(counts[:, stop_band, 1].sum())
    steady = counts[:, 0, 1] / np.maximum(counts[:, 0].sum(axis=1), 1)
    return observed, float((counts[:, stop_band].sum(axis=1) * steady).sum())


def band(value: float, edges: tuple[float, ...]) -> int:
    return int(np.searchsorted(np.asarray(edges[1:-1]), value, side="right"))


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
    frames: list[tuple[float, float, bool]] = []
    causes: dict[str, Counter] = defaultdict(Counter)
    n_runs = 0
    for path in cached:
        doc = json.loads(path.read_text())
        spec = specs.get(doc.get("trajectory", ""))
        frames_csv = Path(doc.get("vo_dir", "")) / "frames.csv"
        if spec is None or not frames_csv.is_file():
            continue
        gt, cal = spec.groundtruth_path(), spec.calibration_dir()
        log = frame_log(read_frames_csv(frames_csv), Path(doc["run_dir"]) / "ae.csv")
        turn = (frame_turn_change_deg(*read_tum(gt), log.times_s) if gt else np.full(len(log.states), np.nan))
        frames += at_risk_frames(log.states, window_change_stops(log.exposure_ratio), turn)
        cause = loss_cause(log, blur_of(log, str(gt) if gt else None, str(cal) if cal else None))
        causes[doc["method"]][cause or "kept"] += 1
        n_runs += 1
    if not frames:
        print(f"error: none of the {len(cached)} cached runs in {args.out} has a frame log of a manifest's walk",
              file=sys.stderr)
        return 1
    counts = np.zeros((len(TURN_EDGES) - 1, len(STOP_EDGES) - 1, 2), int)
    for stops, turn_deg, lost in frames:
        counts[band(turn_deg, TURN_EDGES), band(stops, STOP_EDGES), int(lost)] += 1
    print(f"{n_runs} runs, {len(frames)} frames after a tracked one, {sum(f[2] for f in frames)} losses\n")
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
        print(f"| {_label(STOP_EDGES, s, 'stops')} | {observed} | {expected:.1f} | {observed / expected:.1f} |")
    print("\n| method | " + " | ".join(CAUSES) + " | kept |")
    print("|---|" + "---|" * (len(CAUSES) + 1))
    for method in sorted(causes):
        c = causes[method]
        print(f"| {method} | " + " | ".join(str(c[k]) for k in (*CAUSES, "kept")) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
