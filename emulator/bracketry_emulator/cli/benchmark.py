"""``bracketry benchmark``: closed loops, stereo VO, metrics, statistics and a report for AE methods."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    input_path,
    method_options_options,
    output_dir,
    overwrite_option,
    quiet_option,
    resume_option,
)
from bracketry_emulator.option_table import BENCHMARK, options_for, pop_settings, record_values


@click.command("benchmark")
@click.argument("datasets", nargs=-1, required=True, type=input_path())
@click.option("--out", "out_dir", required=True, type=output_dir(resumable=True),
              help="Output folder, new or empty; a non-empty one needs --resume (its runs and cache are reused) or "
                   "--overwrite.")
@resume_option("Continue the benchmark in a non-empty --out: finished runs come from its cache (an interrupted "
               "benchmark resumes).")
@overwrite_option("Benchmark again into a non-empty --out: the earlier benchmark's runs, cache and report are removed "
                  "first.")
@options_for(BENCHMARK)
@method_options_options()
@quiet_option("No progress bar for the closed loops.")
def command(datasets: tuple[Path, ...], **given: Any) -> int:
    """Benchmark AE methods on DATASET... (trajectory folders, trajectory .zip archives read in place, or manifest
    YAMLs naming subsets).

    Per trajectory, the closed loops of all methods (unless the dataset already holds a method's emulated run) run
    in one pass that decodes each bracket sequence once; then per (trajectory, method) ORB-SLAM3 stereo (each run
    in its own process, its output in a log beside the run; a failed run is a line in the report) or the built-in
    VO, RTE/RRE with evo, the distance tracked and the failure metrics. SLAM gets the emulated images as raw
    frames the closed loops spool (PNGs only with --write-images or --export-orbslam), one run more at a time than
    --workers. Results are cached under
    OUT/cache, so the same command with --resume continues an interrupted one. The report is written to OUT/report
    (CSV, Markdown, HTML, figures). Exit code 0. With ORB-SLAM3 the vocabulary is checked first and a set-up check
    (ORB-SLAM3 on the first seconds of a trajectory's middle bracket, no AE) must pass: else one error line, exit 2.
    """
    import os

    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("benchmark")  # before numpy loads
    from bracketry_emulator.ae import LoopConfig, parse_method_options
    from bracketry_emulator.benchmark import BenchmarkConfig, RunResult, run_benchmark
    from bracketry_emulator.benchmark.cluster import SlurmOptions
    from bracketry_emulator.benchmark.oracle_rows import ORACLE
    from bracketry_emulator.benchmark.slam import slam_options

    out_dir: Path = given.pop("out_dir")
    quiet: bool = given.pop("quiet")
    given.pop("resume")  # read by --out's type
    overwrite: bool = given.pop("overwrite")
    plugin_options = parse_method_options(given.pop("method_option"), given.pop("method_options"))
    settings = pop_settings(BENCHMARK, given)
    assert not given, f"options without a row in the settings table: {sorted(given)}"
    bench = record_values(BENCHMARK, settings, "benchmark")
    methods = record_values(BENCHMARK, settings, "methods")
    if bench.get("scheduler") is not None and not bench["scheduler"].startswith(("tcp://", "tls://", "inproc://",
                                                                                 "ucx://")):
        raise BracketryError(f"bad --scheduler {bench['scheduler']!r} (expected tcp://HOST:PORT)")
    if bench.get("scheduler") is not None and bench.get("cluster") is not None:
        raise BracketryError("--scheduler and --cluster exclude each other (a cluster you run, or batch jobs)")
    cluster = bench.pop("cluster", None)
    slurm = None if cluster is None else SlurmOptions(**record_values(BENCHMARK, settings, "cluster"))
    if bench.get("workers") == 0:
        bench["workers"] = os.cpu_count() or 1
    slam = slam_options(**record_values(BENCHMARK, settings, "slam"), resolve=False)
    slam_repeats = slam.repeats
    loop_values = record_values(BENCHMARK, settings, "loop")
    images = loop_values.pop("images")
    loop = LoopConfig.from_values({**loop_values, "images": "truth" if images == "truth" else "emulated"})
    reference = bench.get("reference", "")
    alpha = bench.get("alpha", 0.0)

    def done(r: RunResult) -> None:
        rep = f" (repeat {r.repeat + 1})" if slam_repeats > 1 else ""
        if r.method == ORACLE:  # its own run: the report's oracle row is the best of its candidates (oracle_rows)
            rep = f" (step search){rep}"
        if r.error:
            click.echo(f"failed {r.trajectory} / {r.method}{rep}: {r.error}")
            return
        m = r.metrics
        state = "cached" if r.cached else "done"
        outcome = "success" if m["success"] else f"failed at {m['time_before_failure_s']:.1f} s"
        if m.get("rte_refused"):
            rte = f"RTE refused: {m['rte_refused']}"
        elif str(m.get("reference", "")).startswith("no reference"):
            rte = "RTE - (no reference)"
        else:
            rte = f"RTE {m['rte_pct']:.2f} %"
        click.echo(f"{state:6s} {r.trajectory} / {r.method}{rep}: {outcome}, "
                   f"{rte}, coverage {100 * m['coverage_mean']:.1f} %, "
                   f"matches {m['matches_mean']:.0f}")

    config = BenchmarkConfig(datasets, methods["methods"], out_dir, **bench, cluster=slurm,
                             drl_weights=methods.get("drl_weights"), progress=not quiet, loop=loop, slam=slam,
                             method_options=plugin_options, overwrite=overwrite)
    if images == "both":  # truth images first refused (one line) for any non-synthetic trajectory, before any work
        from dataclasses import replace

        from bracketry_emulator.benchmark.orchestrate import check_truth_datasets

        check_truth_datasets(config.datasets)
    result = run_benchmark(config, on_done=done, slam_echo=click.echo)
    click.echo(f"report: {result.report_files.get('report.html')}")
    if images == "both":
        from bracketry_emulator.benchmark.truth_agreement import truth_agreement, write_truth_agreement

        click.echo("truth images:")
        truth = run_benchmark(replace(config, out_dir=out_dir / "truth", loop=replace(loop, images="truth"),
                                      overwrite=False),
                              on_done=done, slam_echo=click.echo)
        methods_run = list(dict.fromkeys(r["method"] for r in result.results))
        doc = truth_agreement(result.results, truth.results, methods_run, reference, alpha)
        _json, md = write_truth_agreement(doc, out_dir / "report")
        v = doc["verdicts"]
        click.echo(f"emulated vs truth: Kendall tau {doc['kendall_tau_median']:.2f} (median over metrics), verdicts "
                   f"agree {v['agree']}/{v['total']}: {md}")
    return EXIT_OK
