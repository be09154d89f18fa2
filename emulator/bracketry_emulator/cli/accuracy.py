"""``bracketry accuracy``: the emulator's accuracy protocols (static stack, neighbours on real data, motion on a
synthetic walk); JSON (+ PNG)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    EXIT_PROBLEMS,
    SEED,
    Integer,
    Number,
    input_dir,
    input_path,
    output_dir,
    overwrite_option,
)

#: the effects ``truth-causes`` switches off (bracketry_emulator.ae.truth.TRUTH_EFFECTS; kept here so that the
#: command's help does not import the emulator)
TRUTH_EFFECT_NAMES: tuple[str, ...] = ("blur", "noise", "instant", "exposure")


def _write(out_dir: Path, name: str, result: dict) -> Path:
    out_dir.mkdir(exist_ok=True)
    path = out_dir / f"{name}.json"
    path.write_text(json.dumps(result, indent=1, allow_nan=True) + "\n")
    return path


def _fmt(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:8.2f}"


def _progress(label: str) -> Callable[[int, int], None] | None:
    """A progress callback writing to stderr when it is a terminal, else None."""
    if not sys.stderr.isatty():
        return None

    def cb(done: int, total: int) -> None:
        click.echo(f"\r{label}: {done}/{total}", nl=done == total, err=True)
    return cb


@click.group("accuracy")
def command() -> None:
    """Measure the emulator's accuracy (static stack, neighbours on real data, motion blur on a synthetic walk)."""


@command.command("static")
@click.argument("stack_dir", type=input_dir())
@click.option("--out", "out_dir", type=output_dir(), default=None,
              help="Output folder (new or empty) for accuracy_static.json and .png [default: STACK_DIR/accuracy].")
@overwrite_option()
@click.option("--crf", default="srgb", show_default=True, help="Camera response: 'srgb' or a pcalib.txt file.")
@click.option("--max-targets", type=Integer(0, 10**6), default=250, show_default=True,
              help="Ground-truth exposures used (evenly spread; 0 = all).")
@click.option("--alpha", type=Number(0.0, 1.0, min_open=True, max_open=True), default=0.01, show_default=True,
              help="HigherNoSat saturation threshold (fraction of saturated pixels), in (0, 1).")
@click.option("--side", type=click.Choice(["left", "right"]), default="left", show_default=True,
              help="Camera side of a plain BorealHDR-tree stack.")
@click.option("--noise", type=click.Path(path_type=Path, exists=True, dir_okay=False), default=None,
              help="Camera noise model of the fusion weights (calibrate-crf --noise-out JSON or camera_model.json) "
                   "[default: STACK_DIR/camera_model.json when present, else built-in].")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def static_cmd(stack_dir: Path, out_dir: Path | None, overwrite: bool, crf: str, max_targets: int, alpha: float,
               side: str, noise: Path | None, as_json: bool) -> int:
    """Emulate the ground-truth exposures of a static stack (the paper's protocol; 250 spread evenly over the
    sweep by default, --max-targets 0 for every one); RMSE median/max per mode.

    Exit code 0 when the HigherNoSat goals (median <= 9 DN, max <= 73 DN, noise-corrected) hold, 1 otherwise.
    """
    from bracketry_base.outputs import check_output
    from bracketry_emulator.accuracy import open_static_stack, run_static
    from bracketry_emulator.accuracy.plots import plot_static

    if out_dir is None:
        out_dir = check_output(stack_dir / "accuracy", "dir", overwrite=overwrite)
    _check_crf(crf)
    stack = open_static_stack(stack_dir, side=side)
    noise_model = None
    if noise is not None:
        from bracketry_emulator.emulation.noise import resolve_noise_model

        noise_model, _source = resolve_noise_model(noise)
    result = run_static(stack, crf=crf, max_targets=max_targets or None, alpha=alpha,
                        progress=_progress("static targets"), noise_model=noise_model)
    out = out_dir
    jpath = _write(out, "accuracy_static", result)
    ppath = plot_static(result, out / "accuracy_static.png")
    if as_json:
        click.echo(json.dumps({"summary": result["summary"], "goals": result["goals"]}, indent=1))
    else:
        click.echo(f"{result['n_targets']} targets, brackets {[b / 1000 for b in result['brackets_us']]} ms, "
                   f"crf {result['crf']}")
        click.echo(f"{'mode':12s} {'metric':10s} {'median':>8s} {'max':>8s} {'med.in':>8s}")
        for mode, metrics in result["summary"].items():
            for metric, s in metrics.items():
                click.echo(f"{mode:12s} {metric:10s} {_fmt(s['all']['median'])} {_fmt(s['all']['max'])} "
                           f"{_fmt(s['in_bracket_range']['median'])}")
        for name, g in result["goals"].items():
            click.echo(f"goal {name}: {'met' if g['met'] else 'NOT met'} "
                       f"({', '.join(f'{k}={v:.3g}' for k, v in g.items() if k != 'met')})")
        click.echo(f"wrote {jpath} and {ppath}")
    g = result["goals"]
    ok = all(g[k]["met"] for k in ("highernosat_median_le_9dn", "highernosat_max_le_73dn") if k in g)
    return EXIT_OK if ok else EXIT_PROBLEMS


