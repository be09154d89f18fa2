"""``bracketry calibrate``: geometric stereo calibration (``solve``, ``capture``) and the camera response (``crf``,
also reachable under its old name ``calibrate-crf``).

The commands load, call :mod:`bracketry.calibration` (pure: arrays in, calibration out) and save.
"""

from __future__ import annotations

import importlib
import json
import time
from pathlib import Path
from typing import Any

import click

from bracketry.cli.options import (
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
from bracketry.errors import BracketryError

#: the ORB-SLAM3 settings file written beside the camera_info YAMLs
ORBSLAM3_SETTINGS = "orbslam3_stereo.yaml"
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".jpg")

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


def load_board(path: Path) -> Any:
    """The board of a ``board.yaml`` (one-line error when it is not one)."""
    import yaml

    from bracketry.calibration.board import BoardSpec

    try:
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise BracketryError(f"cannot read the board definition {path}: {' '.join(str(exc).split())}") from None
    return BoardSpec.from_dict(doc)


def image_pairs(folder: Path) -> list[tuple[Path, Path]]:
    """(left, right) image files of a session: ``left/`` and ``right/`` holding images of the same names (a board
    session), or a BorealHDR tree (``bracketry export --format borealhdr`` of a recording):
    ``camera_left/<exposure>/`` and ``camera_right/<exposure>/``, the k-th image of a side with the k-th of the
    other (the pairing's order) in each exposure folder."""
    if (folder / "camera_left").is_dir() and (folder / "camera_right").is_dir():
        return _borealhdr_pairs(folder)
    sides = [folder / "left", folder / "right"]
    if not all(d.is_dir() for d in sides):
        raise BracketryError(f"{folder} has no left/ and right/ image folders (a board session: left/NNNNNN.png, "
                             "right/NNNNNN.png) nor camera_left/ and camera_right/ (a BorealHDR tree)")
    names = [{p.name for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES} for d in sides]
    if names[0] != names[1]:
        odd = sorted(names[0] ^ names[1])
        raise BracketryError(f"left/ and right/ of {folder} do not hold the same image names ({len(odd)} unpaired, "
                             f"e.g. {odd[0]}): give image pairs")
    if not names[0]:
        raise BracketryError(f"no images in {folder}/left (png, tif, pgm, jpg)")
    return [(sides[0] / n, sides[1] / n) for n in sorted(names[0])]


def _borealhdr_pairs(folder: Path) -> list[tuple[Path, Path]]:
    pairs = []
    lefts = sorted(d for d in (folder / "camera_left").iterdir() if d.is_dir())
    for d in lefts:
        r = folder / "camera_right" / d.name
        files = [sorted(p for p in x.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES) if x.is_dir() else []
                 for x in (d, r)]
        if len(files[0]) != len(files[1]):
            raise BracketryError(f"{d} holds {len(files[0])} images but {r} {len(files[1])}: give image pairs "
                                 "(bracketry verify the recording)")
        pairs += list(zip(files[0], files[1], strict=True))
    if not pairs:
        raise BracketryError(f"no images in {folder}/camera_left/*/ (png, tif, pgm, jpg)")
    return pairs


def _read(path: Path) -> Any:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise BracketryError(f"cannot read image {path}")
    return img


def _check_png_sizes(pairs: list[tuple[Path, Path]], size: tuple[int, int]) -> None:
    """Every PNG of the pairs is ``size`` (width, height), read from its header (other formats are checked when
    read)."""
    import struct

    for pair in pairs:
        for p in pair:
            if p.suffix.lower() != ".png":
                continue
            with open(p, "rb") as f:
                head = f.read(24)
            if len(head) < 24 or head[12:16] != b"IHDR":
                raise BracketryError(f"{p} is not a PNG image")
            wh = struct.unpack(">II", head[16:24])
            if wh != size:
                raise BracketryError(f"{p} is {wh[0]}x{wh[1]} but {pairs[0][0]} is {size[0]}x{size[1]}: a "
                                     "session's images must all have one size")


