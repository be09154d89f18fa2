"""``bracketry demo``: record on the simulated backpack, verify, benchmark every AE method, report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from bracketry_base.options import (
    EXIT_OK,
    EXIT_PROBLEMS,
    Duration,
    method_options_options,
    option,
    output_dir,
    overwrite_option,
)
from bracketry_emulator.option_table import DEMO, options_for, pop_settings, record_values


@click.command("demo")
@click.option("--out", "out_dir", type=output_dir(), default=Path("demo-out"),
              show_default=True, help="Output folder, new or empty (recording, dataset, benchmark report).")
@overwrite_option("Run again into a non-empty --out (the earlier demo's files are replaced).")
@option("--duration-s", "seconds", aliases=("--seconds",), type=Duration(600.0, min_s=3.0), default=None,
        help="How long to record: seconds or e.g. 30s, 2m; 3 s to 10 min (default 12 s, or 10 s with --quick).")
@click.option("--quick", is_flag=True, help="Small and short (320x200, 10 s of recording): the version CI runs.")
@options_for(DEMO)
@method_options_options()
@click.option("--suite/--no-suite", "with_suite", default=None,
              help="Also benchmark the demo-size synthetic suite (bracketry synth suite --size demo --seed 0; rendered "
                   "once into the user cache) beside the recording. Default: on, off with --quick.")
def command(out_dir: Path, overwrite: bool, seconds: float | None, quick: bool, method_option: tuple[str, ...],
            method_options: Path | None, with_suite: bool | None, **given: Any) -> int:
    """Run the whole pipeline on the embedded default: simulated rig -> recording -> AE benchmark -> report."""
    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("demo")  # every process of the demo (closed loops beside seven SLAM runs); before numpy loads
    from bracketry.demo.pipeline import check_methods, plan, run
    from bracketry_emulator.ae.registry import parse_method_options
    from bracketry_emulator.benchmark.slam import parse_pace

    settings = pop_settings(DEMO, given)
    assert not given, f"options without a row in the settings table: {sorted(given)}"
    chosen = record_values(DEMO, settings, "methods")
    slam = record_values(DEMO, settings, "slam")
    pace = parse_pace(slam["pace"])  # a bad value: one line before anything runs
    the_plan = plan(out_dir, seconds, quick, chosen.get("drl_weights"), slam.get("backend"), pace, chosen["methods"],
                    record_values(DEMO, settings, "benchmark")["stats_methods"],
                    parse_method_options(method_option, method_options), suite=with_suite)
    check_methods(the_plan)  # unknown methods, bad plugin options, unsafe names: one line before recording
    summary = run(the_plan, echo=lambda s: click.echo(s, err=True))
    click.echo("")
    verdict = "verified clean" if summary["recording_verified"] else "HAS PROBLEMS"
    click.echo(f"bracketry demo: {summary['frames']['left']} + {summary['frames']['right']} frames recorded, "
               f"drops {summary['drops']}, recording {verdict}")
    unknown = summary.get("frames_without_pose", 0)
    for metric, best in summary["best"].items():  # RTE/RRE are absent when the benchmark refused them
        click.echo(f"  best {metric:<32} {best['method']:<8} {best['value']}")
    held = summary.get("frames_held_for_renderer", 0)
    if unknown:
        click.echo(f"  {unknown} recorded frames have no known ground-truth pose: left out of RTE/RRE "
                   "(refused beyond 5 % of a run's frames)")
    if "RTE (%)" not in summary["best"] and not unknown:
        why = (f"the world held for {held} frames (renderer behind on a loaded machine), so the walk may be shorter "
               "than the RTE windows" if held else "no method tracked a stretch as long as the RTE windows")
        click.echo(f"  RTE/RRE not computed for any method: {why}")
    if held:
        click.echo(f"  WARNING: {held} frames repeat an earlier rendered cycle: these are not an idle run's figures")
    if summary.get("suite"):
        click.echo(f"  benchmarked on {summary['trajectories']} trajectories: the recording and the demo-size suite "
                   f"({summary['suite']})")
    report = summary["report"].get("report.html") or summary["report"].get("report.md")
    click.echo(f"report: {report}")
    t, c = summary["timing_s"], summary["cpu_s"]
    suite_t = f", suite {t['suite']} s" if summary.get("suite") else ""
    suite_c = f", suite {c['suite']} s" if summary.get("suite") else ""
    click.echo(f"took {t['total']} s (recording {t['record']} s, export {t['export']} s{suite_t}, benchmark "
               f"{t['benchmark']} s; load average {' / '.join(str(x) for x in summary['load_average'])})")
    click.echo(f"CPU {c['total']} s (recording {c['record']} s, export {c['export']} s{suite_c}, benchmark "
               f"{c['benchmark']} s; user + system, every process of the demo)")
    return EXIT_OK if summary["recording_verified"] else EXIT_PROBLEMS
