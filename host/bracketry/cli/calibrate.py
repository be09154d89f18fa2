"""``bracketry calibrate``: geometric stereo calibration (``solve``, ``capture``) and the camera response (``crf``,
also reachable under its old name ``calibrate-crf``).

The commands load, call :mod:`bracketry_base.calibration` (pure: arrays in, calibration out) and save.
"""

from __future__ import annotations

import importlib
import json
import time
from pathlib import Path
from typing import Any

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    EXIT_PROBLEMS,
    SEED,
    Integer,
    Number,
    count,
    input_dir,
    input_file,
    output_dir,
    overwrite_option,
    quiet_option,
)
from bracketry_rig.boardcapture.files import check_png_sizes, image_pairs, load_board, read_image

#: the ORB-SLAM3 settings file written beside the camera_info YAMLs
ORBSLAM3_SETTINGS = "orbslam3_stereo.yaml"

#: subcommands that live in other modules, loaded when used: name -> (module, attribute)
_LAZY = {"crf": ("bracketry_emulator.cli.crf", "command")}


class CalibrateGroup(click.Group):
    """The group, with ``crf`` loaded from the emulator only when used (a rig without the emulator extra keeps
    ``solve`` and ``capture``)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *_LAZY})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in _LAZY:
            mod, attr = _LAZY[cmd_name]
            try:
                return getattr(importlib.import_module(mod), attr)
            except ImportError as exc:
                raise BracketryError(f"'calibrate {cmd_name}' needs the emulator extra "
                                     f"(pip install -e '.[emulator]'): {exc}") from None
        return super().get_command(ctx, cmd_name)


@click.group("calibrate", cls=CalibrateGroup)
def command() -> None:
    """Calibrate the rig: stereo geometry from a board session (solve, capture), camera response (crf)."""


def detect_session(pairs: list[tuple[Path, Path]], board: Any, bayer: bool, quiet: bool
                   ) -> tuple[list[Any], list[Any], tuple[int, int]]:
    """Detect the board in every pair; the images must all have one size. Returns the left and right detections
    (None where not found) and the size (width, height)."""
    from bracketry_base.calibration.detect import detect, to_gray8
    from bracketry_base.progress import Progress

    left: list[Any] = []
    right: list[Any] = []
    first = read_image(pairs[0][0])
    check_png_sizes(pairs, (int(first.shape[1]), int(first.shape[0])))
    size: tuple[int, int] | None = None
    bar = Progress("detect", unit="pair", enabled=not quiet)
    try:
        for k, pair in enumerate(pairs):
            for path, dets in zip(pair, (left, right), strict=True):
                img = read_image(path)
                hw = (int(img.shape[1]), int(img.shape[0]))
                if size is None:
                    size = hw
                elif hw != size:
                    raise BracketryError(f"{path} is {hw[0]}x{hw[1]} but {pairs[0][0]} is {size[0]}x{size[1]}: "
                                         "a session's images must all have one size")
                dets.append(detect(to_gray8(img, bayer=bayer), board))
            bar.set(k + 1, len(pairs))
    finally:
        bar.close()
    assert size is not None
    return left, right, size


@command.command("solve")
@click.argument("session", type=input_dir(), metavar="SESSION")
@click.option("--out", "out", type=output_dir(), required=True,
              help="Calibration folder to write (new or empty): left.yaml, right.yaml, calib_kitti.txt, "
                   f"{ORBSLAM3_SETTINGS}, report.json.")
@overwrite_option()
@click.option("--board", "board_file", type=input_file(), default=None,
              help="board.yaml of the board (default: SESSION/board.yaml).")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the random view subsets.")
@click.option("--trials", type=count(1, 10000), default=24, show_default=True,
              help="Random view subsets tried per camera (the robust selection), 1..10000.")
@click.option("--inlier-px", type=Number(0.05, 100.0), default=1.0, show_default=True,
              help="A view is an inlier when its reprojection RMS is below this (px), 0.05..100.")
@click.option("--max-blur-px", type=Number(0.5, 100.0), default=2.5, show_default=True,
              help="Views whose board edges are blurred more than this (equivalent Gaussian sigma, px) are dropped.")
@click.option("--no-bayer", is_flag=True, help="The images are grey, not raw RGGB mosaics.")
@click.option("--k3", "free_k3", is_flag=True,
              help="Estimate the third radial coefficient k3 too (default: fixed at 0, as ROS camera_calibration "
                   "and BorealHDR's files).")
@click.option("--fps", type=Number(0.0, 1000.0, min_open=True), default=22.0, show_default=True,
              help="Frame rate written into the ORB-SLAM3 settings, in (0, 1000].")
@click.option("--json", "as_json", is_flag=True, help="Print the report as JSON.")
@quiet_option()
def solve_cmd(session: Path, out: Path, overwrite: bool, board_file: Path | None, seed: int, trials: int,
              inlier_px: float, max_blur_px: float, no_bayer: bool, free_k3: bool, fps: float, as_json: bool,
              quiet: bool) -> int:
    """Calibrate the stereo pair from a board session (SESSION/left/*.png, SESSION/right/*.png, or a recording
    exported as a BorealHDR tree: SESSION/camera_left/<exposure>/, camera_right/; the board in SESSION/board.yaml
    or --board): intrinsics and distortion per camera, extrinsics, rectification, with a robust
    selection over random subsets of the views; dropped views are listed in report.json."""
    from bracketry_base.calibration.camera_info import camera_info_yaml, kitti_text, rectified_camera, report
    from bracketry_base.calibration.solve import solve_stereo

    if board_file is None:
        board_file = session / "board.yaml"
        if not board_file.is_file():
            raise BracketryError(f"no board.yaml in {session}: give the board with --board board.yaml")
    board = load_board(board_file)
    pairs = image_pairs(session)
    t0 = time.perf_counter()
    left, right, size = detect_session(pairs, board, not no_bayer, quiet)
    sol = solve_stereo(left, right, board, size, seed=seed, trials=trials, inlier_px=inlier_px,
                       max_blur_px=max_blur_px, fix_k3=not free_k3)
    solve_s = time.perf_counter() - t0
    rep = report(sol, len(pairs), solve_s)
    rep["views_files"] = [p[0].name for p in pairs]
    rep["board"] = board.to_dict()
    files = {"left.yaml": camera_info_yaml(sol, "left"), "right.yaml": camera_info_yaml(sol, "right"),
             "calib_kitti.txt": kitti_text(sol), ORBSLAM3_SETTINGS: _orbslam3_settings(sol, fps),
             "report.json": json.dumps(rep, indent=1) + "\n"}
    out.mkdir(exist_ok=True)
    for name, text in files.items():
        tmp = out / f".{name}.tmp"
        tmp.write_text(text)
        tmp.replace(out / name)
    if as_json:
        click.echo(json.dumps(rep, indent=1))
        return EXIT_OK
    rect = rectified_camera(sol)
    for side in ("left", "right"):
        K, D = sol.side(side).K, sol.side(side).D
        click.echo(f"{side:5s}  fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} px  "
                   f"k1 {D[0]:+.4f} k2 {D[1]:+.4f}  RMS {sol.side(side).rms_px:.3f} px over "
                   f"{len(sol.side(side).used)} views")
    click.echo(f"stereo baseline {sol.baseline_m * 1000:.2f} mm, rectified fx' {rect['fx_px']:.2f} px, RMS "
               f"{sol.stereo_rms_px:.3f} px over {len(sol.used)} views; {len(sol.dropped)} view(s) dropped "
               f"(report.json); {solve_s:.1f} s")
    click.echo(f"wrote {', '.join(files)} to {out}")
    return EXIT_OK


def _orbslam3_settings(sol: Any, fps: float) -> str:
    """ORB-SLAM3 stereo settings of the rectified pair, as the benchmark writes them (needs the emulator)."""
    from bracketry_base.calibration.camera_info import rectified_camera

    try:
        from bracketry_emulator.slam.settings import OrbSlamCamera, settings_yaml
    except ImportError as exc:
        raise BracketryError(f"the ORB-SLAM3 settings need the emulator extra (pip install -e '.[emulator]'): "
                             f"{exc}") from None
    r = rectified_camera(sol)
    cam = OrbSlamCamera(r["fx_px"], r["fy_px"], r["cx_px"], r["cy_px"], r["baseline_m"], *sol.size)
    return settings_yaml(cam, fps)


@command.command("capture")
@click.option("--from", "source", type=input_dir(), default=None,
              help="Session folder to read the stereo pairs from in order, as a live stream (left/, right/).")
@click.option("--config", "config_path", type=input_file(), default=None,
              help="Drive the rig of this config (the daemon's TOML, the daemon stopped) in calibration mode: the "
                   "trigger board pulses both cameras with one exposure (--exposure-us) at --rate-hz.")
@click.option("--rig", "rig", type=click.Choice(["sim"]), default=None,
              help="Drive the simulated rig in calibration mode instead: its two fake GigE cameras looking at a "
                   "board moved by hand (one fixed exposure, zero gain, software-triggered together).")
@click.option("--out", "out", type=output_dir(), required=True,
              help="Folder for the kept views (new or empty): left/, right/, board.yaml, capture.json.")
@overwrite_option()
@click.option("--board", "board_file", type=input_file(), default=None,
              help="board.yaml of the board (default: the --from folder's board.yaml; with --config or --rig sim "
                   "the default ChArUco board).")
@click.option("--max-blur-px", type=Number(0.5, 100.0), default=2.5, show_default=True,
              help="Pairs whose board edges are blurred more than this (equivalent Gaussian sigma, px) are skipped.")
@click.option("--no-bayer", is_flag=True, help="--from: the images are grey, not raw RGGB mosaics.")
@click.option("--monitor", "monitor_port", type=Integer(0, 65535), default=None,
              help="Serve the monitor page with the live corners and coverage on 127.0.0.1:PORT (0: any port; "
                   "with --rig sim a fixed port).")
@click.option("--rate-hz", type=Number(0.0, 1000.0), default=None,
              help="Pairs per second to replay or trigger at, 0..1000 (0: as fast as they come; default: 0, with "
                   "--config 2).")
@click.option("--hold-s", type=Number(0.0, 3600.0), default=0.0, show_default=True,
              help="Keep the monitor page up this long after the last pair, 0..3600 s.")
@click.option("--exposure-us", type=Integer(20, 100000), default=1000, show_default=True,
              help="--config, --rig: the one fixed exposure of both cameras, us (short: a board moved by hand stays "
                   "sharp).")
@click.option("--max-pairs", type=count(1, 100000), default=120, show_default=True,
              help="--config, --rig: stop after this many pairs when the set is not enough before.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="--rig sim: seed of the hand-held views.")
@click.option("--resolution", default="640x400", show_default=True,
              help="--rig sim: the cameras' resolution WIDTHxHEIGHT.")
@quiet_option()
def capture_cmd(source: Path | None, config_path: Path | None, rig: str | None, out: Path, overwrite: bool,
                board_file: Path | None, max_blur_px: float, no_bayer: bool, monitor_port: int | None,
                rate_hz: float | None, hold_s: float, exposure_us: int, max_pairs: int, seed: int, resolution: str,
                quiet: bool) -> int:
    """Select calibration views from a stream of stereo pairs: a pair is kept when the board is found in both
    images, sharp enough and not a near-duplicate of a kept view; the monitor page (--monitor) shows the corners,
    the coverage bars (x, y, size, skew) and when the set is enough. Exit 1 when the kept set is not enough.

    The stream is an image folder (--from, a recorded session), the rig of a config driven in calibration mode
    (--config rig.toml: the trigger board runs a one-entry bracket table, one exposure, at --rate-hz; each pulse's
    left and right frames, paired as the daemon pairs them, are one stereo pair), or the simulated rig (--rig sim).
    Both rigs stop when the set is enough or after --max-pairs."""
    if sum(x is not None for x in (source, config_path, rig)) != 1:
        raise BracketryError("give one stream: --from SESSION (a recorded board session), --config rig.toml (the "
                             "rig) or --rig sim")
    echo = None if quiet else (lambda line: click.echo(line, err=True))
    if rig is not None:
        return _capture_sim(out, board_file, max_blur_px, monitor_port, rate_hz or 0.0, hold_s, exposure_us,
                            max_pairs, seed, resolution, quiet)
    if config_path is not None:
        from bracketry_rig.boardcapture.trigger_board import (
            TriggerCaptureOptions,
            capture_through_trigger,
            check_options,
        )
        from bracketry_rig.daemon.config import load_config

        config = load_config(config_path)
        opts = TriggerCaptureOptions(exposure_us=exposure_us, rate_hz=2.0 if rate_hz is None else rate_hz,
                                     max_pairs=max_pairs, max_blur_px=max_blur_px)
        if opts.rate_hz <= 0:
            raise BracketryError("--rate-hz must be above 0 with --config (the trigger's pulse rate)")
        check_options(opts)
        board, board_yaml = _board(board_file, None)
        status, pairs = capture_through_trigger(config, out, board, board_yaml, opts, monitor_port=monitor_port,
                                                echo=echo)
    else:
        from bracketry_rig.boardcapture.folder import capture_folder

        assert source is not None
        board, board_yaml = _board(board_file, source)
        status, pairs = capture_folder(source, out, board, board_yaml, max_blur_px=max_blur_px, bayer=not no_bayer,
                                       monitor_port=monitor_port, rate_hz=rate_hz or 0.0, hold_s=hold_s, echo=echo)
    click.echo(f"kept {status['kept']} of {pairs} pairs in {out}; {status['advice']}")
    return EXIT_OK if status["enough"] else EXIT_PROBLEMS


def _board(board_file: Path | None, source: Path | None) -> tuple[Any, str]:
    """The board and its board.yaml text: --board, else the session's board.yaml, else (no session) the default
    ChArUco board."""
    import yaml

    from bracketry_base.calibration.board import BoardSpec

    if board_file is None and source is not None:
        board_file = source / "board.yaml"
        if not board_file.is_file():
            raise BracketryError(f"no board.yaml in {source}: give the board with --board board.yaml")
    if board_file is None:
        board = BoardSpec()
        return board, yaml.safe_dump(board.to_dict(), sort_keys=False)
    return load_board(board_file), board_file.read_text()


def _capture_sim(out: Path, board_file: Path | None, max_blur_px: float, monitor_port: int | None, rate_hz: float,
                 hold_s: float, exposure_us: int, max_pairs: int, seed: int, resolution: str, quiet: bool) -> int:
    """``--rig sim``: the simulated rig's fake cameras (in a private network namespace: this command re-runs
    itself there) serving a board moved by hand, driven in calibration mode."""
    import sys

    from bracketry.sim.rig import in_private_netns, monitor_bridge_outside, reexec_in_netns
    from bracketry_base.options import parse_resolution

    size = parse_resolution(resolution)
    board, board_yaml = _board(board_file, None)  # a bad board: one line before anything starts
    if monitor_port == 0:
        raise BracketryError("--monitor 0 with --rig sim: give a fixed port (the page is served from the rig's "
                             "network namespace)")
    if not in_private_netns():
        out.mkdir(exist_ok=True)
        bridge = monitor_bridge_outside(out, monitor_port) if monitor_port is not None else None
        try:
            # --out was checked here (before the bridge wrote into it): the re-run does not refuse it
            argv = sys.argv[1:]
            return reexec_in_netns([*argv, "--overwrite"] if argv[:2] == ["calibrate", "capture"] else
                                   ["calibrate", "capture", "--rig", "sim", "--out", str(out), "--overwrite",
                                    "--max-blur-px", str(max_blur_px), "--rate-hz", str(rate_hz),
                                    "--hold-s", str(hold_s), "--exposure-us", str(exposure_us),
                                    "--max-pairs", str(max_pairs), "--seed", str(seed), "--resolution", resolution,
                                    *(["--board", str(board_file)] if board_file is not None else []),
                                    *(["--monitor", str(monitor_port)] if monitor_port is not None else []),
                                    *(["--quiet"] if quiet else [])])
        finally:
            if bridge is not None:
                bridge.terminate()
                bridge.wait(timeout=10)
    from bracketry.sim.board_capture import capture_sim

    status, pairs = capture_sim(out, board, board_yaml, size, seed=seed, exposure_us=exposure_us,
                                max_pairs=max_pairs, max_blur_px=max_blur_px, rate_hz=rate_hz, hold_s=hold_s,
                                monitor_port=monitor_port, echo=None if quiet else (lambda x: click.echo(x, err=True)))
    click.echo(f"kept {status['kept']} of {pairs} pairs in {out}; {status['advice']}")
    return EXIT_OK if status["enough"] else EXIT_PROBLEMS
