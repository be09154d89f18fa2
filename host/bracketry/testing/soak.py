"""The simulated rig recording for a long time, with seeded faults or none, and every frame accounted for.

Run as ``python -m bracketry.testing.soak --out DIR --result FILE --seconds S [--faults ...] [--seed N]`` inside a
private network namespace and, for the ``disk_full`` fault, a private mount namespace whose recording disk is a
small tmpfs (:func:`soak_argv` builds the whole command line). ``benchmarks/bench_record_load.py`` (no fault, beside
busy loops) and ``benchmarks/bench_soak.py`` (every fault) run it and print its result.

The rig is the whole simulated rig (:class:`bracketry.sim.rig.SimulatedRig`: the daemon, two fake cameras, the
trigger and panel simulators), driven through its panel buttons as :mod:`bracketry.testing.faults` does. Faults, in a
seeded order, each after a seeded stretch of recording:

- ``cable_pull``: a camera off the network until the daemon shows it ERR, back after 2 s;
- ``camera_restart``: a camera's server stopped and started again at once (new frame ids, no controller), until
  the daemon closed the segment it was in and records with both cameras again;
- ``serial_garbage``: five bursts of 256 seeded bytes of line noise from the trigger simulator (SIGUSR1);
- ``disk_full``: a ballast file fills the recording disk below ``stop_free_mb``; once the daemon stopped, the
  ballast goes and RECORD is pressed again;
- ``sigkill``: the daemon killed (SIGKILL) while recording, started again, SENSORS and RECORD pressed.

Between faults, and for the whole run without faults, the daemon's states are polled every 0.5 s: a sensor not in
REC while no fault is under way is a *false fault*. Accounting: every frame a fake camera served (by its trigger
stamp, which the recording keeps as ``FrameMeta.cam_timestamp_ns``; the priming frames aside; a frame the fake filled
for no trigger of its relay's carries the fake's own stamp and is matched with a recorded frame no stamped one
accounts for) is either recorded, or
lost inside a fault's window (served up to ``CRASH_WINDOW_S`` before a fault began and until the rig recorded with
every sensor again), or
*unaccounted*; every recording is verified (a truncated one is repaired and the copy verified).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bracketry.sim.rig import NETNS_ENV, SimOptions, SimulatedRig
from bracketry.testing.faults import ALL, Session, _sensors_and_record, namespaced_argv, run_on_rig
from bracketry_rig.cameras.netns import netns_available
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US

FAULTS = ("cable_pull", "serial_garbage", "disk_full", "sigkill", "camera_restart")
#: frames served this long before a fault began may be lost with it (the recorder's open chunk, frames in flight)
CRASH_WINDOW_S = 3.0
#: problem kinds of ``verify`` that a fault explains in the recording it closed (a camera gone leaves drops and
#: unpaired frames behind, line noise loses TRIGGER events, a SIGKILL truncates the file)
EXPLAINED_KINDS = ("drops", "unpaired", "events_missing", "truncated")


def soak_argv(out: Path, result: Path, *args: str, tmpfs_mb: int | None = None) -> list[str]:
    """The command running the soak in a private network namespace (and, with ``tmpfs_mb``, a private mount
    namespace where ``out/disk`` is a tmpfs of that many MiB, the recording disk)."""
    inner = [sys.executable, "-m", "bracketry.testing.soak", "--out", str(out), "--result", str(result), *args]
    return namespaced_argv(inner, out, tmpfs_mb, "bracketry-soak")


def run_soak_process(argv: list[str], log: Path, poll_s: float,
                     on_poll: Callable[[float], None] | None = None) -> tuple[int, float]:
    """Run the soak command ``argv`` (:func:`soak_argv`) with its output in ``log``, reading the 1-minute load
    average every ``poll_s`` seconds (``on_poll(elapsed_s)`` each time it is still running). Returns its exit code and
    the mean of the load averages read."""
    t0 = time.monotonic()
    loads: list[float] = []
    with open(log, "wb") as out:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=out)
        while proc.poll() is None:
            loads.append(os.getloadavg()[0])
            try:
                proc.wait(timeout=poll_s)
            except subprocess.TimeoutExpired:
                if on_poll is not None:
                    on_poll(time.monotonic() - t0)
    return proc.returncode, statistics.fmean(loads) if loads else float("nan")


def parse_rig_bench_args(ap: argparse.ArgumentParser, keep_help: str) -> argparse.Namespace | None:
    """The options every benchmark of the simulated rig shares (``--fps``, ``--resolution``, ``--keep``) added to
    ``ap``, the command line parsed; None, with one line on stderr, where no private network namespace can be made."""
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--resolution", default="160x100")
    ap.add_argument("--keep", type=Path, default=None, help=keep_help)
    args = ap.parse_args()
    reason = netns_available()
    if reason:
        print(f"error: the simulated rig needs a private network namespace: {reason}", file=sys.stderr)
        return None
    return args


class Soak:
    """One run: the session, the served frames across camera restarts, fault windows and false faults."""

    def __init__(self, session: Session, seed: int) -> None:
        self.s = session
        self.rig = session.rig
        self.rng = random.Random(seed)
        self.served_done: dict[str, list[tuple[int, int, int]]] = {"left": [], "right": []}
        self.windows: list[dict[str, Any]] = []  # faults: kind, t0_ns, t1_ns, side
        self.false_faults: list[dict[str, Any]] = []
        self.polls = 0

    # -------------------------------------------------------------------------------------------- bookkeeping
    def served(self) -> dict[str, list[tuple[int, int, int]]]:
        """(frame id, trigger stamp ns, exposure µs) of every frame each fake served, restarts included."""
        out = {}
        for side in ("left", "right"):
            cam = self.rig.cameras.get(side)
            out[side] = self.served_done[side] + (cam.frames() if cam is not None else [])
        return out

    def stop_camera(self, side: str) -> None:
        cam = self.rig.cameras.get(side)
        self.s.stop_camera(side)
        if cam is not None:  # read once stopped: a frame filled while it stopped is counted too
            self.served_done[side] += cam.frames()

    def watch(self, seconds: float) -> None:
        """Let the rig record for ``seconds``, polling its states: a sensor not in REC is a false fault."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            reply = self.rig._status_or_none()
            self.polls += 1
            states = reply["state"]["states"] if reply else None
            if states is None or any(states.get(k) != "REC" for k in ALL):
                self.false_faults.append({"t_ns": time.time_ns(), "states": states,
                                          "errors": reply["state"].get("errors") if reply else None})
            self.rig.check_alive()
            time.sleep(0.5)

    def fault(self, kind: str) -> None:
        side = self.rng.choice(("left", "right"))
        window: dict[str, Any] = {"kind": kind, "side": side, "t0_ns": time.time_ns()}
        self.s.step(f"{kind}_begin", side=side)
        getattr(self, f"_{kind}")(side)
        window["t1_ns"] = time.time_ns()
        self.windows.append(window)
        self.s.step(f"{kind}_end", side=side)

    # -------------------------------------------------------------------------------------------- the faults
    def _all_rec(self, timeout_s: float = 90.0) -> None:
        self.rig.wait_states({k: "REC" for k in ALL}, timeout_s)

    def _cable_pull(self, side: str) -> None:
        self.stop_camera(side)
        self.rig.wait_states({f"cam_{side}": "ERR"}, 30.0)
        time.sleep(2.0)
        self.rig.start_camera(side)
        self._all_rec()

    def _segments(self) -> int:
        reply = self.rig._status_or_none()
        return int(reply["segments"]) if reply else 0

    def _camera_restart(self, side: str) -> None:
        before = self._segments()
        self.stop_camera(side)
        self.rig.start_camera(side)
        # the daemon finds the camera it knew gone (no frames, no control): the segment closes; then the new one
        deadline = time.monotonic() + 60.0
        while self._segments() <= before and time.monotonic() < deadline:
            self.rig.check_alive()
            time.sleep(0.2)
        self._all_rec()

    def _serial_garbage(self, _side: str) -> None:
        proc = self.rig.procs["trigger"]
        for _ in range(5):
            proc.send_signal(signal.SIGUSR1)
            time.sleep(0.2)
        self._all_rec(10.0)

    def _disk_full(self, _side: str) -> None:
        from bracketry_rig.daemon.disk import free_mb

        disk = self.rig.rec_dir
        ballast = disk / "ballast.bin"
        block = b"\xa5" * (1 << 20)
        with open(ballast, "wb") as f:
            while free_mb(disk) > self.rig.o.stop_free_mb - 4:
                f.write(block)
                f.flush()
        self.s.wait_message("DISK FULL", 60.0)
        self.rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
        ballast.unlink()
        self.rig.press("record")
        self._all_rec()

    def _sigkill(self, _side: str) -> None:
        proc = self.rig.procs.pop("daemon")
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        self.rig.start_daemon()
        self.s.wait_screen("L:OFF R:OFF TRIG:OFF", 60.0)
        self.rig.press("sensors")
        self.rig.wait_states({k: "IDLE" for k in ALL}, 90.0)
        self.rig.press("record")
        self._all_rec()


