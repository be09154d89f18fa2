"""``bracketry synth``: render synthetic bracketed HDR stereo data (a walk, or the static protocol)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry.cli.options import (
    EXIT_OK,
    SEED,
    Duration,
    Number,
    count,
    input_dir,
    option,
    output_dir,
    overwrite_option,
    quiet_option,
)
from bracketry.errors import BracketryError
from bracketry_emulator.cli.synth_calibration import command as calibration_cmd


def _parse_ms_list(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise BracketryError(f"{what} must be comma-separated milliseconds, e.g. 1,2,4,8 (got {text!r})") from None
    if not values or any(v <= 0 for v in values):
        raise BracketryError(f"{what} must be positive milliseconds (got {text!r})")
    return values


def _make_world(preset: str, seed: int, resolution: str, response: str, calibration: Path | None,
                speed_kmh: float, motion_blur: bool = False):
    from bracketry_emulator.synth import CameraModel, LoopTrajectory, World, parse_resolution
    from bracketry_emulator.synth.calibration import load_calibration

    size = parse_resolution(resolution)
    if response in ("srgb", "linear"):
        camera = CameraModel(response=response)
    else:
        path = Path(response)
        if not path.is_file():
            raise BracketryError(f"--response must be srgb, linear or a pcalib file (not found: {response})")
        camera = CameraModel.with_pcalib_file(path)
    calib = load_calibration(calibration, *size) if calibration is not None else None
    if speed_kmh <= 0 or speed_kmh > 20:
        raise BracketryError("--speed-kmh must be in (0, 20]")
    return World(preset, seed, size, calibration=calib, camera=camera, trajectory=LoopTrajectory(speed_kmh=speed_kmh),
                 motion_blur=motion_blur)


def _out_dir(out: Path) -> Path:
    """The output folder, created (the --out type checked it before any work)."""
    out.mkdir(exist_ok=True)
    return out


def _progress(desc: str, quiet: bool):
    from bracketry.progress import Progress

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
def trajectory_cmd(out: Path, overwrite: bool, preset: str, seed: int, response: str, calibration: Path | None,
                   quiet: bool, seconds: float, resolution: str, brackets_ms: str, fps: float, speed_kmh: float,
                   start_s: float, motion_blur: bool) -> int:
    """A stereo walk along a loop: BorealHDR tree + groundtruth.txt + calibration/ + camera_model.json."""
    from bracketry_emulator.synth import write_trajectory

    brackets = _parse_ms_list(brackets_ms, "--brackets-ms")
    world = _make_world(preset, seed, resolution, response, calibration, speed_kmh, motion_blur)
    out = _out_dir(out)
    bar, update = _progress("synth trajectory", quiet)
    try:
        summary = write_trajectory(world, out, seconds=seconds, brackets_ms=brackets, fps=fps, start_s=start_s,
                                   progress=update)
    finally:
        bar.close()
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
    """The emulator-validation protocol: sweep, repeats, brackets and the exact noise-free truth of one view."""
    from bracketry_emulator.synth import write_static

    if min_us >= max_us:
        raise BracketryError(f"--min-us ({min_us:g}) must be below --max-us ({max_us:g})")
    reps = _parse_ms_list(repeat_ms, "--repeat-ms")
    brackets = _parse_ms_list(brackets_ms, "--brackets-ms")
    world = _make_world(preset, seed, resolution, response, calibration, 2.0)
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
