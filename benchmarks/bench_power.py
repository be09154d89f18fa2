"""Statistical power of the benchmark: how often its statistics flag known-bad controls, and a copy of AE50.

Usage: .venv/bin/python benchmarks/bench_power.py [--seeds 10] [--slam builtin|orbslam3] [--repeats 1]
                                                  [--suites-per-seed 3] [--controls short,long,copy] [--out DIR]
                                                  [--quick] [--tally]

For each seed, a suite is rendered and benchmarked with four methods: ``ae50`` (the reference), a far-too-short
constant (``constant-0.0625``: four stops under the shortest bracket, 1 ms), a far-too-long one (``constant-512``:
four stops over the longest, 32 ms, emulated as 32 ms with 24 dB of gain; the loops' upper bound is raised to 1 s)
and ``ae50copy``, a plug-in (an import path, as a researcher ships one) whose rule is AE50's. The suite's manifest
declares a warm-up (every method first settles on each walk's first view), so the walks compare how methods
follow the light, not how fast they leave the 4 ms start. The far-too-long constant is far too long for the
daylight walks only: under the canopy and at dusk AE50 itself asks for 0.2-1 s here (as gain), so 512 ms is no
worse there, and a test over the whole suite must find it from the daylight walks. (``constant-64``, one stop over
the longest bracket, tracked as well as AE50 on every walk with the built-in VO: not a known-bad control.) The
statistics are the report's: Mann-Whitney U against AE50 with Bonferroni over the three compared methods (alpha
0.05), per metric, as the paper's; and the paired Wilcoxon signed-rank, where a run that never tracked ranks worst
on RTE (worst-rank imputation; the Mann-Whitney table leaves it out, as the paper's).

- **power**: the share of seeds in which a bad control is flagged *worse* than AE50 on RTE or on time before failure;
- **false positives**: the share of seeds in which the copy is flagged (better or worse) on any metric;
- **unstable**: apart from both, the share of seeds in which a row's verdict is shown as ``?`` (fewer than 90 % of
  bootstrap resamples of the walks give the test's verdict, which may be "equal": the report claims no difference
  either way there, so a ``?`` counts neither as a flag nor as a clearance);

each for Mann-Whitney (the report's main table) and for the paired Wilcoxon (its paired table). Per seed a line is
appended to ``--out``/seeds.jsonl as it is measured.

Each with its count and a 95 % Clopper-Pearson interval. Goal (issue 28): power >= 0.9; the copy flagged in at most
1 of 10 seeds.

The suite of seed S: the demo-size suites (``bracketry synth suite --size demo``) of seeds S, 1000 + S, 2000 + S
(``--suites-per-seed``, default 3), benchmarked together: 30 walks of 10 s, half the paper's 59 trajectories. One
suite of 10 walks holds three (the canopy, dusk and sunset walks) on which the far-too-long constant asks what AE50
asks, so only 6-7 walks can tell the two apart, too few for a test at Bonferroni's 0.0167 whose verdict also holds in
90 % of bootstrap resamples of the walks. Where ``synth suite`` does not exist (said in the output): six
snowy-forest walks of 4 s at 320x200 (``bracketry synth trajectory``, seeds 100 S + k). Localisation: the built-in
VO by default (deterministic: its results do not move between runs, so the copy's results are AE50's, bit for bit),
``--slam orbslam3 --repeats N`` for ORB-SLAM3 with N runs per (trajectory, method) (statistics on the medians: its
run-to-run spread is what makes a copy differ from its original). Prints the table, the time per stage, and writes
``power.json`` into ``--out``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import textwrap  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

from bracketry_emulator.runtime_policy import apply_profile  # noqa: E402

SHORT, LONG, COPY = "constant-0.0625", "constant-512", "ae50copy"
#: the closed loops' upper bound (us): the far-too-long control is beyond the default 64 ms
MAX_EXPOSURE_US = 1_000_000.0
COPY_MODULE = textwrap.dedent('''
    """AE50 as a plug-in: the classical rule at 50 % (a copy, to measure the benchmark's false positives)."""
    from bracketry_emulator.ae.classical import ClassicalAE


    class AE50Copy(ClassicalAE):
        name = "ae50copy"

        def __init__(self):
            super().__init__(50.0, name="ae50copy")
''')
#: metrics on which a bad control counts as flagged (worse than AE50)
POWER_METRICS = ("rte_pct", "time_before_failure_s")
#: a verdict the report marks ``?`` (fewer than 90 % of bootstrap resamples of the walks give it): counted apart,
#: neither flagged nor cleared
UNSTABLE = "unstable"
BIN = Path(sys.executable).parent / "bracketry"
#: the demo-size suites pooled into one power seed (``--suites-per-seed``): 30 walks, half the paper's 59
SUITES_PER_SEED = 3
#: power seed S pools the suites of seeds S, S + 1000, S + 2000, ...
SUITE_SEED_STRIDE = 1000


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact two-sided ``level`` interval of a binomial proportion with ``k`` successes in ``n`` trials."""
    from scipy.stats import beta

    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def has_suite_command() -> bool:
    """Whether ``bracketry synth suite`` exists in this checkout."""
    return subprocess.run([str(BIN), "synth", "suite", "--help"], capture_output=True).returncode == 0


def suite_seeds(seed: int, suites: int) -> list[int]:
    """The demo-size suite seeds pooled into power seed ``seed``: ``seed``, ``SUITE_SEED_STRIDE + seed``, ... (the
    first is the demo-size suite of the same seed, so a one-suite run is the suite a user renders)."""
    return [seed + SUITE_SEED_STRIDE * j for j in range(suites)]


def make_suite(root: Path, seed: int, use_suite: bool, suites: int = 1) -> list[Path]:
    """The seed's suites under ``root`` (``suites`` demo-size suites, see :func:`suite_seeds`); returns their
    manifests, benchmarked together (as ``bracketry benchmark M1 M2 ...``: a walk met again is named ``NAME_2``)."""
    if use_suite:
        root.mkdir(parents=True, exist_ok=True)
        folders = []
        for s in suite_seeds(seed, suites):
            folders.append(root / f"s{s}")
            subprocess.run([str(BIN), "synth", "suite", "--out", str(folders[-1]), "--size", "demo", "--seed",
                            str(s), "-q"], check=True, capture_output=True)
        return [f / "manifest.yaml" for f in folders]
    entries = []
    for k in range(6):
        name = f"walk{k}"
        subprocess.run([str(BIN), "synth", "trajectory", "--out", str(root / name), "--seed", str(100 * seed + k),
                        "--duration-s", "4", "--resolution", "320x200", "-q"], check=True, capture_output=True)
        entries.append(f"  - {{path: {name}, subset: forest}}")
    (root / "manifest.yaml").write_text("trajectories:\n" + "\n".join(entries) + "\n")
    return [root / "manifest.yaml"]


def flags(report_dir: Path) -> dict[str, dict[str, dict[str, str]]]:
    """{test: {method: {metric: verdict}}} as the benchmark's report gives them (``verdicts.csv``: Mann-Whitney,
    ``verdicts_paired.csv``: Wilcoxon signed-rank; Bonferroni over the compared methods): read, not recomputed, so
    this counts exactly what a user of the report reads."""
    import csv

    from bracketry_emulator.stats.mannwhitney import METRICS

    key_of = {label: key for key, (label, _higher) in METRICS.items()}

    word = {"▲": "better", "▼": "worse", "≡": "equal", "–": "n/a", "?": UNSTABLE}
    out: dict[str, dict[str, dict[str, str]]] = {}
    for test, name in (("mann-whitney", "verdicts.csv"), ("wilcoxon", "verdicts_paired.csv")):
        with open(report_dir / name, newline="") as fh:
            rows = list(csv.reader(fh))
        methods = rows[0][1:]
        out[test] = {m: {} for m in methods}
        for label, *cells in rows[1:]:
            for m, cell in zip(methods, cells):
                out[test][m][key_of[label]] = word.get(cell, cell)
    return out


def seed_row(seed: int, bench_dir: Path, render_s: float, bench_s: float) -> dict:
    """One seed's line: its flags per test (short, long: worse on RTE or time before failure; copy: any verdict)."""
    import csv

    with open(bench_dir / "report" / "results.csv", newline="") as fh:
        n_traj = len({r["trajectory"] for r in csv.DictReader(fh)})
    f = flags(bench_dir / "report")
    row: dict = {"seed": seed, "trajectories": n_traj, "verdicts": f, "render_s": round(render_s, 1),
                 "benchmark_s": round(bench_s, 1)}
    for test, v in f.items():
        row[test] = {}
        for key, method in (("short", SHORT), ("long", LONG)):
            if method in v:
                row[test][key] = any(v[method].get(k) == "worse" for k in POWER_METRICS)
                row[test][f"{key}_unstable"] = any(v[method].get(k) == UNSTABLE for k in POWER_METRICS)
        if COPY in v:
            row[test]["copy"] = any(x in ("better", "worse") for x in v[COPY].values())
            row[test]["copy_unstable"] = any(x == UNSTABLE for x in v[COPY].values())
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="suites (seeds 0..N-1)")
    ap.add_argument("--slam", choices=("builtin", "orbslam3"), default="builtin")
    ap.add_argument("--repeats", type=int, default=1, help="SLAM runs per (trajectory, method)")
    ap.add_argument("--out", type=Path, default=None, help="keep the suites, benchmarks and power.json here")
    ap.add_argument("--suites-per-seed", type=int, default=SUITES_PER_SEED,
                    help=f"demo-size suites pooled into each seed's benchmark (10 walks each; default "
                         f"{SUITES_PER_SEED})")
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    ap.add_argument("--controls", default="short,long,copy",
                    help="the rows benchmarked beside AE50 (a subset of short,long,copy; e.g. copy alone for the "
                         "false-positive rate with ORB-SLAM3 repeats); the Bonferroni count follows")
    ap.add_argument("--tally", action="store_true",
                    help="run nothing: tally the reports already in --out (bench<seed>/report) into power.json")
    args = ap.parse_args()
    if not 1 <= args.suites_per_seed <= 10 or not 1 <= args.seeds <= SUITE_SEED_STRIDE:
        sys.exit(f"--suites-per-seed: 1 to 10, --seeds: 1 to {SUITE_SEED_STRIDE}")
    ids = {"short": SHORT, "long": LONG, "copy": "ae50copy_mod:AE50Copy"}
    wanted = [c.strip() for c in args.controls.split(",") if c.strip()]
    if not wanted or any(c not in ids for c in wanted):
        sys.exit(f"--controls: a comma-separated subset of {', '.join(ids)}, got {args.controls!r}")
    apply_profile("timing")
    from bracketry_emulator.ae import LoopConfig
    from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
    from bracketry_emulator.benchmark.slam import slam_options
    n_seeds = 3 if args.quick else args.seeds
    work = args.out or Path(tempfile.mkdtemp(prefix="bench_power_"))
    work.mkdir(parents=True, exist_ok=True)
    plugin_dir = work / "plugin"
    plugin_dir.mkdir(exist_ok=True)
    (plugin_dir / "ae50copy_mod.py").write_text(COPY_MODULE)
    sys.path.insert(0, str(plugin_dir))
    use_suite = has_suite_command()
    suite_text = (f"bracketry synth suite --size demo, {args.suites_per_seed} suite(s) a seed" if use_suite
                  else "6 snowy-forest walks of 4 s at 320x200 (no `synth suite` in this checkout)")
    slam = slam_options(args.slam, None, "0" if args.slam == "orbslam3" else None, True, args.repeats, resolve=False)
    print(f"suite: {suite_text}; SLAM: {args.slam}, {args.repeats} run(s) per (trajectory, method); "
          f"{n_seeds} seeds", flush=True)
    per_seed = []
    render_s = bench_s = 0.0
    if args.tally:
        if args.out is None:
            sys.exit("--tally needs --out DIR (the folder of an earlier run)")
        old = {int(json.loads(line)["seed"]): json.loads(line) for line in
               (work / "seeds.jsonl").read_text().splitlines()} if (work / "seeds.jsonl").is_file() else {}
        for seed in range(n_seeds):
            if (work / f"bench{seed}" / "report" / "verdicts_paired.csv").is_file():
                t = old.get(seed, {})
                per_seed.append(seed_row(seed, work / f"bench{seed}", t.get("render_s", 0.0),
                                         t.get("benchmark_s", 0.0)))
                render_s += t.get("render_s", 0.0)
                bench_s += t.get("benchmark_s", 0.0)
    for seed in range(0 if not args.tally else n_seeds, n_seeds):
        t0 = time.perf_counter()
        manifests = make_suite(work / f"suite{seed}", seed, use_suite, args.suites_per_seed)
        t1 = time.perf_counter()
        res = run_benchmark(BenchmarkConfig(manifests, ["ae50", *(ids[c] for c in wanted)],
                                            work / f"bench{seed}", workers=os.cpu_count() or 1,
                                            stats_methods="all", slam=slam,
                                            setup_check=False, loop=LoopConfig(max_exposure_us=MAX_EXPOSURE_US)))
        t2 = time.perf_counter()
        render_s += t1 - t0
        bench_s += t2 - t1
        row = seed_row(seed, res.out_dir, t1 - t0, t2 - t1)
        per_seed.append(row)
        if args.out is not None:  # kept as it goes: an interrupted run still says what it measured
            with open(work / "seeds.jsonl", "a") as fh:
                fh.write(json.dumps(row) + "\n")
        said = ", ".join(f"{c} {row['mann-whitney'][c]}/{row['wilcoxon'][c]}" for c in wanted)
        print(f"seed {seed}: {row['trajectories']} trajectories, flagged (Mann-Whitney / Wilcoxon): {said} "
              f"(render {t1 - t0:.0f} s, benchmark {t2 - t1:.0f} s)", flush=True)
    n = len(per_seed)
    table: list[dict[str, Any]] = []
    for test in ("mann-whitney", "wilcoxon"):
        for what, key, goal in (("far-too-short constant flagged worse (power)", "short", ">= 0.9"),
                                ("far-too-short constant: ? on RTE or failure time", "short_unstable", ""),
                                ("far-too-long constant flagged worse (power)", "long", ">= 0.9"),
                                ("far-too-long constant: ? on RTE or failure time", "long_unstable", ""),
                                ("AE50 plug-in copy flagged at all (false positive)", "copy", "<= 1 of 10"),
                                ("AE50 plug-in copy: ? on any metric", "copy_unstable", "")):
            if not per_seed or any(key not in r[test] for r in per_seed):
                continue
            k = sum(bool(r[test][key]) for r in per_seed)
            lo, hi = clopper_pearson(k, n)
            table.append({"test": test, "what": what, "count": k, "seeds": n, "rate": k / n, "ci95": [lo, hi],
                          "goal": goal})
    print(f"\n| test | {'what':52s} | count | rate | 95 % CI (Clopper-Pearson) | goal |")
    print(f"|---|{'-' * 54}|-------|------|---------------------------|------|")
    for t in table:
        print(f"| {t['test']} | {t['what']:52s} | {t['count']}/{t['seeds']} | {t['rate']:.2f} | "
              f"[{t['ci95'][0]:.2f}, {t['ci95'][1]:.2f}] | {t['goal']} |")
    print(f"\ntime: render {render_s:.0f} s, benchmark {bench_s:.0f} s (wall, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f})")
    doc = {"suite": suite_text, "slam": args.slam, "repeats": args.repeats, "controls": wanted, "table": table,
           "seeds": per_seed,
           "render_s": round(render_s, 1), "benchmark_s": round(bench_s, 1)}
    if args.out is None:
        shutil.rmtree(work, ignore_errors=True)
    else:
        (work / "power.json").write_text(json.dumps(doc, indent=1) + "\n")
        print(f"written: {work / 'power.json'}")


if __name__ == "__main__":
    main()