def run(soak: Soak, seconds: float, faults: tuple[str, ...], gap_s: tuple[float, float]) -> dict[str, Any]:
    """Record for ``seconds`` with ``faults`` in a seeded order (each after a seeded stretch in ``gap_s``), stop,
    SIGTERM; then verify and account."""
    s, rig = soak.s, soak.rig
    _sensors_and_record(s)
    t_end = time.monotonic() + seconds
    order: list[str] = []
    while faults:
        gap = soak.rng.uniform(*gap_s)
        if time.monotonic() + gap >= t_end:
            break
        soak.watch(gap)
        if not order:
            order = soak.rng.sample(faults, len(faults))
        soak.fault(order.pop(0))
    soak.watch(max(0.0, t_end - time.monotonic()))
    s.step("before_stop")
    rig.press("record")
    rig.wait_states({k: "IDLE" for k in ALL}, 60.0)
    rc = rig.stop_daemon(signal.SIGTERM)
    s.step("sigterm", daemon_exit_code=rc)
    counters = (s.steps[-2].get("counters") or {})
    return {"daemon_exit_code": rc, "daemon_counters": counters, **account(soak)}


def recorded_stamps(rig: SimulatedRig) -> dict[str, Counter[int]]:
    """side -> camera timestamps (trigger stamps) of every frame recorded by this rig, with their counts."""
    from bracketry_base.recording import topics as T
    from bracketry_base.recording.decode import decode
    from bracketry_base.recording.reader import RecordingReader

    out: dict[str, Counter[int]] = {side: Counter() for side in T.SIDES}
    topics = {T.frame_meta_topic(side): side for side in T.SIDES}
    for seg in rig.recordings():
        for f in sorted(seg.glob("*.mcap")):
            if f.name.endswith(".repaired.mcap"):
                continue
            for m in RecordingReader(f).messages(set(topics)):
                out[topics[m.topic]][int(decode(m.schema_name, m.data).cam_timestamp_ns)] += 1
    return out


