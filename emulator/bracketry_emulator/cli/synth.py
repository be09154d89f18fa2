"""``bracketry synth``: render synthetic bracketed HDR stereo data (a walk, or the static protocol)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    SEED,
    WORKERS,
    Duration,
    Number,
    count,
    input_dir,
    input_file,
    option,
    output_dir,
    overwrite_option,
    quiet_option,
)
from bracketry_emulator.cli.synth_calibration import command as calibration_cmd


def _parse_ms_list(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise BracketryError(f"{what} must be comma-separated milliseconds, e.g. 1,2,4,8 (got {text!r})") from None
    if not values or any(v <= 0 for v in values):
        raise BracketryError(f"{what} must be positive milliseconds (got {text!r})")
    return values


def _camera(response: str):
    from bracketry_emulator.synth import CameraModel

    if response in ("srgb", "linear"):
        return CameraModel(response=response)
    path = Path(response)
    if not path.is_file():
        raise BracketryError(f"--response must be srgb, linear or a pcalib file (not found: {response})")
    return CameraModel.with_pcalib_file(path)


def _scenario_world(ctx: click.Context, scenario_file: Path, seed: int, seconds: float, resolution: str,
                    brackets_ms: str, fps: float, response: str, calibration: Path | None, detail: float,
                    motion_blur: bool):
    """The world of a scenario file, and its duration, brackets and fps (the command line's where given)."""
    from click.core import ParameterSource

    from bracketry_emulator.synth import parse_resolution
    from bracketry_emulator.synth.calibration import load_calibration
    from bracketry_emulator.synth.scenario import load_scenario
    from bracketry_emulator.synth.world import world_from_scenario

    def given(name: str) -> bool:
        return ctx.get_parameter_source(name) == ParameterSource.COMMANDLINE

    if given("preset") or given("speed_kmh"):
        raise BracketryError("--preset and --speed-kmh come from the scenario (its preset, route.pace_kmh)")
    sc = load_scenario(scenario_file)
    size = parse_resolution(resolution) if given("resolution") else sc.resolution
    calib = load_calibration(calibration, *size) if calibration is not None else None
    world = world_from_scenario(sc, seed=seed if given("seed") else sc.seed, resolution=size, detail=detail,
                                camera=_camera(response), calibration=calib, motion_blur=motion_blur)
    brackets = _parse_ms_list(brackets_ms, "--brackets-ms") if given("brackets_ms") else sc.brackets_ms
    return (world, seconds if given("seconds") else sc.duration_s, brackets, fps if given("fps") else sc.fps)


def _make_world(preset: str, seed: int, resolution: str, response: str, calibration: Path | None,
                speed_kmh: float, motion_blur: bool = False, detail: float = 1.0, blooming: bool = True):
    """The world of the command-line options; ``blooming=False``: a camera whose saturated pixels do not spill."""
    import dataclasses

    from bracketry_emulator.synth import LoopTrajectory, World, parse_resolution
    from bracketry_emulator.synth.calibration import load_calibration

    size = parse_resolution(resolution)
    camera = _camera(response)
    if not blooming:
        camera = dataclasses.replace(camera, blooming=0.0)
    calib = load_calibration(calibration, *size) if calibration is not None else None
    if speed_kmh <= 0 or speed_kmh > 20:
        raise BracketryError("--speed-kmh must be in (0, 20]")
    return World(preset, seed, size, calibration=calib, camera=camera, trajectory=LoopTrajectory(speed_kmh=speed_kmh),
                 motion_blur=motion_blur, detail=detail)


def _out_dir(out: Path) -> Path:
    """The output folder, created (the --out type checked it before any work)."""
    out.mkdir(exist_ok=True)
    return out


def _progress(desc: str, quiet: bool):
    from bracketry_base.progress import Progress

    bar = Progress(desc, unit="img", enabled=not quiet)

    def update(done: int, total: int) -> None:
        bar.set(done, total)

    return bar, update


_common = [
    click.option("--out", "out", type=output_dir(), required=True, help="Output folder (new or empty)."),
    overwrite_option(),
    click.option("--preset", type=click.Choice(["forest-winter", "campus-summer"]), default="forest-winter",
                 show_default=True, help="World preset."),
    click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the world and of the noise."),
    click.option("--response", default="srgb", show_default=True,
                 help="Camera response: srgb (like the real sample), linear, or a pcalib.txt file (TUM 256 values, "
                      "or the 4096 of bracketry calibrate-crf)."),
    click.option("--calibration", type=input_dir(), default=None,
                 help="Folder with left.yaml/right.yaml to take the intrinsics from (default: the real sample's)."),
    quiet_option(),
]


def _with_common(f):
    for opt in reversed(_common):
        f = opt(f)
    return f


@click.group("synth")
def command() -> None:
    """Render synthetic bracketed HDR stereo data with exact ground truth."""


@command.command("trajectory")
@_with_common
@option("--duration-s", "seconds", aliases=("--seconds",), type=Duration(3600.0), default=10.0, show_default=True,
        help="Duration in seconds (whole bracket cycles), at most 3600.")
@click.option("--resolution", default="960x600", show_default=True, help="WxH (even).")
@click.option("--brackets-ms", default="1,2,4,8,16,32", show_default=True, help="Bracket exposures, ms.")
@click.option("--fps", type=Number(0.0, 200.0, min_open=True), default=22.0, show_default=True,
              help="Frame rate (one bracket per frame), in (0, 200].")
@click.option("--speed-kmh", type=Number(0.0, 20.0, min_open=True), default=2.0, show_default=True,
              help="Walking speed in km/h, in (0, 20].")
@click.option("--start-s", type=Number(0.0, 1e6), default=0.0, show_default=True,
              help="Start time along the walk (s).")
@click.option("--motion-blur/--no-motion-blur", default=True, show_default=True,
              help="Integrate the motion over each exposure (one render per frame, moved by its range to instants "
                   "~1 px of motion apart); off: each frame is the render at its mid-exposure.")
@click.option("--scenario", "scenario_file", type=input_file(), default=None,
              help="A scenario YAML (route, pace, time of day, weather, lighting events; see DATASET.md and the "
                   "shipped ones in bracketry_emulator/synth/scenarios/): its preset, seed, duration, resolution, "
                   "fps and brackets unless given here.")
@click.option("--detail", type=Number(0.05, 2.0), default=1.0, show_default=True,
              help="Ground texture detail (1.0: 4 cm texels near the path; less builds the world faster).")
@click.pass_context
def trajectory_cmd(ctx: click.Context, out: Path, overwrite: bool, preset: str, seed: int, response: str,
                   calibration: Path | None, quiet: bool, seconds: float, resolution: str, brackets_ms: str, fps: float,
                   speed_kmh: float, start_s: float, motion_blur: bool, scenario_file: Path | None,
                   detail: float) -> int:
    """A stereo walk along a loop: BorealHDR tree + groundtruth.txt + calibration/ + camera_model.json."""
    from bracketry_emulator.synth import write_trajectory

    if scenario_file is not None:
        world, seconds, brackets, fps = _scenario_world(ctx, scenario_file, seed, seconds, resolution, brackets_ms,
                                                        fps, response, calibration, detail, motion_blur)
    else:
        brackets = _parse_ms_list(brackets_ms, "--brackets-ms")
        world = _make_world(preset, seed, resolution, response, calibration, speed_kmh, motion_blur, detail)
    out = _out_dir(out)
    bar, update = _progress("synth trajectory", quiet)
    try:
        summary = write_trajectory(world, out, seconds=seconds, brackets_ms=brackets, fps=fps, start_s=start_s,
                                   progress=update)
    finally:
        bar.close()
    if world.scenario is not None:
        import yaml

        (out / "scenario.yaml").write_text(yaml.safe_dump(world.scenario.to_dict(), sort_keys=False))
    click.echo(f"wrote {summary['frames']} frames x {len(summary['sides'])} cameras ({summary['cycles']} bracket "
               f"cycles, {summary['duration_s']:.2f} s, radiance range {summary['radiance_range_db']:.0f} dB) "
               f"to {out}")
    return EXIT_OK


@command.command("static")
@_with_common
@click.option("--resolution", default="640x400", show_default=True, help="WxH (even).")
@click.option("--n-exposures", type=count(2, 100000), default=1000, show_default=True,
              help="Sweep length (log-spaced).")
@click.option("--min-us", type=Number(0.0, 1e7, min_open=True), default=20.0, show_default=True,
              help="Shortest sweep exposure (us).")
@click.option("--max-us", type=Number(0.0, 1e7, min_open=True), default=50000.0, show_default=True,
              help="Longest sweep exposure (us).")
@click.option("--repeats", type=count(1, 1000), default=25, show_default=True, help="Frames per repeat exposure.")
@click.option("--repeat-ms", default="0.1,0.5,1,2,4,8,16,32", show_default=True,
              help="Exposures with repeated frames (noise estimation), ms.")
@click.option("--brackets-ms", default="1,2,4,8,16,32", show_default=True, help="Bracket set, ms.")
@click.option("--side", type=click.Choice(["left", "right"]), default="left", show_default=True,
              help="Camera whose view is rendered.")
@click.option("--t-s", "t_s", type=Number(0.0, 1e6), default=0.0, show_default=True,
              help="Time of the static view along the walk (s).")
def static_cmd(out: Path, overwrite: bool, preset: str, seed: int, response: str, calibration: Path | None,
               quiet: bool, resolution: str, n_exposures: int, min_us: float, max_us: float, repeats: int,
               repeat_ms: str, brackets_ms: str, side: str, t_s: float) -> int:
    """The emulator-validation protocol: sweep, repeats, brackets and the exact noise-free truth of one view (a
    camera without blooming: the protocol measures the emulation of a linear sensor, and no bracket holds the charge
    a longer exposure spills around its saturated areas)."""
    from bracketry_emulator.synth import write_static

    if min_us >= max_us:
        raise BracketryError(f"--min-us ({min_us:g}) must be below --max-us ({max_us:g})")
    reps = _parse_ms_list(repeat_ms, "--repeat-ms")
    brackets = _parse_ms_list(brackets_ms, "--brackets-ms")
    world = _make_world(preset, seed, resolution, response, calibration, 2.0, blooming=False)
    out = _out_dir(out)
    bar, update = _progress("synth static", quiet)
    try:
        index = write_static(world, out, n_exposures=n_exposures, min_us=min_us, max_us=max_us, repeats=repeats,
                             repeat_exposures_ms=reps, brackets_ms=brackets, side=side, t_s=t_s, progress=update)
    finally:
        bar.close()
    click.echo(f"wrote static protocol: {index['sweep']['n']} sweep exposures, {len(reps)} x {repeats} repeats, "
               f"{len(brackets)} brackets ({side}) to {out}")
    return EXIT_OK


command.add_command(calibration_cmd)  # bracketry synth calibration (its own module)


@command.command("suite")
@click.option("--out", "out", type=output_dir(existing="resume"), required=True,
              help="Output folder: new, empty, or holding this very suite (then reused as it is).")
@overwrite_option("Replace a non-empty --out that holds something else.")
@click.option("--size", type=click.Choice(["demo", "full"]), required=True,
              help="demo: 10 trajectories of 10 s at 320x200; full: 28 of 60 s at 640x400.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Suite seed (every world seed follows from it).")
@click.option("--workers", type=WORKERS, default=2, show_default=True,
              help="Trajectories rendered in parallel processes (the bytes do not depend on it).")
@click.option("--no-cache", is_flag=True,
              help="Render straight into --out (default: render into the cache, $BRACKETRY_CACHE or "
                   "~/.cache/bracketry/synth-suites, and link from there).")
@quiet_option()
def suite_cmd(out: Path, overwrite: bool, size: str, seed: int, workers: int, no_cache: bool, quiet: bool) -> int:
    """A versioned suite of synthetic trajectories with ground truth and DIR/manifest.yaml (subsets forest,
    sun-shadow, glare, day-cycle; split train/test), for ``bracketry benchmark DIR/manifest.yaml``."""
    from bracketry_base.progress import Progress
    from bracketry_emulator.synth.suite import cache_dir, make_suite

    bar = Progress("synth suite", unit="trajectory", enabled=not quiet)
    try:
        ident, how = make_suite(out, size, seed, overwrite=overwrite, use_cache=not no_cache,
                                workers=max(1, workers), progress=lambda d, t: bar.set(d, t))
    finally:
        bar.close()
    where = "" if no_cache else f" (cache: {cache_dir(size, seed)})"
    click.echo(f"suite v{ident['version']} {size} seed {seed} {how} in {out}{where}; "
               f"benchmark it with: bracketry benchmark {out / 'manifest.yaml'}")
    return EXIT_OK
