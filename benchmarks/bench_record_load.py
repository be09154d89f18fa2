"""Recording at load: the simulated rig records beside busy loops, several times; no false drop, mismatch or fault.

Usage: .venv/bin/python benchmarks/bench_record_load.py [--runs 5] [--seconds 120] [--hogs 4] [--fps 10]

Each run starts ``--hogs`` busy loops (``python -c 'while True: pass'``, ended by PID after the run), then the whole
simulated rig (``bracketry.testing.soak`` without faults, in a private network namespace: the daemon, two Aravis
fake cameras fired by software triggers, the trigger and panel simulators) records ``--seconds`` through its panel
buttons. Printed per run: the load average seen during it (1-minute, mean of samples every 5 s), pulses, frames
recorded per camera, then what must stay 0: drops, timestamp mismatches, unpaired frames, false faults (a sensor
seen out of REC, a segment restarted), software triggers the fake cameras lost, served frames not recorded; and the
daemon's starved supervisor windows (the daemon told its own starvation from a silent device: informative). Exit 0
when every run is clean. On a shared machine the load comes from the hogs and from everything else running.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bracketry.testing.soak import parse_rig_bench_args, run_soak_process, soak_argv


def start_hogs(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
            for _ in range(n)]


def end_hogs(hogs: list[subprocess.Popen]) -> None:
    for p in hogs:  # by PID, only the processes this script started
        p.terminate()
    for p in hogs:
        p.wait(timeout=10)


def run_once(out: Path, seconds: float, hogs: int, fps: float, resolution: str) -> dict[str, Any]:
    result_path = out / "result.json"
    argv = soak_argv(out, result_path, "--seconds", f"{seconds:g}", "--fps", f"{fps:g}", "--resolution", resolution,
                     "--quiet")
    procs = start_hogs(hogs)
    try:
        exit_code, load1 = run_soak_process(argv, out / "soak.log", 5.0)
    finally:
        end_hogs(procs)
    result = json.loads(result_path.read_text()) if result_path.exists() else {"error": "no result"}
    result["load1"] = load1
    result["exit_code"] = exit_code
    return result


def row(k: int, hogs: int, r: dict[str, Any]) -> dict[str, Any]:
    kinds: dict[str, int] = {}
    for v in r.get("verify", []):
        for kind, n in v["kinds"].items():
            kinds[kind] = kinds.get(kind, 0) + n
    sides = r.get("sides", {})
    counters = r.get("daemon_counters", {})
    segments = len(r.get("verify", []))
    return {"run": k, "hogs": hogs, "load1": r["load1"], "pulses": sum(v["events"] for v in r.get("verify", [])),
            "frames_l": sides.get("left", {}).get("recorded", 0), "frames_r": sides.get("right", {}).get("recorded", 0),
            "drops": kinds.get("drops", 0), "mismatches": kinds.get("timestamp_mismatches", 0),
            "unpaired": kinds.get("unpaired", 0),
            "faults": len(r.get("false_faults", [])) + max(0, segments - 1),
            "lost_sw_triggers": kinds.get("lost_triggers", 0),
            "not_recorded": sum(s.get("unaccounted", 0) for s in sides.values()),
            "starved": counters.get("daemon_starved", 0), "error": r.get("error", "")}


COLUMNS = ("run", "hogs", "load1", "pulses", "frames_l", "frames_r", "drops", "mismatches", "unpaired", "faults",
           "lost_sw_triggers", "not_recorded", "starved")
MUST_BE_ZERO = ("drops", "mismatches", "unpaired", "faults", "lost_sw_triggers", "not_recorded")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--hogs", type=int, default=4)
    args = parse_rig_bench_args(ap, "keep each run's folder under this one")
    if args is None:
        return 2
    base = args.keep or Path(tempfile.mkdtemp(prefix="bench_record_load-"))
    rows = []
    print(f"{args.runs} runs of {args.seconds:g} s at {args.fps:g} fps ({args.resolution}) beside {args.hogs} busy "
          f"loops; folders under {base}", flush=True)
    print(" ".join(f"{c:>16}" if c == "lost_sw_triggers" else f"{c:>10}" for c in COLUMNS), flush=True)
    t0 = time.monotonic()
    for k in range(1, args.runs + 1):
        out = base / f"run{k}"
        out.mkdir(parents=True, exist_ok=True)
        r = row(k, args.hogs, run_once(out, args.seconds, args.hogs, args.fps, args.resolution))
        rows.append(r)
        cells = [f"{r[c]:>10.1f}" if c == "load1" else (f"{r[c]:>16}" if c == "lost_sw_triggers" else f"{r[c]:>10}")
                 for c in COLUMNS]
        print(" ".join(cells) + (f"  ERROR {r['error']}" if r["error"] else ""), flush=True)
    clean = all(not r["error"] and all(r[c] == 0 for c in MUST_BE_ZERO) for r in rows)
    print(f"{'clean' if clean else 'NOT CLEAN'}: {sum(r['pulses'] for r in rows)} pulses in {len(rows)} runs, "
          f"{time.monotonic() - t0:.0f} s")
    return 0 if clean else 1


if __name__ == "__main__":
    sys.exit(main())
