"""``bracketry benchmark``: closed loops, stereo VO, metrics, statistics and a report for AE methods."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry.cli.options import (
    EXIT_OK,
    SEED,
    WORKERS,
    Duration,
    Integer,
    MemorySize,
    Number,
    input_dir,
    input_file,
    input_path,
    method_options_options,
    option,
    output_dir,
    quiet_option,
)
from bracketry.errors import BracketryError
from bracketry_emulator.defaults import (
    AE_CAMERAS,
    CLUSTERS,
    DEFAULT_ALPHA,
    DEFAULT_CLUSTER_JOBS,
    DEFAULT_CRF,
    DEFAULT_INIT_EXPOSURE_US,
    DEFAULT_REFERENCE,
    DEFAULT_SLAM_PACE,
    DEFAULT_STATS_METHODS,
    MAX_CLUSTER_JOBS,
    MAX_EXPOSURE_OPTION_MS,
    MAX_WARMUP_STEPS,
    PARITIES,
    RUN_IMAGES,
    SELECTIONS,
    SLAM_BACKENDS,
)


def _windows(text: str) -> tuple[float, ...]:
    """``5:50:1`` (start:stop:step, inclusive) or ``5,10,20`` -> window sizes in metres."""
    try:
        if ":" in text:
            a, b, *rest = (float(x) for x in text.split(":"))
            step = rest[0] if rest else 1.0
            if step <= 0 or b < a:
                raise ValueError
            n = round((b - a) / step) + 1
            return tuple(a + k * step for k in range(n))
        ws = tuple(float(x) for x in text.split(",") if x.strip())
        if not ws or min(ws) <= 0:
            raise ValueError
        return ws
    except ValueError:
        raise BracketryError(f"bad --windows {text!r} (use START:STOP:STEP in metres, or a list like 5,10,20)"
                             ) from None


@click.command("benchmark")
@click.argument("datasets", nargs=-1, required=True, type=input_path())
@option("--methods", "-m", "methods", aliases=("--method",), default="all", show_default=True,
        help="AE methods: 'all' or 'paper': the paper's seven (fix, ae30, ae50, ae70, shim, wang, kim) and drl with "
             "--drl-weights; 'controls': the oracle and constant exposures; or a comma list of ids (zhang, "
             "constant-<ms>, oracle), plugins pkg.module:Class or entry points (each named by its 'name').")
@method_options_options()
@click.option("--stats-methods", default=DEFAULT_STATS_METHODS, show_default=True,
              help="Methods in the statistics and their Bonferroni count: 'paper' (zhang and plugins are reported, "
                   "not tested), 'all', or a comma-separated list.")
@click.option("--out", "out_dir", required=True, type=output_dir(existing="resume"),
              help="Output folder; an existing one is resumed (its cache is reused), not replaced.")
@click.option("--reference", default=DEFAULT_REFERENCE, show_default=True, help="Reference method of the statistics.")
@click.option("--scheduler", default=None, help="Dask scheduler address tcp://HOST:PORT (default: local processes).")
@click.option("--workers", default=0, show_default=True, type=WORKERS,
              help="Local worker processes, 0 = one per CPU (1 = in this process; ignored on a cluster).")
@click.option("--cluster", type=click.Choice(CLUSTERS), default=None,
              help="Run on a batch system: Dask workers in at most --jobs jobs (dask-jobqueue), fewer as the work "
                   "runs out, all released at the end. Data, output and cache on storage every node sees "
                   "(docs/CLUSTER.md).")
@click.option("--jobs", default=DEFAULT_CLUSTER_JOBS, show_default=True, type=Integer(1, MAX_CLUSTER_JOBS),
              help="--cluster: at most this many jobs at once (one Dask worker each).")
@click.option("--job-cores", type=Integer(1, 1024), default=None,
              help="--cluster: cores per job (a trajectory's closed loops and SLAM runs share them). Default: "
                   "jobqueue.slurm.cores of dask-jobqueue's configuration.")
@click.option("--job-memory", type=MemorySize(), default=None,
              help="--cluster: memory per job, e.g. 8GB. Default: jobqueue.slurm.memory.")
@click.option("--job-walltime", type=Duration(), default=None,
              help="--cluster: walltime per job (e.g. 2h, 90m); a job that hits it has its runs done again by "
                   "another. Default: jobqueue.slurm.walltime.")
@click.option("--job-partition", default=None, help="--cluster: Slurm partition. Default: jobqueue.slurm.queue.")
@click.option("--job-account", default=None, help="--cluster: Slurm account. Default: jobqueue.slurm.account.")
@click.option("--windows", "windows_text", default=None,
              help="RTE/RRE windows in metres: START:STOP:STEP or a list. Default: a manifest's windows_m (the "
                   "demo-size suite's short walks declare 1-3 m), else 5:50:1 (the paper's).")
@click.option("--alpha", default=DEFAULT_ALPHA, show_default=True, type=Number(0, 1, min_open=True, max_open=True),
              help="Significance level before the Bonferroni correction, in (0, 1).")
@click.option("--max-frames", default=None, type=Integer(2), help="Only the first N frames of each run (N >= 2).")
@click.option("--write-images", is_flag=True,
              help="Also write every emulated image as a PNG under OUT/runs/<trajectory>/<method>/ (default: SLAM "
                   "gets them in memory and no PNG is written).")
@click.option("--export-orbslam", is_flag=True,
              help="Also export each run for ORB-SLAM2/3's stereo examples to OUT/orbslam/<trajectory>/<method>/.")
@click.option("--slam-trajectories", "slam_dir", default=None, type=input_dir(),
              help="Evaluate external SLAM output DIR/<trajectory>/<method>/CameraTrajectory*.txt instead of the "
                   "built-in VO.")
@click.option("--drl-weights", type=input_file(), default=None, envvar="BRACKETRY_DRL_WEIGHTS",
              help="The DRL actor's .pth (ShuyangUni/drl_exposure_ctrl model/actor_drl_feat_10000.pth; env "
                   "BRACKETRY_DRL_WEIGHTS). Without it 'all' leaves DRL out.")
@click.option("--selection", type=click.Choice(SELECTIONS), default=SELECTIONS[0], show_default=True,
              help="Closed loops: the emulator's source-bracket selection.")
@click.option("--crf", default=DEFAULT_CRF, show_default=True,
              help="Closed loops: camera response, 'srgb' or a pcalib.txt.")
@click.option("--init-exposure-ms", type=Number(0.0, MAX_EXPOSURE_OPTION_MS, min_open=True),
              default=DEFAULT_INIT_EXPOSURE_US / 1000.0, show_default=True,
              help="Closed loops: first target exposure of every method (ms).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Closed loops: seed of stochastic methods.")
@click.option("--ae-camera", type=click.Choice(AE_CAMERAS), default=AE_CAMERAS[0], show_default=True,
              help="Closed loops: the camera whose image the methods see.")
@click.option("--parity", type=click.Choice(PARITIES), default=PARITIES[0], show_default=True,
              help="Closed loops: the methods as their papers describe them (default) or as the authors' code runs "
                   "them (upstream: with their emulation arithmetic; needs --crf pcalib_inside1.txt).")
@click.option("--images", type=click.Choice(RUN_IMAGES), default=RUN_IMAGES[0], show_default=True,
              help="Closed loops: emulated images, the synthetic world's renders at the chosen exposures (truth; "
                   "synthetic trajectories only), or both (truth into OUT/truth; OUT/report/truth_agreement.md "
                   "compares metrics, rankings and verdicts).")
@click.option("--emulate-blur", is_flag=True,
              help="Closed loops: emulate the motion blur of an exposure longer than its source bracket.")
@click.option("--warmup-steps", type=click.IntRange(0, MAX_WARMUP_STEPS), default=None,
              help="Closed loops: steps each method takes on a trajectory's first view before it (not recorded: the "
                   "walk starts with a running camera). Default: the manifest's warmup_steps (a synthetic suite "
                   "declares one), else 0.")
@click.option("--slam", "slam_backend", type=click.Choice(SLAM_BACKENDS), default=SLAM_BACKENDS[0],
              show_default=True, help="Localisation: ORB-SLAM3 stereo, or the built-in VO (fast, deterministic).")
@click.option("--vocabulary", type=input_file(), default=None,
              help="ORB-SLAM3 vocabulary (e.g. ORBvoc.txt; env PYORBSLAM3_VOCAB). Default: the project's own, "
                   "built once into the user cache (never downloaded).")
@click.option("--slam-pace", default=DEFAULT_SLAM_PACE, show_default=True,
              help="ORB-SLAM3 feed: 'lockstep' (each frame once ORB-SLAM3's mapping threads are idle: results that "
                   "do not move with the machine's load), 'realtime' (the recording's timestamps) or seconds per "
                   "frame (0 = unpaced).")
@click.option("--loop-closing/--no-loop-closing", default=True, show_default=True,
              help="ORB-SLAM3's loop-closing thread; off also turns relocalisation off.")
@click.option("--slam-repeats", default=1, show_default=True, type=Integer(1, 50),
              help="SLAM runs per (trajectory, method): the report gives median and spread, statistics use medians.")
@click.option("--setup-check/--no-setup-check", default=True, show_default=True,
              help="ORB-SLAM3: before the methods run, check that it tracks the first seconds of a trajectory's "
                   "middle bracket (no AE) with this vocabulary and calibration; a failure is one error line, exit 2. "
                   "Off: for a dataset whose every trajectory starts unusably (e.g. in darkness).")
@quiet_option("No progress bar for the closed loops.")
def command(datasets: tuple[Path, ...], methods: str, method_option: tuple[str, ...], method_options: Path | None,
            stats_methods: str, out_dir: Path, reference: str,
            scheduler: str | None, workers: int, cluster: str | None, jobs: int, job_cores: int | None,
            job_memory: str | None, job_walltime: float | None, job_partition: str | None, job_account: str | None,
            windows_text: str | None, alpha: float, max_frames: int | None,
            write_images: bool, export_orbslam: bool, slam_dir: Path | None, drl_weights: Path | None,
            selection: str, crf: str,
            init_exposure_ms: float, seed: int, ae_camera: str, parity: str, slam_backend: str, vocabulary: Path | None,
            slam_pace: str, loop_closing: bool, slam_repeats: int, setup_check: bool, quiet: bool, images: str,
            emulate_blur: bool, warmup_steps: int | None) -> int:
    """Benchmark AE methods on DATASET... (trajectory folders, trajectory .zip archives read in place, or manifest
    YAMLs naming subsets).

    Per trajectory, the closed loops of all methods (unless the dataset already holds a method's emulated run) run
    in one pass that decodes each bracket sequence once; then per (trajectory, method) ORB-SLAM3 stereo (each run
    in its own process, its output in a log beside the run; a failed run is a line in the report) or the built-in
    VO, RTE/RRE with evo, the distance tracked and the failure metrics. SLAM gets the emulated images in memory
    as the closed loops make them (PNGs only with --write-images or --export-orbslam). Results are cached under
    OUT/cache, so running the same command again resumes. The report is written to OUT/report (CSV, Markdown,
    HTML, figures). Exit code 0. With ORB-SLAM3 the vocabulary is checked first and a set-up check (ORB-SLAM3 on
    the first seconds of a trajectory's middle bracket, no AE) must pass: else one error line, exit 2.
    """
    import os

    from bracketry_emulator.runtime_policy import apply_profile

    apply_profile("benchmark")  # before numpy loads
    from bracketry_emulator.ae import LoopConfig, parse_method_options
    from bracketry_emulator.benchmark import BenchmarkConfig, RunResult, run_benchmark
    from bracketry_emulator.benchmark.cluster import SlurmOptions, slurm_walltime
    from bracketry_emulator.benchmark.slam import slam_options

    if scheduler is not None and not scheduler.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
        raise BracketryError(f"bad --scheduler {scheduler!r} (expected tcp://HOST:PORT)")
    if scheduler is not None and cluster is not None:
        raise BracketryError("--scheduler and --cluster exclude each other (a cluster you run, or batch jobs)")
    slurm = None if cluster is None else SlurmOptions(
        jobs, job_cores, job_memory, None if job_walltime is None else slurm_walltime(job_walltime), job_partition,
        job_account)
    windows_m = _windows(windows_text) if windows_text is not None else None
    plugin_options = parse_method_options(method_option, method_options)
    if workers == 0:
        workers = os.cpu_count() or 1

    slam = slam_options(slam_backend, vocabulary, slam_pace, loop_closing, slam_repeats, resolve=False)

    loop = LoopConfig.from_json({"selection": selection, "crf": crf, "init_exposure_us": init_exposure_ms * 1000.0,
                                 "seed": seed, "ae_camera": ae_camera, "parity": parity, "blur": emulate_blur,
                                 "images": "truth" if images == "truth" else "emulated"})

    def done(r: RunResult) -> None:
        rep = f" (repeat {r.repeat + 1})" if slam_repeats > 1 else ""
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

    config = BenchmarkConfig(datasets, methods, out_dir, reference=reference, scheduler=scheduler, cluster=slurm,
                             workers=workers,
                             windows_m=windows_m, max_frames=max_frames, alpha=alpha, export_orbslam=export_orbslam,
                             slam_dir=slam_dir, drl_weights=str(drl_weights) if drl_weights else None,
                             progress=not quiet, loop=loop, slam=slam, stats_methods=stats_methods,
                             write_images=write_images, setup_check=setup_check, method_options=plugin_options,
                             warmup_steps=warmup_steps)
    if images == "both":  # truth images first refused (one line) for any non-synthetic trajectory, before any work
        from dataclasses import replace

        from bracketry_emulator.benchmark.orchestrate import check_truth_datasets

        check_truth_datasets(config.datasets)
    result = run_benchmark(config, on_done=done, slam_echo=click.echo)
    click.echo(f"report: {result.report_files.get('report.html')}")
    if images == "both":
        from bracketry_emulator.benchmark.truth_agreement import truth_agreement, write_truth_agreement

        click.echo("truth images:")
        truth = run_benchmark(replace(config, out_dir=out_dir / "truth", loop=replace(loop, images="truth")),
                              on_done=done, slam_echo=click.echo)
        methods_run = list(dict.fromkeys(r["method"] for r in result.results))
        doc = truth_agreement(result.results, truth.results, methods_run, reference, alpha)
        _json, md = write_truth_agreement(doc, out_dir / "report")
        v = doc["verdicts"]
        click.echo(f"emulated vs truth: Kendall tau {doc['kendall_tau_median']:.2f} (median over metrics), verdicts "
                   f"agree {v['agree']}/{v['total']}: {md}")
    return EXIT_OK