def verify_all(rig: SimulatedRig) -> list[dict[str, Any]]:
    """Every recording of this rig verified; a truncated one is repaired and the copy verified too."""
    from bracketry_base.recording.verify import repair_recording, verify_recording

    rows = []
    for seg in rig.recordings():
        report = verify_recording(seg)
        row: dict[str, Any] = {"recording": str(seg), "readable": report.readable, "ok": report.ok,
                               "events": report.events,
                               "truncated": report.truncated, "problems": report.problems,
                               "kinds": problem_kinds(report)}
        if report.truncated:
            for f in sorted(seg.glob("*.mcap")):
                if f.name.endswith(".repaired.mcap"):
                    continue
                r = verify_recording(f)
                if r.truncated:
                    copy, _n = repair_recording(f, overwrite=True)
                    again = verify_recording(copy)
                    row["repaired_readable"] = again.readable and not again.truncated
        rows.append(row)
    return rows


def problem_kinds(report: Any) -> dict[str, int]:
    """How many of each problem kind a verify report counts (both cameras)."""
    kinds: Counter[str] = Counter()
    for sr in report.sides.values():
        for kind in ("drops", "incomplete", "unpaired", "bracket_order_breaks", "exposure_mismatches",
                     "timestamp_mismatches", "missing_images", "lost_triggers"):
            kinds[kind] += int(getattr(sr, kind))
    kinds["events_missing"] = report.events_missing
    kinds["queue_overflows"] = report.queue_overflows
    kinds["truncated"] = int(report.truncated)
    return {k: v for k, v in kinds.items() if v}


