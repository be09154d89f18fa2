"""When glare walks are lost: the share of lost runs whose loss comes within a window after an instant with the sun
in the left image, against the share the walks' own sun-in-view instants would give by chance.

Usage:
    .venv/bin/python benchmarks/bench_glare_loss_timing.py --runs OUT[:WALK,WALK] [--runs ...] MANIFEST [MANIFEST ...]
        [--window-s 3]

OUT: a ``bracketry benchmark`` output folder (its ``report/results.csv``); after a colon, only these walks of it
(to pair runs of different walks from different benchmarks). MANIFEST: the dataset arguments the walks come from
(their folders' ``scenario.yaml``). Every lost run of a paper method (not the oracle) on a walk with a scenario counts.
A loss at ``t`` is *near the sun* when the sun's centre lands in the left image at some instant of ``[t - window,
t]`` (every 0.25 s; :func:`~bracketry_emulator.synth.suite.sun_in_view`); by chance, a walk's losses would be near
the sun at the share of its instants (every 0.5 s) that are. Prints each walk's share, the losses near the sun, the
count expected by chance and a one-sided binomial p. docs/RESULTS.md ("Suite version 8: all 28 walks") quotes it.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import binomtest

from bracketry_base.errors import BracketryError
from bracketry_emulator.metrics.manifest import expand_datasets
from bracketry_emulator.synth.suite import sun_in_view

#: the instants a window is sampled at, and a walk's instants for the chance share (s)
WINDOW_STEP_S = 0.25
BASE_STEP_S = 0.5


def near_sun(doc: dict, t_s: np.ndarray, window_s: float) -> np.ndarray:
    """Whether the sun is in the left image at some instant of ``[t - window_s, t]``, for each ``t`` of ``t_s``
    (float (N,), seconds): bool (N,)."""
    offsets = np.arange(0.0, window_s + 1e-9, WINDOW_STEP_S)
    t = np.asarray(t_s, np.float64)
    seen = sun_in_view(doc, (t[:, None] - offsets[None, :]).ravel()).reshape(t.size, offsets.size)
    return np.asarray(seen.any(axis=1), bool)


def read_losses(spec: str) -> list[tuple[str, str, float]]:
    """(walk, method, time_s) of the lost runs of a paper method in ``OUT[:WALK,WALK]``'s ``report/results.csv``."""
    out, _, walks = spec.partition(":")
    path = Path(out) / "report" / "results.csv"
    keep = {w for w in walks.split(",") if w}
    try:
        with path.open(newline="") as f:
            rows = list(csv.DictReader(f))
        return [(r["trajectory"], r["method"], float(r["time_before_failure_s"])) for r in rows
                if r["success"] != "yes" and r["method"] != "oracle" and (not keep or r["trajectory"] in keep)]
    except (OSError, KeyError, ValueError) as exc:
        raise BracketryError(f"cannot read the runs of {path}: {exc}") from exc


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", action="append", required=True,
                    help="OUT[:WALK,WALK]: a bracketry benchmark --out folder")
    ap.add_argument("manifests", nargs="+", help="the dataset arguments the walks come from")
    ap.add_argument("--window-s", type=float, default=3.0, help="the window before a loss (s, default 3)")
    args = ap.parse_args(argv)
    try:
        if not args.window_s >= 0:
            raise BracketryError(f"--window-s must be >= 0 (got {args.window_s})")
        docs = {}
        for s in expand_datasets(args.manifests):
            scenario = s.path / "scenario.yaml"
            if scenario.is_file():
                docs[s.name] = yaml.safe_load(scenario.read_text())
        losses = [loss for spec in args.runs for loss in read_losses(spec) if loss[0] in docs]
    except (BracketryError, yaml.YAMLError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if not losses:
        print("error: no lost run of a paper method on a walk with a scenario.yaml in those manifests", file=sys.stderr)
        return 1
    share = {}
    for name in sorted({w for w, _, _ in losses}):
        duration_s = float(docs[name].get("duration_s", 60.0))
        share[name] = float(near_sun(docs[name], np.arange(0.0, duration_s, BASE_STEP_S), args.window_s).mean())
    hits = sum(bool(near_sun(docs[w], np.array([t]), args.window_s)[0]) for w, _, t in losses)
    expected = sum(share[w] for w, _, _ in losses)
    n = len(losses)
    print(f"window {args.window_s:g} s; each walk's share of instants near the sun: "
          + ", ".join(f"{w} {v:.2f}" for w, v in share.items()))
    p = binomtest(hits, n, expected / n, alternative="greater").pvalue
    print(f"{n} losses, {hits} ({hits / n:.0%}) near the sun; by chance {expected:.1f} ({expected / n:.0%}); "
          f"one-sided binomial p {p:.1g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
