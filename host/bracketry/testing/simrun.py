"""Record from two in-process fake cameras software-triggered at a bracket cycle (tests, benchmarks, demos).

Run as ``python -m bracketry.testing.simrun --out DIR ...`` (inside ``bracketry_rig.cameras.netns.netns_argv`` when
the cameras need 127.0.0.2/.3). It starts one ``FakeCameraServer`` per side serving ``sim_pixels`` (pixels are a
known function of side and exposure, so tests can check every exported image exactly), opens them by IP with the
``aravis_fake`` profile, generates TRIGGER events at ``fps`` cycling the brackets, fires the cameras at each event
(``bracketry_rig.cameras.triggering.SoftwareTrigger``, as the daemon does), records, and writes a JSON summary
(``--summary``) with what was fired, dropped and served, and the packet-loss ``--seed``. ``--progress FILE`` gets
one line ``<trigger_seq> <host_ns>`` per fired trigger (flushed), for kill -9 tests.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_rig.cameras.camera import GigECamera
from bracketry_rig.cameras.fake import DEFAULT_SEED, FakeCameraServer
from bracketry_rig.cameras.profiles import CameraSettings
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US, SoftwareTrigger
from bracketry_rig.events import TriggerEvent
from bracketry_rig.recording.recorder import Recorder, RecorderConfig
from bracketry_rig.recording.session import RecordingSession

SIDE_OFFSET = {"left": 0, "right": 1000}
SIDES = ("left", "right")


def sim_pixels(side: str, exposure_us: int, width: int, height: int) -> np.ndarray:
    """Deterministic 12-bit test image of one side at one exposure: uint16 ``(height, width)``, codes 0..4095."""
    y, x = np.mgrid[0:height, 0:width].astype(np.int64)
    value = (x * 7 + y * 13 + SIDE_OFFSET.get(side, 0) + exposure_us // 100) % 4096
    return value.astype(np.uint16)


def run_internal(trigger: SoftwareTrigger, session: RecordingSession, brackets: list[int], period_ns: int, n: int,
                 lead_s: float, drop_events: set[int], skip: set[tuple[str, int]], progress: Any) -> list[int]:
    """Generate ``n`` pulses here (the simulated device stamps each when it fires the cameras)."""
    t0_ns = time.time_ns() + int(lead_s * 1e9)
    fired = []
    for k in range(n):
        t_ns = t0_ns + k * period_ns
        while (now := time.time_ns()) < t_ns:
            time.sleep(min(0.005, (t_ns - now) / 1e9))
        ev = TriggerEvent(session_id=1, trigger_seq=k, bracket_index=k % len(brackets),
                          exposure_us=brackets[k % len(brackets)], t_start_device_us=0)
        _fire(trigger, ev, skip)
        fire_ns = trigger.fired_at_ns or time.time_ns()  # the simulated device stamps the pulse when it fires it
        ev = dataclasses.replace(ev, t_start_device_us=(fire_ns - t0_ns) // 1000 + 5_000_000, t_start_host_ns=fire_ns)
        if k not in drop_events:
            session.on_trigger_event(ev)
        fired.append(k)
        if progress:
            progress.write(f"{k} {ev.t_start_host_ns}\n")
    return fired


def _fire(trigger: SoftwareTrigger, ev: TriggerEvent, skip: set[tuple[str, int]]) -> None:
    """The pulse of ``ev`` reaches every camera but the ones ``skip`` says miss it (side, trigger_seq)."""
    missed = {side for side, seq in skip if seq == ev.trigger_seq}
    trigger.fire(ev, None if not missed else [s for s in SIDES if s not in missed])


def run_with_trigger_simulator(trigger: SoftwareTrigger, session: RecordingSession, brackets: list[int],
                               period_us: int, n: int, drop_events: set[int], skip: set[tuple[str, int]],
                               progress: Any) -> list[int]:
    """Drive the STM32 trigger simulator through ``TriggerClient``; fire the cameras at each TRIGGER event."""
    from bracketry_rig.trigger.client import TriggerClient
    from bracketry_rig.trigger.simulator import SimConfig, simulate_on_pty

    sim, path = simulate_on_pty(config=SimConfig(drop_seqs=frozenset(drop_events)))
    fired: list[int] = []
    try:
        with TriggerClient.open(path) as client:
            client.hello()
            client.sync_clock()
            client.configure(period_us, brackets)
            client.start(session_id=1)
            for ev in client.events(timeout_s=10.0):  # generous: a loaded machine may stall the pty
                if ev.trigger_seq >= n:
                    break
                _fire(trigger, ev, skip)
                session.on_trigger_event(ev)
                fired.append(ev.trigger_seq)
                if progress:
                    progress.write(f"{ev.trigger_seq} {ev.t_start_host_ns}\n")
            client.stop()
    finally:
        sim.close()
    # pulses whose events the simulator dropped were never seen here, so the cameras were not fired for them
    return list(range(max(fired) + 1)) if fired else []


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--name", default="rec")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fps", type=float, default=22.0)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=200)
    ap.add_argument("--brackets-us", default="1000,2000,4000,8000,16000,32000")
    ap.add_argument("--addresses", default="127.0.0.2,127.0.0.3", help="left,right camera IPs")
    ap.add_argument("--lost-ratio", type=float, default=0.0, help="GVSP packet loss ratio of both fakes")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED,
                    help="seed of the fakes' packet loss (same seed: the same packets of the same frames lost)")
    ap.add_argument("--drop-events", default="", help="trigger_seqs whose TRIGGER event is not delivered")
    ap.add_argument("--skip-trigger", default="", help="side:seq,... pulses a camera does not see (missed trigger)")
    ap.add_argument("--packet-size", type=int, default=1500)
    ap.add_argument("--chunk-max-age-s", type=float, default=0.4)
    ap.add_argument("--split-s", type=float, default=600.0)
    ap.add_argument("--trigger", choices=["internal", "simulator"], default="internal",
                    help="internal: events generated here; simulator: the STM32 trigger simulator on a pty, driven "
                         "through TriggerClient (wire protocol, clock model); cameras fired at each TRIGGER event")
    ap.add_argument("--lead-s", type=float, default=1.0, help="time between arming the cameras and the first pulse")
    ap.add_argument("--summary", type=Path)
    ap.add_argument("--progress", type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    addresses = dict(zip(SIDES, args.addresses.split(","), strict=True))
    brackets = [int(b) for b in args.brackets_us.split(",")]
    drop_events = {int(s) for s in args.drop_events.split(",") if s}
    skip = {(p.split(":")[0], int(p.split(":")[1])) for p in args.skip_trigger.split(",") if p}
    period_ns = int(1e9 / args.fps)

    servers = {s: FakeCameraServer(addresses[s], f"SIM-{s.upper()}", image_source=functools.partial(sim_pixels, s),
                                   lost_packet_ratio=args.lost_ratio, seed=args.seed).start() for s in SIDES}
    cams = {s: GigECamera(addresses[s], side=s) for s in SIDES}
    for cam in cams.values():
        cam.configure(CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=args.width,
                                     height=args.height, packet_size_bytes=args.packet_size)).raise_if_mismatch()
    cfg = RecorderConfig(chunk_max_age_s=args.chunk_max_age_s, split_s=args.split_s)
    recorder = Recorder(args.out, args.name, cfg, metadata={"brackets_us": ",".join(map(str, brackets)),
                                                             "fps": str(args.fps), "source": "simrun"}).start()
    trigger = SoftwareTrigger(cams)  # the one software-trigger adapter, as the daemon's for these cameras
    session = RecordingSession(cams, recorder, initial_alignment=trigger.initial_alignment,
                               window=max(3, round(0.35 * args.fps))).start()
    trigger.arm()  # the fake loses the first software trigger after AcquisitionStart
    progress = open(args.progress, "w", buffering=1) if args.progress else None  # noqa: SIM115
    n = round(args.seconds * args.fps)
    if args.trigger == "simulator":
        fired = run_with_trigger_simulator(trigger, session, brackets, period_ns // 1000, n, drop_events, skip,
                                           progress)
    else:
        fired = run_internal(trigger, session, brackets, period_ns, n, args.lead_s, drop_events, skip, progress)
    # every buffer a fake served reaches us (the priming frame too, when the fake gave one): wait for all of them
    primed = {s: sum(1 for e in srv.exposures() if e == PRIMING_EXPOSURE_US) for s, srv in servers.items()}
    result = session.stop(drain_s=2.0, expect_frames={s: len(fired) + primed.get(s, 0) for s in cams})
    summary = {"fired": len(fired), "seed": args.seed, "dropped_events": sorted(drop_events),
               "skipped_triggers": sorted(skip),
               "served_exposures_us": {s: srv.exposures() for s, srv in servers.items()},
               "fill_errors": {s: srv.fill_errors for s, srv in servers.items()},
               "packets_lost": {s: len(srv.relay.dropped) if srv.relay else 0 for s, srv in servers.items()},
               "triggers_lost_by_fake": {s: srv.relay.triggers_lost if srv.relay else 0 for s, srv in servers.items()},
               **result}
    for cam in cams.values():
        cam.close()
    for srv in servers.values():
        srv.stop()
    text = json.dumps(summary, indent=1, default=str)
    if args.summary:
        args.summary.write_text(text)
    if recorder.error:
        print(recorder.error, file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