@command.command("motion")
@click.option("--out", "out_dir", type=output_dir(), required=True,
              help="Output folder (new or empty) for motion.json.")
@overwrite_option()
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the synthetic world.")
@click.option("--preset", type=click.Choice(["forest-winter", "campus-summer"]), default="forest-winter",
              show_default=True, help="World preset (as bracketry synth).")
@click.option("--instants", type=Integer(1, 100), default=3, show_default=True,
              help="Trigger instants per speed (each row is the median over them).")
@click.option("--resolution", default="640x400", show_default=True,
              help="WxH (even) of the renders (below 640x400 the walk moves under a pixel per bracket period).")
@click.option("--reference", type=click.Choice(["exact", "reproject"]), default="exact", show_default=True,
              help="True frames: the exact integral (a ray cast every pixel of motion) or the world's default warp "
                   "of one ray cast (the former protocol; its own error is as large as the emulator's).")
@click.option("--supersample", type=Integer(1, 4), default=2, show_default=True,
              help="Sub-samples per pixel side (each colour plane area-averaged, as a sensor pixel); 1: point "
                   "sampled.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def motion_cmd(out_dir: Path, overwrite: bool, seed: int, preset: str, instants: int, resolution: str,
               reference: str, supersample: int, as_json: bool) -> int:
    """Emulated 16 and 32 ms frames from 1-8 ms sources of a walking synthetic camera (2 and 5 km/h, and held
    still) against the world's true renders, with and without motion-blur emulation; writes OUT/motion.json.

    Exit code 0 when blur emulation lowers the moving rows' RMSE by >= 30 % (median) and is never worse on the
    still camera, 1 otherwise."""
    from bracketry_emulator.accuracy.motion import run_motion
    from bracketry_emulator.synth import parse_resolution

    size = parse_resolution(resolution)
    result = run_motion(seed=seed, preset=preset, resolution=size, n_instants=instants, reference=reference,
                        supersample=supersample, progress=_progress("speeds x instants"))
    jpath = _write(out_dir, "motion", result)
    if as_json:
        click.echo(json.dumps({"summary": result["summary"], "goals": result["goals"]}, indent=1))
    else:
        click.echo(f"{'km/h':>5s} {'src ms':>6s} {'tgt ms':>6s} {'rmse plain':>10s} {'rmse blur':>9s} "
                   f"{'sharp.err plain':>15s} {'sharp.err blur':>14s}")
        for r in result["rows"]:
            click.echo(f"{r['speed_kmh']:5g} {r['source_ms']:6g} {r['target_ms']:6g} {r['rmse_dn_plain']:10.1f} "
                       f"{r['rmse_dn_blur']:9.1f} {r['sharpness_error_plain']:15.3f} {r['sharpness_error_blur']:14.3f}")
        for speed, sm in result["summary"].items():
            line = (f"{speed:>5s} km/h: median rmse plain {sm['rmse_dn_plain_median']:.1f}, blur "
                    f"{sm['rmse_dn_blur_median']:.1f}, reduction {100 * sm['rmse_reduction_median']:.1f} %")
            if "rmse_reduction_reproject_median" in sm:
                line += (f" (reprojected point-sampled reference: {sm['rmse_dn_plain_reproject_median']:.1f} -> "
                         f"{sm['rmse_dn_blur_reproject_median']:.1f}, "
                         f"{100 * sm['rmse_reduction_reproject_median']:.1f} %)")
            line += (f"; off depth edges {100 * sm['rmse_reduction_off_edges_median']:.1f} % (edges hold "
                     f"{100 * sm['depth_edge_error_share_blur_median']:.0f} % of the blurred error)")
            click.echo(line)
        for name, g in result["goals"].items():
            click.echo(f"goal {name}: {'met' if g['met'] else 'NOT met'} "
                       f"({', '.join(f'{k}={v:.3g}' for k, v in g.items() if k != 'met')})")
        click.echo(f"wrote {jpath}")
    return EXIT_OK if all(g["met"] for g in result["goals"].values()) else EXIT_PROBLEMS