def account(soak: Soak) -> dict[str, Any]:
    """Served frames against recorded ones (module doc), and the recordings verified."""
    recorded = recorded_stamps(soak.rig)
    served = soak.served()
    sides: dict[str, Any] = {}
    for side in ("left", "right"):
        counts = Counter({"served": 0, "recorded": 0, "in_fault_window": 0, "unaccounted": 0, "not_served": 0,
                          "unstamped": 0})
        seen: set[int] = set()
        unaccounted: list[int] = []
        for _fid, t_ns, exposure_us in served[side]:
            if exposure_us == PRIMING_EXPOSURE_US:
                continue
            counts["served"] += 1
            if t_ns == 0:  # a fill no relay trigger was waiting for: it carries the fake's own stamp (matched below)
                counts["unstamped"] += 1
                continue
            seen.add(t_ns)
            if recorded[side].get(t_ns):
                counts["recorded"] += 1
            elif any(w["t0_ns"] - CRASH_WINDOW_S * 1e9 <= t_ns <= w["t1_ns"] for w in soak.windows):
                counts["in_fault_window"] += 1
            else:
                counts["unaccounted"] += 1
                unaccounted.append(t_ns)
        # recorded frames whose stamp no stamped served frame has: the unstamped served frames, else not served
        others = sum(n for t, n in recorded[side].items() if t not in seen)
        matched = min(others, counts["unstamped"])
        counts["recorded"] += matched
        counts["unaccounted"] += counts["unstamped"] - matched
        counts["not_served"] = others - matched
        counts["recorded_twice"] = sum(n - 1 for n in recorded[side].values() if n > 1)
        sides[side] = {**counts, "unaccounted_stamps": unaccounted[:20]}
    verified = verify_all(soak.rig)
    faults_in = Counter(w["kind"] for w in soak.windows)
    unexplained = [{"recording": v["recording"], "kinds": {k: n for k, n in v["kinds"].items()
                                                            if k not in EXPLAINED_KINDS}}
                   for v in verified if any(k not in EXPLAINED_KINDS for k in v["kinds"])]
    if not soak.windows:  # without faults nothing is explained: every problem counts
        unexplained = [{"recording": v["recording"], "kinds": v["kinds"]} for v in verified if v["kinds"]]
    return {"sides": sides, "verify": verified, "faults": dict(faults_in), "windows": soak.windows,
            "false_faults": soak.false_faults, "polls": soak.polls, "unexplained": unexplained}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--result", type=Path, required=True)
    ap.add_argument("--seconds", type=float, default=1800.0, help="recording time (faults included)")
    ap.add_argument("--faults", default="", help=f"comma-separated, of {','.join(FAULTS)} (default: none)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the faults' order, sides and spacing")
    ap.add_argument("--gap-s", default="20,40", help="seconds of recording before each fault: min,max")
    ap.add_argument("--resolution", default="160x100")
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    from bracketry_base.options import parse_resolution

    faults = tuple(f for f in args.faults.split(",") if f)
    unknown = [f for f in faults if f not in FAULTS]
    if unknown:
        print(f"error: --faults: unknown {', '.join(unknown)} (known: {', '.join(FAULTS)})", file=sys.stderr)
        return 2
    lo, hi = (float(x) for x in args.gap_s.split(","))
    os.environ[NETNS_ENV] = "1"
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    disk = out / "disk"
    if "disk_full" in faults and not os.path.ismount(disk):
        print(f"error: --faults disk_full needs {disk} to be a small tmpfs (run through soak_argv(tmpfs_mb=...))",
              file=sys.stderr)
        return 2
    opts = SimOptions(out_dir=out, resolution=parse_resolution(args.resolution), fps=args.fps, world_seconds=3.0,
                      world=False, output_dir=disk if disk.is_dir() else None,
                      echo=(lambda _s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True)))
    rig = SimulatedRig(opts)
    session = Session(rig)
    soak = Soak(session, args.seed)
    result: dict[str, Any] = {"seconds": args.seconds, "faults_asked": faults, "seed": args.seed,
                              "fps": args.fps, "resolution": args.resolution, "daemon_log": str(out / "daemon.log")}
    run_on_rig(session, result, lambda: run(soak, args.seconds, faults, (lo, hi)), soak.stop_camera)
    if "sides" not in result and "error" in result:
        with contextlib.suppress(Exception):
            result.update(account(soak))
    args.result.write_text(json.dumps(result, indent=1, default=str))
    return 1 if "error" in result else 0


if __name__ == "__main__":
    raise SystemExit(main())