def detect_session(pairs: list[tuple[Path, Path]], board: Any, bayer: bool, quiet: bool
                   ) -> tuple[list[Any], list[Any], tuple[int, int]]:
    """Detect the board in every pair; the images must all have one size. Returns the left and right detections
    (None where not found) and the size (width, height)."""
    from bracketry.calibration.detect import detect, to_gray8
    from bracketry.progress import Progress

    left: list[Any] = []
    right: list[Any] = []
    first = _read(pairs[0][0])
    _check_png_sizes(pairs, (int(first.shape[1]), int(first.shape[0])))
    size: tuple[int, int] | None = None
    bar = Progress("detect", unit="pair", enabled=not quiet)
    try:
        for k, pair in enumerate(pairs):
            for path, dets in zip(pair, (left, right), strict=True):
                img = _read(path)
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
    from bracketry.calibration.camera_info import camera_info_yaml, kitti_text, rectified_camera, report
    from bracketry.calibration.solve import solve_stereo

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
    from bracketry.calibration.camera_info import rectified_camera

    try:
        from bracketry_emulator.slam.settings import OrbSlamCamera, settings_yaml
    except ImportError as exc:
        raise BracketryError(f"the ORB-SLAM3 settings need the emulator extra (pip install -e '.[emulator]'): "
                             f"{exc}") from None
    r = rectified_camera(sol)
    cam = OrbSlamCamera(r["fx_px"], r["fy_px"], r["cx_px"], r["cy_px"], r["baseline_m"], *sol.size)
    return settings_yaml(cam, fps)


class _FolderBackend:
    """The monitor's backend while a capture reads an image folder: no sensors to show or switch."""

    def __init__(self, source: Path) -> None:
        self.source = source

    def monitor_status(self) -> dict[str, Any]:
        import shutil as _shutil

        free_mb = _shutil.disk_usage(self.source).free // (1024 * 1024)
        return {"time_ns": time.time_ns(), "sensors": {}, "errors": {}, "cameras": {},
                "disk": {"free_mb": free_mb, "time_left_s": None},
                "recording": {"active": False, "name": None, "segment": 0, "seconds": 0},
                "message": f"board capture from {self.source.name}", "brackets_us": [], "fps_target": 0,
                "sensors_on": False}

    def monitor_action(self, action: str, body: dict[str, Any]) -> dict[str, Any]:
        from bracketry.monitor.server import ActionError

        raise ActionError("no rig here: this capture reads an image folder")

    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        return (), 1, 1


class _Selection:
    """The capture's bookkeeping shared by both streams: judge a pair, save it when kept, log it, print a line."""

    def __init__(self, feed: Any, board: Any, out: Path, bayer: bool, quiet: bool) -> None:
        self.feed, self.board, self.out, self.bayer, self.quiet = feed, board, out, bayer, quiet
        self.log: list[dict[str, Any]] = []
        for side in ("left", "right"):
            (out / side).mkdir(exist_ok=True)

    def offer(self, name: str, imgs: tuple[Any, Any], save: Any) -> bool:
        """Judge the pair ``imgs`` (raw images); ``save(out, name)`` writes it when kept. Returns the set is
        enough."""
        from bracketry.calibration.detect import detect, to_gray8

        grays = (to_gray8(imgs[0], bayer=self.bayer), to_gray8(imgs[1], bayer=self.bayer))
        kept, why = self.feed.offer(grays, (detect(grays[0], self.board), detect(grays[1], self.board)))
        self.log.append({"pair": name, "kept": kept, "why": why})
        if kept:
            save(self.out, name)  # one name for both: solve pairs by name
        st = self.feed.coverage.status()
        if not self.quiet:
            bars = " ".join(f"{k} {v:.0%}" for k, v in st["bars"].items())
            click.echo(f"{name}: {'kept' if kept else why}; {st['kept']} kept; {bars}", err=True)
        return bool(st["enough"])

    def finish(self, board_yaml: str, extra: dict[str, Any]) -> dict[str, Any]:
        self.feed.finish()
        (self.out / "board.yaml").write_text(board_yaml)
        status: dict[str, Any] = self.feed.coverage.status()
        (self.out / "capture.json").write_text(json.dumps({**extra, **status, "pairs": self.log}, indent=1) + "\n")
        return status


@command.command("capture")
@click.option("--from", "source", type=input_dir(), default=None,
              help="Session folder to read the stereo pairs from in order, as a live stream (left/, right/).")
@click.option("--rig", "rig", type=click.Choice(["sim"]), default=None,
              help="Drive a rig in calibration mode instead: 'sim' is the simulated rig's two fake GigE cameras "
                   "looking at a board moved by hand (one fixed exposure, zero gain, software-triggered together).")
@click.option("--out", "out", type=output_dir(), required=True,
              help="Folder for the kept views (new or empty): left/, right/, board.yaml, capture.json.")
@overwrite_option()
@click.option("--board", "board_file", type=input_file(), default=None,
              help="board.yaml of the board (default: the --from folder's board.yaml; with --rig sim the default "
                   "ChArUco board).")
@click.option("--max-blur-px", type=Number(0.5, 100.0), default=2.5, show_default=True,
              help="Pairs whose board edges are blurred more than this (equivalent Gaussian sigma, px) are skipped.")