@command.command("truth-causes")
@click.argument("manifest", type=input_path())
@click.option("--out", "out_dir", type=output_dir(existing="resume"), required=True,
              help="Output folder: OUT/both (the emulated and truth benchmark, --images both), OUT/variants/<effect> "
                   "(the truth benchmark without that effect); an existing one is resumed.")
@click.option("--methods", "-m", default="fix,ae30,ae50,ae70,shim,wang,kim", show_default=True,
              help="AE methods (comma-separated), as bracketry benchmark (default: the paper's seven without DRL).")
@click.option("--effects", default="blur,noise,instant", show_default=True,
              help="Effects of the truth switched off one at a time (comma-separated; also: exposure, a no-op with "
                   "the benchmark's camera, which takes gain beyond the longest bracket in the truth too).")
@click.option("--reference", default="ae50", show_default=True, help="Reference method of the statistics.")
@click.option("--slam", "slam_backend", type=click.Choice(["builtin", "orbslam3"]), default="builtin",
              show_default=True, help="Localisation (as bracketry benchmark).")
@click.option("--emulate-blur/--no-emulate-blur", default=True, show_default=True,
              help="Closed loops of the emulated run: motion-blur emulation.")
@click.option("--workers", default=1, show_default=True, type=Integer(0, 256),
              help="Local worker processes of each benchmark (0 = one per CPU).")
@click.option("--max-frames", default=None, type=Integer(2), help="Only the first N frames of each run.")
@click.option("--windows", "windows_text", default=None,
              help="RTE/RRE windows in metres, as bracketry benchmark. Default: the manifest's windows_m (the "
                   "demo-size suite's 10 s walks declare 2-8 m), else 5:50:1 (the paper's).")
def truth_causes_cmd(manifest: Path, out_dir: Path, methods: str, effects: str, reference: str,
                     slam_backend: str, emulate_blur: bool, workers: int, max_frames: int | None,
                     windows_text: str | None) -> int:
    """Which effect (blur, the frame's instant, noise, exposure vs gain) drives the disagreement of emulated and
    truth benchmarks on a synthetic suite MANIFEST: the truth benchmark again with each effect switched off;
    writes OUT/both/report/truth_causes.{json,md} (and a section of truth_agreement.md there)."""
    from bracketry_emulator.benchmark.truth_causes import (
        causes_markdown,
        truth_causes,
        variant_dataset,
        write_truth_causes,
    )

    from .benchmark import command as benchmark

    wanted = [e.strip() for e in effects.split(",") if e.strip()]
    bad = [e for e in wanted if e not in TRUTH_EFFECT_NAMES]
    if bad or not wanted:
        raise BracketryError(f"--effects: unknown {', '.join(bad) or 'none given'} (choose from "
                             f"{', '.join(TRUTH_EFFECT_NAMES)})")
    common = ["--methods", methods, "--reference", reference, "--slam", slam_backend, "--workers", str(workers),
              "--quiet", "--resume"] + (["--windows", windows_text] if windows_text else []) + \
        (["--emulate-blur"] if emulate_blur else []) + \
        (["--max-frames", str(max_frames)] if max_frames else [])
    out_dir.mkdir(parents=True, exist_ok=True)

    def run(args: list[str]) -> list[dict]:
        out = Path(args[args.index("--out") + 1])
        benchmark.main(args=args, standalone_mode=False, prog_name="bracketry benchmark")
        return json.loads((out / "report" / "results.json").read_text())

    click.echo("emulated and truth images:")
    emulated = run([str(manifest), "--images", "both", "--out", str(out_dir / "both"), *common])
    truth = json.loads((out_dir / "both" / "truth" / "report" / "results.json").read_text())
    variants: dict[str, list[dict]] = {}
    for eff in wanted:
        click.echo(f"truth without {eff}:")
        vman = variant_dataset(Path(manifest), eff, out_dir / "variants" / eff / "data")
        variants[eff] = run([str(vman), "--images", "truth", "--out", str(out_dir / "variants" / eff / "bench"),
                             *common])
    method_list = list(dict.fromkeys(r["method"] for r in emulated))
    doc = truth_causes(emulated, truth, variants, method_list)
    jpath, mpath = write_truth_causes(doc, out_dir / "both" / "report")
    click.echo("\n".join(causes_markdown(doc)))
    click.echo(f"wrote {jpath} and {mpath}")
    return EXIT_OK


