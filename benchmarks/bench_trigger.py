"""Trigger benchmark: the Python simulator and the real firmware in QEMU, measured side by side in one run.

For each device: PING round trip (median, us), clock-model residual (us), and a 1 kHz pulse stream (period 1000 us,
width 100 us) for a few seconds: events/s received by the host client and events missed (trigger_seq gaps).

    .venv/bin/python benchmarks/bench_trigger.py [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from bracketry_rig.trigger.client import TriggerClient
from bracketry_rig.trigger.qemu import QemuTrigger, build_firmware
from bracketry_rig.trigger.simulator import simulate_on_pty


def measure(url: str, n_pings: int, stream_s: float, timeout_s: float) -> dict[str, float]:
    with TriggerClient.open(url, timeout_s=timeout_s) as client:
        client.link.peer_lost_after_s = 10.0
        client.hello()
        rtts_us = []
        for _ in range(n_pings):
            t0 = time.perf_counter_ns()
            client.ping()
            rtts_us.append((time.perf_counter_ns() - t0) / 1000.0)
        residual_us = client.clock.residual_us
        client.configure(1000, [100])
        client.start(1)
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < stream_s:
            if client.get_event(0.1) is not None:
                n += 1
        elapsed = time.monotonic() - t0
        client.stop()
        n += len(client.drain_events())
        return {"ping_rtt_median_us": statistics.median(rtts_us), "clock_residual_us": residual_us,
                "events_per_s": n / elapsed, "missed_events": float(client.counters.missed_events)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer pings, shorter streams")
    args = ap.parse_args()
    n_pings, stream_s = (20, 2.0) if args.quick else (100, 5.0)
    results: dict[str, dict[str, float]] = {}
    sim, path = simulate_on_pty()
    try:
        results["simulator"] = measure(path, n_pings, stream_s, 0.5)
    finally:
        sim.close()
    with tempfile.TemporaryDirectory() as tmp:
        elf = build_firmware(Path(tmp))
        with QemuTrigger(elf) as q:
            results["qemu"] = measure(q.url, n_pings, stream_s, 1.0)
    keys = list(results["simulator"])
    print(f"{'metric':<22}{'simulator':>14}{'qemu':>14}{'qemu/sim':>10}")
    for k in keys:
        a, b = results["simulator"][k], results["qemu"][k]
        ratio = f"{b / a:.2f}" if a else "-"
        print(f"{k:<22}{a:>14.1f}{b:>14.1f}{ratio:>10}")


if __name__ == "__main__":
    main()