@click.option("--no-bayer", is_flag=True, help="The images are grey, not raw RGGB mosaics.")
@click.option("--monitor", "monitor_port", type=Integer(0, 65535), default=None,
              help="Serve the monitor page with the live corners and coverage on 127.0.0.1:PORT (0: any port; "
                   "with --rig sim a fixed port).")
@click.option("--rate-hz", type=Number(0.0, 1000.0), default=0.0, show_default=True,
              help="Pairs per second to replay or trigger at (0: as fast as they come), 0..1000.")
@click.option("--hold-s", type=Number(0.0, 3600.0), default=0.0, show_default=True,
              help="Keep the monitor page up this long after the last pair, 0..3600 s.")
@click.option("--exposure-us", type=Integer(20, 100000), default=1000, show_default=True,
              help="--rig: the one fixed exposure of both cameras, us (short: a board moved by hand stays sharp).")
@click.option("--max-pairs", type=count(1, 100000), default=120, show_default=True,
              help="--rig: stop after this many pairs when the set is not enough before.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="--rig sim: seed of the hand-held views.")
@click.option("--resolution", default="640x400", show_default=True,
              help="--rig sim: the cameras' resolution WIDTHxHEIGHT.")
@quiet_option()
def capture_cmd(source: Path | None, rig: str | None, out: Path, overwrite: bool, board_file: Path | None,
                max_blur_px: float, no_bayer: bool, monitor_port: int | None, rate_hz: float, hold_s: float,
                exposure_us: int, max_pairs: int, seed: int, resolution: str, quiet: bool) -> int:
    """Select calibration views from a stream of stereo pairs: a pair is kept when the board is found in both
    images, sharp enough and not a near-duplicate of a kept view; the monitor page (--monitor) shows the corners,
    the coverage bars (x, y, size, skew) and when the set is enough. Exit 1 when the kept set is not enough.

    The stream is an image folder (--from, a recorded session) or a rig driven in calibration mode (--rig sim:
    both cameras at one fixed exposure and zero gain, triggered together, until the set is enough or --max-pairs);
    the real rig's line-triggered cameras are not driven yet."""
    if (source is None) == (rig is None):
        raise BracketryError("give the stream: --from SESSION (a recorded board session) or --rig sim")
    if rig is not None:
        return _capture_sim(out, board_file, max_blur_px, monitor_port, rate_hz, hold_s, exposure_us, max_pairs,
                            seed, resolution, quiet)
    assert source is not None
    return _capture_folder(source, out, board_file, max_blur_px, no_bayer, monitor_port, rate_hz, hold_s, quiet)


def _capture_folder(source: Path, out: Path, board_file: Path | None, max_blur_px: float, no_bayer: bool,
                    monitor_port: int | None, rate_hz: float, hold_s: float, quiet: bool) -> int:
    import shutil as _shutil

    from bracketry.monitor.calibration_feed import CaptureFeed

    if board_file is None:
        board_file = source / "board.yaml"
        if not board_file.is_file():
            raise BracketryError(f"no board.yaml in {source}: give the board with --board board.yaml")
    board = load_board(board_file)
    pairs = image_pairs(source)
    first = _read(pairs[0][0])
    size = (int(first.shape[1]), int(first.shape[0]))
    _check_png_sizes(pairs, size)  # before anything is written
    feed = CaptureFeed(board, size, max_blur_px)
    server = None
    if monitor_port is not None:
        from bracketry.monitor.hub import PreviewHub
        from bracketry.monitor.server import MonitorServer

        server = MonitorServer(_FolderBackend(source), PreviewHub(), "127.0.0.1", monitor_port,
                               calibration=feed).start()
        click.echo(f"monitor: {server.url}", err=True)
    out.mkdir(exist_ok=True)
    sel = _Selection(feed, board, out, not no_bayer, quiet)
    try:
        t_next = time.monotonic()
        for pair in pairs:
            imgs = (_read(pair[0]), _read(pair[1]))
            for p, img in zip(pair, imgs, strict=True):
                if (int(img.shape[1]), int(img.shape[0])) != size:
                    raise BracketryError(f"{p} is {img.shape[1]}x{img.shape[0]} but the stream is "
                                         f"{size[0]}x{size[1]}: a session's images must all have one size")

            def save(dest: Path, name: str, pair: tuple[Path, Path] = pair) -> None:
                for side, p in zip(("left", "right"), pair, strict=True):
                    _shutil.copyfile(p, dest / side / name)

            sel.offer(pair[0].name, imgs, save)
            if rate_hz > 0:
                t_next += 1.0 / rate_hz
                time.sleep(max(0.0, t_next - time.monotonic()))
        status = sel.finish(board_file.read_text(), {"source": str(source)})
        if server is not None and hold_s > 0:
            time.sleep(hold_s)
    finally:
        if server is not None:
            server.close()
    click.echo(f"kept {status['kept']} of {len(pairs)} pairs in {out}; {status['advice']}")
    return EXIT_OK if status["enough"] else EXIT_PROBLEMS


def _capture_sim(out: Path, board_file: Path | None, max_blur_px: float, monitor_port: int | None, rate_hz: float,
                 hold_s: float, exposure_us: int, max_pairs: int, seed: int, resolution: str, quiet: bool) -> int:
    """``--rig sim``: the simulated rig's fake cameras (in a private network namespace: this command re-runs
    itself there) serving a board moved by hand, driven in calibration mode."""
    import subprocess
    import sys

    from bracketry.cli.simulate import parse_resolution
    from bracketry.sim.rig import in_private_netns, monitor_bridge_outside, monitor_socket, reexec_in_netns

    size = parse_resolution(resolution)
    if board_file is not None:
        load_board(board_file)  # a bad board: one line before anything starts
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
    from bracketry.calibration.board import BoardSpec
    from bracketry.cameras.lockstep import LockstepPair
    from bracketry.cameras.profiles import CameraSettings
    from bracketry.monitor.calibration_feed import CaptureFeed
    from bracketry.png import write_png
    from bracketry.sim.board_rig import BoardSource, start_board_cameras
    from bracketry.sim.frames import read_frame_id
    from bracketry.sim.rig import CAMERA_ADDRESSES

    board = load_board(board_file) if board_file is not None else BoardSpec()
    import yaml

    board_yaml = board_file.read_text() if board_file is not None else yaml.safe_dump(board.to_dict(),
                                                                                     sort_keys=False)
    out.mkdir(exist_ok=True)
    feed = CaptureFeed(board, size, max_blur_px)
    source = BoardSource(board, size, seed)
    servers = start_board_cameras(source)
    server = bridge_in = None
    pairs = mismatched = 0
    try:
        if monitor_port is not None:
            from bracketry.monitor.hub import PreviewHub
            from bracketry.monitor.server import MonitorServer

            server = MonitorServer(_FolderBackend(out), PreviewHub(), "127.0.0.1", monitor_port,
                                   calibration=feed).start()
            sock = monitor_socket(out)
            bridge_in = subprocess.Popen(["socat", f"UNIX-LISTEN:{sock},fork,mode=600",
                                          f"TCP:127.0.0.1:{monitor_port}"], stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            click.echo(f"monitor: http://127.0.0.1:{monitor_port}/", err=True)
        sel = _Selection(feed, board, out, True, quiet)
        settings = CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=size[0], height=size[1],
                                  trigger_source="Software", exposure_us=float(exposure_us))
        with LockstepPair(CAMERA_ADDRESSES, settings) as cams:
            t_next = time.monotonic()
            while pairs < max_pairs:
                left, right = cams.grab()
                pairs += 1
                name = f"{pairs - 1:06d}.png"
                if left.image is None or right.image is None:
                    sel.log.append({"pair": name, "kept": False, "why": "incomplete frame"})
                    continue
                ids = (read_frame_id(left.image), read_frame_id(right.image))
                if ids[0] is None or ids[0] != ids[1]:  # the two images are not one instant's
                    mismatched += 1
                    sel.log.append({"pair": name, "kept": False, "why": f"not a pair (views {ids[0]}, {ids[1]})"})
                    continue
                imgs = (left.image, right.image)

                def save(dest: Path, name: str, imgs: tuple[Any, Any] = imgs) -> None:
                    for side, img in zip(("left", "right"), imgs, strict=True):
                        write_png(dest / side / name, img)

                if sel.offer(name, imgs, save):
                    break
                if rate_hz > 0:
                    t_next += 1.0 / rate_hz
                    time.sleep(max(0.0, t_next - time.monotonic()))
        source.write_truth(out / "truth")
        status = sel.finish(board_yaml, {"source": "rig sim", "seed": seed, "exposure_us": exposure_us,
                                         "gain": 0, "served_exposures_us": source.exposures_us,
                                         "pairs_not_matched": mismatched})
        if server is not None and hold_s > 0:
            time.sleep(hold_s)
    finally:
        if bridge_in is not None:
            bridge_in.terminate()
            bridge_in.wait(timeout=10)
        if server is not None:
            server.close()
        for cam in servers.values():
            cam.stop()
    click.echo(f"kept {status['kept']} of {pairs} pairs in {out}; {status['advice']}")
    return EXIT_OK if status["enough"] else EXIT_PROBLEMS