@command.command("neighbours")
@click.argument("dataset", type=input_path())
@click.option("--out", "out_dir", type=output_dir(), default=Path("accuracy-neighbours"),
              show_default=True, help="Output folder (new or empty) for accuracy_neighbours.json and .png.")
@overwrite_option()
@click.option("--crf", default="srgb", show_default=True, help="Camera response: 'srgb' or a pcalib.txt file.")
@click.option("--camera", type=click.Choice(["left", "right", "both"]), default="both", show_default=True,
              help="Cameras whose brackets are emulated.")
@click.option("--alignment", type=click.Choice(["homography", "translation"]), default="homography",
              show_default=True, help="Global alignment used for the aligned variant.")
@click.option("--max-sequences", type=Integer(0, 10**6), default=0, show_default=True,
              help="Use the first N bracket sequences (0 = all).")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def neighbours_cmd(dataset: Path, out_dir: Path, overwrite: bool, crf: str, camera: str, alignment: str,
                   max_sequences: int, as_json: bool) -> int:
    """Emulate bracket k from k-1 and k+1 on real data, with and without alignment; RMSE and bias per mode."""
    from bracketry_emulator.accuracy import run_neighbours
    from bracketry_emulator.accuracy.plots import plot_neighbours
    from bracketry_emulator.dataset import open_dataset

    _check_crf(crf)
    ds = open_dataset(dataset)
    sides = ds.sides if camera == "both" else (camera,)
    if any(s not in ds.sides for s in sides):
        raise BracketryError(f"dataset has no {camera} camera (sides: {', '.join(ds.sides)})")
    result = run_neighbours(ds, sides=sides, crf=crf, alignments=("none", alignment),  # type: ignore[arg-type]
                            max_sequences=max_sequences or None, progress=_progress("sequences x sides"))
    jpath = _write(out_dir, "accuracy_neighbours", result)
    ppath = plot_neighbours(result, out_dir / "accuracy_neighbours.png")
    if as_json:
        click.echo(json.dumps({"summary": result["summary"], "goals": result["goals"]}, indent=1))
    else:
        click.echo(f"{result['n_pairs']} emulated frames from {result['n_sequences']} sequences, sides {sides}")
        click.echo(f"{'alignment':11s} {'mode':12s} {'rmse med':>8s} {'rmse mean':>9s} {'bias med':>8s}")
        for al, modes in result["summary"].items():
            for mode, s in modes.items():
                click.echo(f"{al:11s} {mode:12s} {_fmt(s['rmse_dn']['median'])} {_fmt(s['rmse_dn']['mean'])}  "
                           f"{_fmt(s['bias_dn']['median'])}")
        for name, g in result["goals"].items():
            click.echo(f"goal {name}: {'met' if g['met'] else 'NOT met'}")
        click.echo(f"wrote {jpath} and {ppath}")
    return EXIT_OK


def _check_crf(crf: str) -> None:
    if crf.lower() != "srgb" and not Path(crf).is_file():
        raise BracketryError(f"--crf must be 'srgb' or a pcalib.txt file, got {crf!r}")
