"""``bracketry synth calibration``: a rendered board session with its true stereo calibration (a subcommand of
``bracketry synth``, registered there)."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    SEED,
    Number,
    count,
    input_dir,
    input_file,
    output_dir,
    overwrite_option,
    quiet_option,
)


def load_board_file(path: Path):
    """The board of a ``board.yaml`` (one-line error when it is not one)."""
    import yaml

    from bracketry_base.calibration.board import BoardSpec

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BracketryError(f"cannot read the board definition {path}: {' '.join(str(exc).split())}") from None
    return BoardSpec.from_dict(doc)


@click.command("calibration")
@click.option("--out", "out", type=output_dir(), required=True, help="Output folder (new or empty).")
@overwrite_option()
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the board poses and the noise.")
@click.option("--resolution", default="640x400", show_default=True, help="WxH (even); the rig's is 1920x1200.")
@click.option("--views", "n_views", type=count(6, 1000), default=40, show_default=True,
              help="Board views (image pairs) to render, 6..1000.")
@click.option("--calibration", type=input_dir(), default=None,
              help="Folder with left.yaml/right.yaml giving the true intrinsics (default: the real sample's).")
@click.option("--baseline-m", type=Number(0.01, 2.0), default=None,
              help="True baseline in metres, 0.01..2 (default: the synthetic rig's 0.18).")
@click.option("--board", "board_file", type=input_file(), default=None,
              help="board.yaml of the board to render (default: ChArUco 8x6 squares of 90 mm, DICT_4X4_50).")
@quiet_option()
def command(out: Path, overwrite: bool, seed: int, resolution: str, n_views: int, calibration: Path | None,
            baseline_m: float | None, board_file: Path | None, quiet: bool) -> int:
    """A hand-held board session seen by the synthetic stereo cameras (lens distortion on, some views blurred,
    partial or over-exposed): left/ and right/ image pairs, truth/left.yaml and truth/right.yaml (the true
    calibration, camera_info), board.yaml and session.json. `bracketry calibrate solve OUT` calibrates it."""
    from bracketry_base.calibration.board import BoardSpec
    from bracketry_base.progress import Progress
    from bracketry_emulator.synth import default_calibration, parse_resolution
    from bracketry_emulator.synth.board_session import write_board_session
    from bracketry_emulator.synth.calibration import DEFAULT_BASELINE_M, load_calibration

    size = parse_resolution(resolution)
    base = DEFAULT_BASELINE_M if baseline_m is None else baseline_m
    calib = (load_calibration(calibration, *size, baseline_m=base) if calibration is not None
             else default_calibration(*size, baseline_m=base))
    board = load_board_file(board_file) if board_file is not None else BoardSpec()
    out.mkdir(exist_ok=True)
    bar = Progress("synth calibration", unit="view", enabled=not quiet)
    try:
        summary = write_board_session(out, board, calib, seed, n_views, progress=lambda d, t: bar.set(d, t))
    finally:
        bar.close()
    c = summary["counts"]
    click.echo(f"wrote {n_views} board views ({c['partial']} partial, {c['blurred']} blurred, {c['heavy_blur']} "
               f"heavily blurred, {c['overexposed']} over-exposed) at {size[0]}x{size[1]}, truth in {out / 'truth'}")
    return EXIT_OK
