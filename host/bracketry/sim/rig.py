"""The whole rig on one machine: two fake GigE cameras, the trigger, the panel and the daemon, each a real process
or server speaking the real protocols.

- Cameras: two in-process Aravis ``GvFakeCamera`` servers on 127.0.0.2 and 127.0.0.3 (GVCP/GVSP over loopback),
  serving the synthetic world at the exposure of each trigger (ctypes fill-pattern route). Two addresses need a
  private network namespace: ``bracketry simulate`` re-runs itself under ``unshare -n`` (see
  :mod:`bracketry_rig.cameras.netns`), which also keeps Aravis traffic off every real interface.
- Trigger: ``bracketry trigger simulate`` on a pty (or the real firmware in QEMU with ``trigger="qemu"``).
- Panel: ``bracketry panel simulate`` running the actual MicroPython firmware files, on one end of a socat pty
  pair; buttons are pressed through its standard input and its screen is read from its screen file.
- Daemon: ``bracketry daemon --config sim.toml``; the cameras' ``aravis_fake`` profile has no trigger line, so the
  daemon's camera trigger is the software one (``bracketry_rig.cameras.triggering.SoftwareTrigger``: TriggerSoftware at
  each TRIGGER event), chosen by the profile layer, never by a "simulated" switch.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_rig.daemon.status import query

CAMERA_ADDRESSES = {"left": "127.0.0.2", "right": "127.0.0.3"}
NETNS_ENV = "BRACKETRY_IN_NETNS"


@dataclass
class SimOptions:
    """What to simulate. ``resolution`` (width, height) of the cameras; ``fps`` and ``brackets_ms`` of the trigger;
    ``world_seconds`` of pre-rendered frames (frames beyond repeat); ``trigger`` "simulator" or "qemu";
    ``preset``/``seed`` of the synthetic world (``world=False``: a test pattern, no emulator extra needed)."""

    out_dir: Path
    resolution: tuple[int, int] = (640, 400)
    fps: float = 22.0
    brackets_ms: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
    world_seconds: float = 30.0
    trigger: str = "simulator"
    preset: str = "forest-winter"
    seed: int = 0
    world: bool = True
    min_free_mb: int = 64
    stop_free_mb: int = 16
    output_dir: Path | None = None
    echo: Callable[[str], None] = print
    monitor_port: int | None = None
    #: keep the rendered frames in ``out_dir/dev/frames`` after the run (default: a temporary folder in memory,
    #: /dev/shm when there is one, removed at the end)
    keep_frames: bool = False
    #: the stereo calibration folder the rig config names (``rig.calibration``; None: recordings carry none)
    calibration: Path | None = None


def _bracketry_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "bracketry", *args]


class SimulatedRig:
    """Starts and stops the simulated devices and the daemon; exposes fault injection for tests."""

    def __init__(self, options: SimOptions) -> None:
        self.o = options
        self.out = Path(options.out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.dev_dir = self.out / "dev"
        self.dev_dir.mkdir(exist_ok=True)
        self.rec_dir = options.output_dir or (self.out / "recordings")
        #: recordings already in rec_dir before this rig ran (an --out reused): never reported as this run's
        self._earlier = set(self.rec_dir.glob("*/seg*")) if self.rec_dir.is_dir() else set()
        self.screen_file = self.out / "panel_screen.txt"
        self.socket_path = self.out / "status.sock"
        self.config_path = self.out / "sim_rig.toml"
        self.trigger_link = self.dev_dir / "trigger"
        self.panel_dev = self.dev_dir / "panel-board"
        self.panel_host = self.dev_dir / "panel"
        self.cameras: dict[str, Any] = {}
        self.schedule: Any = None
        self.world: Any = None
        self.procs: dict[str, subprocess.Popen] = {}
        self.qemu: Any = None
        self._last_screen: list[str] | None = None
        #: (the recording files' identity, {side: frame ids}) of the last read (:meth:`recorded_frame_ids`)
        self._frame_ids: tuple[Any, dict[str, list[tuple[int, int | None]]]] | None = None
        self._world_thread: threading.Thread | None = None
        self._world_error: BaseException | None = None

    # ------------------------------------------------------------------------------------------------ set-up
    def prepare_frames(self, progress: Callable[[int, int], None] | None = None, wait: bool = False) -> None:
        """Start rendering the frames the cameras will serve (the synthetic world, or a test pattern) in a separate
        process; the rig can start at once (the cameras wait for frames not yet rendered). ``wait``: block until
        every frame is rendered (``progress(done, total)`` on the way)."""
        from bracketry.sim.frames import FrameSchedule, WorldSpec

        spec = None
        if self.o.world:
            if importlib.util.find_spec("bracketry_emulator") is None:
                raise BracketryError("the synthetic world needs the emulator extra: pip install -e '.[emulator]' "
                                     "(or run with --no-world for a test pattern)")
            spec = WorldSpec(self.o.preset, self.o.seed)  # built by the renderer; ours waits (write_world_files)
        n = len(self.o.brackets_ms)
        n_frames = max(n, round(self.o.world_seconds * self.o.fps / n) * n)
        brackets_us = [round(b * 1000) for b in self.o.brackets_ms]
        if self.o.keep_frames:
            folder = self.dev_dir / "frames"
        else:
            shm = Path("/dev/shm")
            folder = Path(tempfile.mkdtemp(prefix="bracketry-frames-",
                                           dir=shm if shm.is_dir() and os.access(shm, os.W_OK) else None))
        self.schedule = FrameSchedule(folder, spec, brackets_us, self.o.fps, n_frames,
                                      resolution=self.o.resolution).start()
        if wait:
            self.schedule.wait(progress)

    def start_cameras(self) -> None:
        from bracketry_rig.cameras.fake import FakeCameraServer

        for side, addr in CAMERA_ADDRESSES.items():
            self.start_camera(side, FakeCameraServer)
            self.o.echo(f"camera {side}: fake GigE camera on {addr}")

    def start_camera(self, side: str, cls: Any = None) -> None:
        """(Re)start the fake camera of ``side``."""
        if cls is None:
            from bracketry_rig.cameras.fake import FakeCameraServer as cls
        cam = cls(CAMERA_ADDRESSES[side], serial=f"SIM{side.upper()}", image_source=self.schedule.source(side))
        self.cameras[side] = cam.start()

    def stop_camera(self, side: str) -> None:
        """Take the fake camera of ``side`` off the network (fault injection)."""
        cam = self.cameras.pop(side, None)
        if cam is not None:
            cam.stop()

    def start_trigger(self) -> None:
        """Start the trigger simulator (or QEMU) and make ``self.trigger_url`` point at it."""
        if self.o.trigger == "qemu":
            from bracketry_rig.trigger.qemu import QemuTrigger

            self.qemu = QemuTrigger(serial="tcp", log_path=self.out / "qemu.log").start()
            self.trigger_url = self.qemu.url
            self.o.echo(f"trigger: real firmware in QEMU at {self.trigger_url}")
            return
        if self.trigger_link.is_symlink():
            self.trigger_link.unlink()
        log = open(self.out / "trigger_sim.log", "ab")  # noqa: SIM115 (lives as long as the process)
        cmd = _bracketry_cmd("trigger", "simulate", "--link", str(self.trigger_link))
        self.procs["trigger"] = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        _wait_for(lambda: self.trigger_link.exists(), 15.0, "the trigger simulator's port")
        self.trigger_url = str(self.trigger_link)
        self.o.echo(f"trigger: simulator on {self.trigger_url}")

    def stop_trigger(self, sig: int = signal.SIGKILL) -> None:
        """Kill the trigger simulator (fault injection) or QEMU."""
        if self.qemu is not None:
            self.qemu.stop()
            self.qemu = None
        proc = self.procs.pop("trigger", None)
        if proc is not None:
            _end(proc, sig)

    def start_panel(self) -> None:
        """Start socat (pty pair) once, then the panel simulator on the board end."""
        if "socat" not in self.procs:
            if shutil.which("socat") is None:
                raise BracketryError("socat not found: apt-get install socat (or run ./setup.sh)")
            for p in (self.panel_dev, self.panel_host):
                if p.is_symlink():
                    p.unlink()
            self.procs["socat"] = subprocess.Popen(
                ["socat", f"pty,raw,echo=0,link={self.panel_dev}", f"pty,raw,echo=0,link={self.panel_host}"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            _wait_for(lambda: self.panel_dev.exists() and self.panel_host.exists(), 10.0, "socat's pty pair")
        log = open(self.out / "panel_sim.log", "ab")  # noqa: SIM115
        self.procs["panel"] = subprocess.Popen(
            _bracketry_cmd("panel", "simulate", "--link", str(self.panel_dev), "--screen-file", str(self.screen_file),
                           "--quiet"), stdin=subprocess.PIPE, stdout=log, stderr=log, text=True)
        self.o.echo(f"panel: firmware simulator on {self.panel_dev} (host side {self.panel_host})")

    def stop_panel(self, sig: int = signal.SIGKILL) -> None:
        """Kill the panel simulator (a panel reboot when started again)."""
        proc = self.procs.pop("panel", None)
        if proc is not None:
            _end(proc, sig)

    def write_config(self) -> Path:
        """The daemon's rig config for the simulated devices."""
        brackets = ", ".join(f"{b:g}" for b in self.o.brackets_ms)
        cams = "".join(f'\n[[cameras]]\nside = "{side}"\nprofile = "aravis_fake"\naddress = "{addr}"\n'
                       f'pixel_format = "Mono16"\n' for side, addr in CAMERA_ADDRESSES.items())
        monitor = (f'[monitor]\nlisten = "127.0.0.1:{self.o.monitor_port}"\nbayer = true\n\n'
                   if self.o.monitor_port is not None else "")
        calibration = f'calibration = "{Path(self.o.calibration).resolve()}"\n' if self.o.calibration else ""
        self.config_path.write_text(
            f'{monitor}[rig]\noutput_dir = "{self.rec_dir}"\nbrackets_ms = [{brackets}]\nfps = {self.o.fps:g}\n'
            f'min_free_mb = {self.o.min_free_mb}\nstop_free_mb = {self.o.stop_free_mb}\n'
            f'status_socket = "{self.socket_path}"\n{calibration}\n'
            f'[trigger]\nkind = "{self.o.trigger}"\nport = "{self.trigger_url}"\nbaudrate = 921600\n\n'
            f'[panel]\nenabled = true\nport = "{self.panel_host}"\nbaudrate = 115200\nrefresh_hz = 4\n{cams}')
        return self.config_path

    def start_daemon(self) -> None:
        w, h = self.o.resolution
        log = open(self.out / "daemon.log", "ab")  # noqa: SIM115
        self.procs["daemon"] = subprocess.Popen(
            _bracketry_cmd("daemon", "--config", str(self.config_path), "--roi", f"{w}x{h}"),
            stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        _wait_for(lambda: self._status_or_none() is not None, 30.0, "the daemon's status socket",
                  alive=self.procs["daemon"])
        self.o.echo(f"daemon: running (pid {self.procs['daemon'].pid}), status socket {self.socket_path}")

    def start(self) -> SimulatedRig:
        """Start everything (frames must be prepared); the daemon comes last."""
        self.start_cameras()
        self.start_trigger()
        self.start_panel()
        self.write_config()
        self.start_daemon()
        if self.o.monitor_port is not None:
            self.start_monitor_bridge()
        return self

    def start_monitor_bridge(self) -> None:
        """Make the daemon's monitor (127.0.0.1:PORT in this namespace) reachable through ``monitor.sock`` in the
        output folder (a UNIX socket is a file: :func:`monitor_bridge_outside` serves the same port outside)."""
        sock = monitor_socket(self.out)
        with contextlib.suppress(FileNotFoundError):
            sock.unlink()
        self.procs["monitor-bridge"] = subprocess.Popen(
            ["socat", f"UNIX-LISTEN:{sock},fork,mode=600", f"TCP:127.0.0.1:{self.o.monitor_port}"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait_for(sock.exists, 10.0, "the monitor bridge's socket")
        url = (self.status().get("monitor") or {}).get("url")
        self.o.echo(f"monitor: {url}" if url else f"monitor: not running (see {self.out}/daemon.log)")

    # ------------------------------------------------------------------------------------------------ driving
    def press(self, button: str, long_press: bool = False) -> None:
        """Press a panel button (through the panel simulator's standard input)."""
        proc = self.procs.get("panel")
        if proc is None or proc.stdin is None or proc.poll() is not None:
            raise BracketryError("the panel simulator is not running")
        proc.stdin.write(f"{button}{' long' if long_press else ''}\n")
        proc.stdin.flush()
        self.o.echo(f"[press {button}{' long' if long_press else ''}]")

    def _status_or_none(self) -> dict[str, Any] | None:
        try:
            return query(self.socket_path, {"cmd": "status"}, timeout_s=2.0)
        except BracketryError:
            return None

    def status(self) -> dict[str, Any]:
        """The daemon's state (``bracketry status --json``)."""
        reply = self._status_or_none()
        if reply is None:
            raise BracketryError("the daemon does not answer on its status socket")
        return reply

    def screen(self) -> list[str]:
        """The panel's 4x20 screen as the firmware drew it (empty lines before the first draw)."""
        try:
            return self.screen_file.read_text().splitlines()[:4]
        except FileNotFoundError:
            return []

    def echo_screen_if_changed(self) -> None:
        lines = self.screen()
        if lines and lines != self._last_screen:
            self._last_screen = lines
            bar = "+" + "-" * 20 + "+"
            self.o.echo("\n".join([bar, *(f"|{line:<20.20}|" for line in lines), bar]))

    def wait_states(self, wanted: dict[str, str], timeout_s: float) -> dict[str, Any]:
        """Wait until the daemon reports ``wanted`` sensor states (e.g. {"cam_left": "IDLE"}); echo the screen."""
        deadline = time.monotonic() + timeout_s
        last: dict[str, Any] = {}
        while time.monotonic() < deadline:
            self.echo_screen_if_changed()
            reply = self._status_or_none()
            if reply is not None:
                last = reply["state"]
                if all(last["states"].get(k) == v for k, v in wanted.items()):
                    return last
            self.check_alive()
            time.sleep(0.25)
        raise BracketryError(f"timeout waiting for {wanted}: daemon reports {last.get('states')} "
                             f"errors {last.get('errors')} (see {self.out}/daemon.log)")

    def wait_screen(self, text: str, timeout_s: float) -> list[str]:
        """Wait until ``text`` appears on the panel screen."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.echo_screen_if_changed()
            lines = self.screen()
            if any(text in line for line in lines):
                return lines
            time.sleep(0.2)
        raise BracketryError(f"timeout waiting for {text!r} on the panel screen: {self.screen()}")

    def run_for(self, seconds: float) -> None:
        """Let the rig run, echoing screen changes."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.echo_screen_if_changed()
            self.check_alive()
            time.sleep(0.25)

    def check_alive(self) -> None:
        proc = self.procs.get("daemon")
        if proc is not None and proc.poll() is not None:
            raise BracketryError(f"the daemon exited with code {proc.returncode} (see {self.out}/daemon.log)")

    def stop_daemon(self, sig: int = signal.SIGTERM, timeout_s: float = 30.0) -> int:
        """Signal the daemon and wait for it; returns its exit code."""
        proc = self.procs.pop("daemon", None)
        if proc is None:
            return 0
        proc.send_signal(sig)
        try:
            return proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGUSR1)  # its threads' stacks into daemon.log: where it waits
            try:
                proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
            raise BracketryError(f"the daemon did not exit within {timeout_s:g} s of signal {sig} (its threads' "
                                 f"stacks: {self.out / 'daemon.log'})") from None

    def recordings(self) -> list[Path]:
        """Segment folders (``<rec>/segNN``) holding MCAP files recorded by this rig, oldest first."""
        return sorted({p.parent for p in self.rec_dir.glob("*/seg*/*.mcap")} - self._earlier)

    def recorded_frame_ids(self, side: str = "left") -> list[tuple[int, int | None]]:
        """Every recorded frame of ``side`` (this rig's recordings, in order): (stamp_ns of the image, the rendered
        frame index its pixels carry, or None when it carries none). One pass over the recordings gives both
        sides; it is kept until a recording file changes (each pass decompresses every chunk)."""
        from bracketry.sim.frames import read_frame_id
        from bracketry_base.recording import topics as T
        from bracketry_base.recording.decode import decode_image_msg
        from bracketry_base.recording.reader import RecordingReader

        files = [f for seg in self.recordings() for f in sorted(seg.glob("*.mcap"))]
        key = [(str(f), f.stat().st_size, f.stat().st_mtime_ns) for f in files]
        if self._frame_ids is None or self._frame_ids[0] != key:
            topics = {T.image_topic(s): s for s in T.SIDES}
            ids: dict[str, list[tuple[int, int | None]]] = {s: [] for s in T.SIDES}
            for f in files:
                for msg in RecordingReader(f).messages(set(topics)):
                    img = decode_image_msg(msg.data)
                    k = read_frame_id(img.image) if img.image.dtype == np.uint16 else None
                    ids[topics[msg.topic]].append((int(img.stamp_ns), k))
            for frames in ids.values():
                frames.sort(key=lambda t: t[0])
            self._frame_ids = (key, ids)
        return list(self._frame_ids[1].get(side, []))

    def start_world_files(self) -> None:
        """Start :meth:`write_world_files` on a thread (e.g. while the recording is verified); the next
        :meth:`write_world_files` waits for it (and raises what it raised)."""
        if self._world_thread is not None or self.schedule is None or self.schedule.world is None:
            return

        def build() -> None:
            try:
                self._build_world_files()
            except BaseException as exc:  # handed to write_world_files
                self._world_error = exc

        self._world_thread = threading.Thread(target=build, name="bracketry-world", daemon=True)
        self._world_thread.start()

    def write_world_files(self) -> None:
        """The world's calibration and camera model next to the recordings (``write_common``); builds the rig
        process's own world (poses) on first use, after recording, so it never delays the first frame."""
        if self._world_thread is not None:
            self._world_thread.join()
            self._world_thread = None
            if self._world_error is not None:
                raise self._world_error
        self._build_world_files()

    def _build_world_files(self) -> None:
        if self.schedule is None or self.schedule.world is None:
            return
        if self.world is None:
            from bracketry_emulator.synth import World
            from bracketry_emulator.synth.writer import write_common

            world = World(self.o.preset, seed=self.o.seed, resolution=self.o.resolution)
            write_common(world, self.out, {"dataset": "simulated-rig"})
            self.world = world

    def write_groundtruth(self) -> dict[str, Any] | None:
        """Ground truth of the recorded left frames (image time stamps), next to the recordings: each frame's pose
        is the world's at the rendered frame its pixels carry (never matched by order or timing). Frames that carry
        no index, or whose right partner carries another one, are left out and counted; ``groundtruth_unknown.txt``
        lists their stamps.

        Returns {"path", "frames", "poses", "unknown"} (None without a world)."""
        if self.schedule is None or self.schedule.world is None:
            return None
        self.start_world_files()  # built while the recordings are read
        frames = self.recorded_frame_ids("left")
        self.write_world_files()
        from bracketry.sim.frames import groundtruth_lines

        # a stereo pair whose right image shows another rendered frame than its left one has no single pose
        right = dict(self.recorded_frame_ids("right"))
        frames = [(t, k if right.get(t, k) == k else None) for t, k in frames]
        lines, unknown = groundtruth_lines(self.world, self.schedule.t_s, frames)
        path = self.out / "groundtruth.txt"
        path.write_text("\n".join(lines) + "\n")
        missing = self.out / "groundtruth_unknown.txt"
        if unknown:
            missing.write_text("".join(f"{t}\n" for t, k in frames if k is None))
        elif missing.exists():
            missing.unlink()
        return {"path": str(path), "frames": len(frames), "poses": len(frames) - unknown, "unknown": unknown}

    def close(self) -> None:
        """End every process this rig started (by PID) and the fake cameras."""
        if "daemon" in self.procs:
            with contextlib.suppress(BracketryError):
                self.stop_daemon(signal.SIGTERM, 20.0)
        for name in ("monitor-bridge", "panel", "trigger", "socat"):
            proc = self.procs.pop(name, None)
            if proc is not None:
                _end(proc, signal.SIGTERM)
        if self.qemu is not None:
            self.qemu.stop()
            self.qemu = None
        for side in list(self.cameras):
            self.stop_camera(side)
        if self.schedule is not None:
            self.schedule.stop()
            if not self.o.keep_frames:
                shutil.rmtree(self.schedule.folder, ignore_errors=True)


def _end(proc: subprocess.Popen, sig: int) -> None:
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
    for stream in (proc.stdin, proc.stdout, proc.stderr):
        if stream is not None:
            with contextlib.suppress(OSError):
                stream.close()


def _wait_for(cond: Callable[[], bool], timeout_s: float, what: str, alive: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():
            return
        if alive is not None and alive.poll() is not None:
            raise BracketryError(f"{what}: the process exited with code {alive.returncode}")
        time.sleep(0.1)
    raise BracketryError(f"timeout ({timeout_s:g} s) waiting for {what}")


def monitor_socket(out_dir: Path) -> Path:
    """The UNIX socket that carries the simulated rig's monitor out of its network namespace."""
    return Path(out_dir).resolve() / "monitor.sock"


def monitor_bridge_outside(out_dir: Path, port: int) -> subprocess.Popen:
    """socat serving 127.0.0.1:``port`` of this namespace from :func:`monitor_socket` (connections before the rig
    is up are refused)."""
    if shutil.which("socat") is None:
        raise BracketryError("socat not found: apt-get install socat (or run ./setup.sh)")
    import socket

    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError as exc:
            raise BracketryError(f"--monitor {port}: cannot listen on 127.0.0.1:{port}: {exc.strerror}") from None
    return subprocess.Popen(["socat", f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr,fork",
                             f"UNIX-CONNECT:{monitor_socket(out_dir)}"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def in_private_netns() -> bool:
    """True when this process runs in the namespace ``bracketry simulate`` made (127.0.0.2/.3 on lo)."""
    return os.environ.get(NETNS_ENV) == "1"


def reexec_in_netns(argv: list[str]) -> int:
    """Run ``python -m bracketry ARGV`` in a private network namespace; returns its exit code."""
    from bracketry_rig.cameras.netns import netns_argv, netns_available

    reason = netns_available()
    if reason:
        raise BracketryError(f"the simulated rig needs a private network namespace: {reason}")
    env = dict(os.environ, **{NETNS_ENV: "1"})
    return subprocess.call(netns_argv(_bracketry_cmd(*argv), tuple(CAMERA_ADDRESSES.values())), env=env)


def summary_json(rig: SimulatedRig, reports: list[Any], extra: dict[str, Any]) -> dict[str, Any]:
    """Summary of a simulated run (written to ``simulation.json``)."""
    out = {"recordings": [str(p) for p in rig.recordings()],
           "verify": [r.as_dict() for r in reports],
           "ok": bool(reports) and all(r.ok for r in reports), **extra}
    (rig.out / "simulation.json").write_text(json.dumps(out, indent=2, default=str))
    return out
