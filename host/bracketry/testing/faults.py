"""Scripted sessions of the simulated rig with fault injection, for tests and demos; each writes a JSON result.

Run as ``python -m bracketry.testing.faults --scenario NAME --out DIR --result FILE`` inside a private network namespace
(:func:`scenario_argv` builds the whole command line: ``unshare -n`` and, for ``disk``, a private mount namespace with
a small tmpfs as the recording disk). The test process stays outside and asserts on the JSON result and the files.

Scenarios (panel buttons pressed through the panel firmware simulator, states read from the screen file and the
status socket):

- ``e2e``: SENSORS -> IDLE, RECORD -> REC, ``--seconds`` of recording, RECORD -> IDLE, SIGTERM -> exit code; then
  the one-shot ``bracketry record --config F --duration D`` on the same simulated devices.
- ``faults``: while recording: trigger simulator killed and restarted, right camera stopped and restarted, panel
  rebooted (its simulator killed and restarted), then SIGKILL of the daemon (``t_kill_ns`` in the result) and a
  new daemon that brings the sensors up again.
- ``disk``: recording on a small tmpfs that a ballast file fills: the daemon stops cleanly below ``stop_free_mb``
  and refuses RECORD below ``min_free_mb``; the segments are verified inside (the tmpfs dies with the namespace).
  Then the left camera drops off the network while idle and comes back.
- ``preview``: the monitor on (127.0.0.1:8470 in the namespace): SENSORS -> IDLE, previews of every bracket of both
  cameras arrive while nothing is recorded; a new bracket table applied through the monitor reaches the previews;
  RECORD -> REC, ``--seconds`` of recording, RECORD -> IDLE, and the previews resume.

The result holds ``steps`` (name, monotonic time, screen lines, sensor states, message, counters at each checkpoint),
``served`` (exposure of every frame each fake camera served, in order, across restarts, with ``served_at`` counts per
step), ``segments`` and, when the scenario failed, ``error`` with a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bracketry.sim.rig import CAMERA_ADDRESSES, NETNS_ENV, SimOptions, SimulatedRig
from bracketry.testing.http import http_json
from bracketry_base.errors import BracketryError

ALL = ("cam_left", "cam_right", "trigger")
SCENARIOS = ("e2e", "faults", "disk", "preview")
#: the monitor's port in the scenario's private network namespace
PREVIEW_PORT = 8470


def scenario_argv(scenario: str, out: Path, result: Path, *args: str, tmpfs_mb: int | None = None) -> list[str]:
    """The command running ``scenario`` in a private network namespace (and, with ``tmpfs_mb``, a private mount
    namespace where ``out/disk`` is a tmpfs of that many MiB)."""
    inner = [sys.executable, "-m", "bracketry.testing.faults", "--scenario", scenario, "--out", str(out),
             "--result", str(result), *args]
    return namespaced_argv(inner, out, tmpfs_mb, "bracketry-sim")


def namespaced_argv(inner: list[str], out: Path, tmpfs_mb: int | None, tmpfs_name: str) -> list[str]:
    """``inner`` in a private network namespace holding the fake cameras' addresses (and, with ``tmpfs_mb``, a
    private mount namespace where ``out/disk`` is a tmpfs of that many MiB named ``tmpfs_name``)."""
    from bracketry_rig.cameras.netns import netns_argv

    argv = netns_argv(inner, tuple(CAMERA_ADDRESSES.values()))
    if tmpfs_mb is None:
        return argv
    disk = out / "disk"
    script = (f"mkdir -p {shlex.quote(str(disk))} && mount -t tmpfs -o size={int(tmpfs_mb)}m {tmpfs_name} "
              f"{shlex.quote(str(disk))} && exec \"$@\"")
    return ["unshare", "--mount", "--propagation", "private", "sh", "-c", script, "mountns", *argv]


class Session:
    """One scripted run: the rig, checkpoints and the served-frame bookkeeping across camera restarts."""

    def __init__(self, rig: SimulatedRig) -> None:
        self.rig = rig
        self.t0 = time.monotonic()
        self.steps: list[dict[str, Any]] = []
        self._served_done: dict[str, list[int]] = {"left": [], "right": []}
        self.seen: list[str] = []

    def listen_sd_notify(self) -> None:
        """Be systemd for the daemon: a ``$NOTIFY_SOCKET`` datagram socket and a 2 s watchdog (set before start)."""
        import socket

        path = self.rig.out / "notify.sock"
        path.unlink(missing_ok=True)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(str(path))
        sock.settimeout(0.2)
        self._notes: list[str] = []
        self._notify_stop = threading.Event()

        def collect() -> None:
            with sock:
                while not self._notify_stop.is_set():
                    try:
                        self._notes.append(sock.recv(4096).decode())
                    except (TimeoutError, OSError):
                        continue

        self._notify_thread = threading.Thread(target=collect, name="sd-notify", daemon=True)
        self._notify_thread.start()
        os.environ["NOTIFY_SOCKET"] = str(path)
        os.environ["WATCHDOG_USEC"] = "2000000"

    def notifications(self) -> list[str]:
        """Every sd_notify message received; stops listening (later children do not inherit the socket)."""
        os.environ.pop("NOTIFY_SOCKET", None)
        os.environ.pop("WATCHDOG_USEC", None)
        if getattr(self, "_notify_thread", None) is None:
            return []
        self._notify_stop.set()
        self._notify_thread.join(timeout=5)
        return list(self._notes)

    def served(self) -> dict[str, list[int]]:
        """Exposure (µs) of every frame each side's fake camera served so far, restarts included."""
        out = {}
        for side in ("left", "right"):
            cam = self.rig.cameras.get(side)
            out[side] = self._served_done[side] + (cam.exposures() if cam is not None else [])
        return out

    def stop_camera(self, side: str) -> None:
        cam = self.rig.cameras.get(side)
        if cam is not None:
            self._served_done[side] += cam.exposures()
        self.rig.stop_camera(side)

    def step(self, name: str, **extra: Any) -> dict[str, Any]:
        """Record a checkpoint: screen, daemon state (if it answers), served frame counts."""
        reply = self.rig._status_or_none()
        state = reply["state"] if reply else None
        entry = {"name": name, "t_s": round(time.monotonic() - self.t0, 2), "t_ns": time.time_ns(),
                 "screen": self.rig.screen(), "seen": self.seen, "states": state["states"] if state else None,
                 "message": state["message"] if state else None, "counters": state["counters"] if state else None,
                 "recording": state["recording"] if state else None, "segments": reply["segments"] if reply else None,
                 "panel": reply.get("panel") if reply else None,
                 "served_at": {s: len(v) for s, v in self.served().items()}, **extra}
        self.steps.append(entry)
        self.rig.o.echo(f"[{entry['t_s']:6.1f} s] {name}: states={entry['states']} message={entry['message']!r}")
        return entry

    def wait_screen(self, text: str, timeout_s: float) -> list[str]:
        """Wait until ``text`` is on the panel screen; the screen as matched goes into the next step as ``seen``
        (the firmware blinks ERR slots, so a later look may miss it)."""
        self.seen = self.rig.wait_screen(text, timeout_s)
        return self.seen

    def wait_message(self, text: str, timeout_s: float) -> None:
        """Wait until the daemon's message line contains ``text``."""
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            reply = self.rig._status_or_none()
            if reply is not None:
                last = reply["state"]["message"]
                if text in last:
                    return
            self.rig.check_alive()
            time.sleep(0.2)
        raise BracketryError(f"timeout waiting for message {text!r}: daemon says {last!r}")

    def status_cli(self, *args: str) -> dict[str, Any]:
        """``bracketry status --socket S [ARGS]``: exit code and output."""
        res = subprocess.run([sys.executable, "-m", "bracketry", "status", "--socket", str(self.rig.socket_path),
                              *args], capture_output=True, text=True, timeout=60)
        return {"exit_code": res.returncode, "stdout": res.stdout, "stderr": res.stderr}

    def wait_segments(self, n: int, timeout_s: float) -> None:
        """Wait until the daemon has closed ``n`` recording segments."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            reply = self.rig._status_or_none()
            if reply is not None and reply["segments"] >= n:
                return
            self.rig.check_alive()
            time.sleep(0.2)
        raise BracketryError(f"the daemon did not close {n} segments within {timeout_s:g} s")

    def wait_recorded_events(self, n: int, timeout_s: float) -> None:
        """Wait until the daemon has delivered ``n`` more trigger events than now (recording makes progress)."""
        start = self._events()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._events() >= start + n:
                return
            self.rig.check_alive()
            time.sleep(0.2)
        raise BracketryError(f"the recording made no progress ({n} events) within {timeout_s:g} s")

    def _events(self) -> int:
        reply = self.rig._status_or_none()
        return int(reply["state"]["counters"].get("trigger_events", 0)) if reply else 0


def _sensors_and_record(s: Session) -> None:
    rig = s.rig
    s.wait_screen("READY", 30.0)
    s.step("ready")
    rig.press("sensors")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    s.wait_screen("L:IDL R:IDL TRIG:IDL", 20.0)
    s.step("idle")
    rig.press("record")
    rig.wait_states({k: "REC" for k in ALL}, 60.0)
    s.wait_screen("L:REC R:REC TRIG:REC", 20.0)
    s.step("rec")


def run_e2e(s: Session, seconds: float, record_s: float) -> dict[str, Any]:
    """Buttons end to end, SIGTERM, then ``bracketry record`` one-shot."""
    rig = s.rig
    _sensors_and_record(s)
    rig.run_for(seconds)
    s.step("before_stop", status_cli=s.status_cli(), status_cli_json=s.status_cli("--json"))
    rig.press("record")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    s.wait_screen("SAVED", 20.0)
    s.wait_screen("L:IDL R:IDL TRIG:IDL", 20.0)
    s.step("stopped")
    rc = rig.stop_daemon(signal.SIGTERM)
    s.step("sigterm", daemon_exit_code=rc)
    out: dict[str, Any] = {"daemon_exit_code": rc, "sd_notify": s.notifications()}
    if record_s > 0:
        w, h = rig.o.resolution
        cmd = [sys.executable, "-m", "bracketry", "record", "--config", str(rig.config_path), "--duration-s",
               f"{record_s:g}s", "--roi", f"{w}x{h}"]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120 + record_s)
        s.step("record_oneshot", exit_code=res.returncode)
        out["record"] = {"exit_code": res.returncode, "stdout": res.stdout[-4000:], "stderr": res.stderr[-4000:]}
    return out


def run_faults(s: Session, seconds: float) -> dict[str, Any]:
    """Trigger, camera and panel faults while recording, SIGKILL of the daemon, then SIGTERM of the restarted daemon
    while it records."""
    rig = s.rig
    _sensors_and_record(s)
    s.wait_recorded_events(round(seconds * rig.o.fps), 60.0)
    # 1. trigger simulator killed: ERR on the panel, segment closed; restarted: a new segment records
    s.step("trigger_kill")
    rig.stop_trigger(signal.SIGKILL)
    rig.wait_states({"trigger": "ERR"}, 30.0)
    s.wait_screen("TRIG:ERR", 20.0)
    s.step("trigger_err")
    rig.start_trigger()
    rig.wait_states({k: "REC" for k in ALL}, 60.0)
    s.wait_screen("TRIG:REC", 20.0)
    s.step("trigger_back")
    s.wait_recorded_events(round(seconds * rig.o.fps), 60.0)
    # 2. right camera off the network: ERR, left goes on recording; back: a new segment with both
    s.step("camera_stop")
    s.stop_camera("right")
    rig.wait_states({"cam_right": "ERR"}, 30.0)
    s.wait_screen("R:ERR", 20.0)
    s.step("camera_err", status_cli=s.status_cli())
    s.wait_segments(2, 60.0)  # trigger fault + camera fault closed two segments; the third records the left camera
    s.wait_recorded_events(round(rig.o.fps), 60.0)
    s.step("camera_err_recording")
    rig.start_camera("right")
    rig.wait_states({k: "REC" for k in ALL}, 60.0)
    s.wait_screen("R:REC", 20.0)
    s.step("camera_back")
    s.wait_recorded_events(round(seconds * rig.o.fps), 60.0)
    # 3. panel rebooted: the daemon records on; the new panel shows the state again
    s.step("panel_kill")
    rig.stop_panel(signal.SIGKILL)
    rig.screen_file.unlink(missing_ok=True)  # whatever is shown next comes from the rebooted panel
    s.wait_recorded_events(round(rig.o.fps), 60.0)
    s.step("panel_down")
    rig.start_panel()
    s.wait_screen("L:REC R:REC TRIG:REC", 60.0)
    s.step("panel_back")
    s.wait_recorded_events(round(seconds * rig.o.fps), 60.0)
    # 4. SIGKILL of the daemon mid-recording
    before = s.step("before_kill")
    proc = rig.procs.pop("daemon")
    t_kill_ns = time.time_ns()
    proc.send_signal(signal.SIGKILL)
    rc = proc.wait(timeout=30)
    s.step("killed", daemon_exit_code=rc)
    # 5. the service comes back after the crash (systemd Restart=): stale socket, a trigger still STARTed
    rig.start_daemon()
    s.wait_screen("L:OFF R:OFF TRIG:OFF", 30.0)
    rig.press("sensors")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    s.wait_screen("L:IDL R:IDL TRIG:IDL", 20.0)
    s.step("restarted_idle")
    # 6. SIGTERM while recording (systemctl stop, shutdown): the recording is closed cleanly, footer and all
    rig.press("record")
    rig.wait_states({k: "REC" for k in ALL}, 60.0)
    s.wait_recorded_events(round(rig.o.fps), 60.0)
    s.step("restarted_rec")
    rc2 = rig.stop_daemon(signal.SIGTERM)
    s.step("restarted_sigterm", daemon_exit_code=rc2)
    return {"daemon_exit_code": rc, "t_kill_ns": t_kill_ns, "events_before_kill": before["counters"],
            "restarted_exit_code": rc2}


def run_disk(s: Session, ballast_mb: int) -> dict[str, Any]:
    """Fill the recording disk with a ballast file while recording; the daemon must stop cleanly and refuse."""
    rig = s.rig
    from bracketry_rig.daemon.disk import free_mb

    disk = rig.rec_dir
    _sensors_and_record(s)
    s.wait_recorded_events(round(2 * rig.o.fps), 60.0)
    s.step("filling", free_mb=free_mb(disk))
    ballast = disk / "ballast.bin"
    block = b"\xa5" * (1 << 20)
    written = 0
    with open(ballast, "wb") as f:
        while written < ballast_mb and free_mb(disk) > rig.o.stop_free_mb - 4:
            f.write(block)
            f.flush()
            written += 1
            time.sleep(0.02)
    s.step("filled", free_mb=free_mb(disk), ballast_mb=written)
    s.wait_message("DISK FULL", 30.0)
    rig.wait_states({k: "IDLE" for k in ALL}, 30.0)
    s.wait_screen("DISK FULL", 20.0)
    s.step("disk_full")
    rig.press("record")
    s.wait_message("DISK LOW", 30.0)
    s.wait_screen("DISK LOW", 20.0)
    s.step("refused")
    # an idle camera drops off the network and comes back: ERR, then IDLE again by itself
    s.stop_camera("left")
    rig.wait_states({"cam_left": "ERR"}, 60.0)
    s.wait_screen("L:ERR", 20.0)
    s.step("idle_camera_err")
    rig.start_camera("left")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    s.wait_screen("L:IDL R:IDL TRIG:IDL", 20.0)
    s.step("idle_camera_back")
    rc = rig.stop_daemon(signal.SIGTERM)
    s.step("sigterm", daemon_exit_code=rc)
    from bracketry_base.recording.verify import verify_recording

    reports = [verify_recording(seg).as_dict() for seg in rig.recordings()]
    return {"daemon_exit_code": rc, "ballast_mb": written, "verify": reports}


def _previews(base: str) -> dict[str, dict[int, dict[str, Any]]]:
    """side -> bracket index -> the monitor's latest preview entry."""
    _code, data = http_json(f"{base}/api/previews")
    return {side: {e["bracket"]: e for e in entries} for side, entries in data["cameras"].items()}


def _wait_previews(s: Session, base: str, brackets_us: list[int], timeout_s: float,
                   newer_than: dict[str, dict[int, dict[str, Any]]] | None = None) -> dict[str, Any]:
    """Wait until both cameras have a preview of every bracket of ``brackets_us`` (with its exposure), each newer
    than in ``newer_than`` when given."""
    deadline = time.monotonic() + timeout_s
    last: dict[str, Any] = {}
    while time.monotonic() < deadline:
        last = _previews(base)
        ok = all([last.get(side, {}).get(k, {}).get("exposure_us") for k in range(len(brackets_us))] == brackets_us
                 for side in ("left", "right"))
        if ok and newer_than is not None:
            ok = all(last[side][k]["version"] > newer_than.get(side, {}).get(k, {}).get("version", 0)
                     for side in ("left", "right") for k in range(len(brackets_us)))
        if ok:
            return last
        s.rig.check_alive()
        time.sleep(0.3)
    raise BracketryError(f"no previews of {brackets_us} from both cameras within {timeout_s:g} s: {last}")


def _files_under(path: Path) -> list[str]:
    return sorted(str(p.relative_to(path)) for p in path.rglob("*")) if path.exists() else []


def run_preview(s: Session, seconds: float) -> dict[str, Any]:
    """Previews while the sensors are idle, a bracket table applied while idle, then a recording."""
    rig = s.rig
    base = f"http://127.0.0.1:{PREVIEW_PORT}"
    token = str(rig.status()["monitor"]["url"]).split("token=", 1)[1]
    brackets_us = [round(b * 1000) for b in rig.o.brackets_ms]
    s.wait_screen("READY", 30.0)
    s.step("ready", previews=_previews(base))
    rig.press("sensors")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    idle = _wait_previews(s, base, brackets_us, 60.0)
    s.step("idle_previews", previews=idle, files=_files_under(rig.rec_dir), status=http_json(f"{base}/api/status")[1])
    new_us = [b // 2 for b in brackets_us]
    applied = http_json(f"{base}/api/action", {"action": "apply_brackets", "brackets_us": new_us}, token)
    applied_previews = _wait_previews(s, base, new_us, 60.0)
    s.step("applied_previews", applied=applied, previews=applied_previews, files=_files_under(rig.rec_dir))
    rig.press("record")
    rig.wait_states({k: "REC" for k in ALL}, 60.0)
    s.step("rec")
    s.wait_recorded_events(round(seconds * rig.o.fps), 60.0 + 3 * seconds)
    s.step("before_stop", previews=_previews(base))
    rig.press("record")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    s.wait_message("SAVED", 20.0)
    s.step("stopped", previews=_previews(base))
    resumed = _wait_previews(s, base, new_us, 60.0, newer_than=s.steps[-1]["previews"])
    s.step("resumed_previews", previews=resumed, status=http_json(f"{base}/api/status")[1])
    rc = rig.stop_daemon(signal.SIGTERM)
    s.step("sigterm", daemon_exit_code=rc)
    return {"daemon_exit_code": rc, "brackets_us": brackets_us, "applied_us": new_us}



def run_on_rig(session: Session, result: dict[str, Any], body: Callable[[], dict[str, Any]],
               stop_camera: Callable[[str], None], before_start: Callable[[], None] | None = None) -> None:
    """Start the session's rig (every frame ready before the devices start, so fault timing is as designed), merge
    ``body()``'s result into ``result``; an exception goes into ``result`` (``error``, ``traceback``) as a last step.
    Whatever happens, every camera is stopped through ``stop_camera`` and the rig is closed; ``result`` gets the
    session's ``steps`` and ``runtime_s``."""
    rig = session.rig
    t0 = time.monotonic()
    try:
        rig.prepare_frames(wait=True)
        if before_start is not None:
            before_start()
        rig.start()
        result.update(body())
    except Exception as exc:
        result["error"] = f"{type(exc).__name__}: {exc}"
        result["traceback"] = traceback.format_exc()
        with contextlib.suppress(Exception):
            session.step("error")
    finally:
        for side in list(rig.cameras):
            stop_camera(side)
        rig.close()
        result["steps"] = session.steps
        result["runtime_s"] = round(time.monotonic() - t0, 1)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", choices=SCENARIOS, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--result", type=Path, required=True)
    ap.add_argument("--seconds", type=float, default=10.0, help="e2e: recording time; faults: time between faults")
    ap.add_argument("--record-seconds", type=float, default=10.0, help="e2e: duration of `bracketry record` (0: skip)")
    ap.add_argument("--resolution", default="320x200")
    ap.add_argument("--fps", type=float, default=22.0)
    ap.add_argument("--world", action="store_true", help="serve the synthetic world (default: a test pattern)")
    ap.add_argument("--min-free-mb", type=int, default=64)
    ap.add_argument("--stop-free-mb", type=int, default=16)
    ap.add_argument("--ballast-mb", type=int, default=4096)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    from bracketry_base.options import parse_resolution

    os.environ[NETNS_ENV] = "1"
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    opts = SimOptions(out_dir=out, resolution=parse_resolution(args.resolution), fps=args.fps, world_seconds=3.0,
                      world=args.world, min_free_mb=args.min_free_mb, stop_free_mb=args.stop_free_mb,
                      output_dir=out / "disk" if args.scenario == "disk" else None,
                      monitor_port=PREVIEW_PORT if args.scenario == "preview" else None,
                      echo=(lambda _s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True)))
    rig = SimulatedRig(opts)
    session = Session(rig)
    result: dict[str, Any] = {"scenario": args.scenario, "config": str(rig.config_path),
                              "daemon_log": str(out / "daemon.log"), "screen_file": str(rig.screen_file)}
    def body() -> dict[str, Any]:
        if args.scenario == "e2e":
            return run_e2e(session, args.seconds, args.record_seconds)
        if args.scenario == "faults":
            return run_faults(session, args.seconds)
        if args.scenario == "preview":
            return run_preview(session, args.seconds)
        return run_disk(session, args.ballast_mb)

    run_on_rig(session, result, body, session.stop_camera,
               before_start=session.listen_sd_notify if args.scenario == "e2e" else None)
    result["served"] = session.served()
    result["segments"] = [str(p) for p in rig.recordings()]
    args.result.write_text(json.dumps(result, indent=1, default=str))
    return 1 if "error" in result else 0


if __name__ == "__main__":
    raise SystemExit(main())
