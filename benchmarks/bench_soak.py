"""Soak: the simulated rig records for a long time with seeded faults; every frame accounted for, every recording
verifying.

Usage: .venv/bin/python benchmarks/bench_soak.py [--minutes 30] [--seed 0] [--faults all] [--gap-s 20,40]

One run of ``bracketry.testing.soak`` (in a private network and mount namespace; the recording disk a
``--tmpfs-mb`` tmpfs): the whole simulated rig records ``--minutes`` through its panel buttons while, in a seeded
order and after seeded stretches of ``--gap-s`` seconds, the faults hit it: cable pulls, serial garbage on the
trigger's line, a full disk, SIGKILL of the recorder (the daemon), a camera restart. Printed: the faults injected,
per camera the frames the fake served, recorded, lost inside a fault's window (served up to 2 s before the fault
began and until the rig recorded again) and unaccounted; the recordings: how many, how many verify clean, truncated
ones whose repaired copy verifies, and problems no fault explains (timestamp mismatches, lost software triggers,
bracket-order breaks, ... anywhere; any problem in a recording no fault closed); the false faults (a sensor seen out
of REC while no fault was under way). Exit 0 when nothing is unaccounted or unexplained and no false fault was seen.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from bracketry.testing.soak import FAULTS, parse_rig_bench_args, run_soak_process, soak_argv


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=30.0, help="recording time, faults included")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--faults", default="all", help=f"comma-separated of {','.join(FAULTS)}, or all")
    ap.add_argument("--gap-s", default="20,40", help="seconds of recording before each fault: min,max")
    ap.add_argument("--tmpfs-mb", type=int, default=512, help="size of the recording disk (a tmpfs)")
    args = parse_rig_bench_args(ap, "keep the run's folder here")
    if args is None:
        return 2
    faults = ",".join(FAULTS) if args.faults == "all" else args.faults
    out = args.keep or Path(tempfile.mkdtemp(prefix="bench_soak-"))
    out.mkdir(parents=True, exist_ok=True)
    result_path = out / "result.json"
    argv = soak_argv(out, result_path, "--seconds", f"{args.minutes * 60:g}", "--faults", faults, "--seed",
                     str(args.seed), "--gap-s", args.gap_s, "--fps", f"{args.fps:g}", "--resolution",
                     args.resolution, "--quiet", tmpfs_mb=args.tmpfs_mb)
    print(f"soak: {args.minutes:g} min at {args.fps:g} fps ({args.resolution}), faults {faults}, seed {args.seed}; "
          f"folder {out}", flush=True)
    _, load1 = run_soak_process(argv, out / "soak.log", 10.0,
                                lambda elapsed_s: print(f"  {elapsed_s:6.0f} s", flush=True))
    if not result_path.exists():
        print(f"error: the soak wrote no result (see {out}/soak.log)", file=sys.stderr)
        return 1
    r = json.loads(result_path.read_text())
    print(f"runtime {r.get('runtime_s')} s, mean load1 {load1:.1f}")
    if r.get("error"):
        print(f"ERROR: {r['error']}")
    print("faults injected: " + ", ".join(f"{k} {n}" for k, n in sorted(r.get("faults", {}).items())))
    print(f"{'camera':>8} {'served':>8} {'recorded':>9} {'in_fault':>9} {'unaccounted':>12} {'not_served':>11} "
          f"{'twice':>6} {'unstamped':>10}")
    sides = r.get("sides", {})
    for side, c in sides.items():
        print(f"{side:>8} {c['served']:>8} {c['recorded']:>9} {c['in_fault_window']:>9} {c['unaccounted']:>12} "
              f"{c['not_served']:>11} {c['recorded_twice']:>6} {c.get('unstamped', 0):>10}")
    verified = r.get("verify", [])
    clean = sum(1 for v in verified if v["ok"])
    truncated = [v for v in verified if v["truncated"]]
    repaired = sum(1 for v in truncated if v.get("repaired_readable"))
    unreadable = sum(1 for v in verified if not v["readable"])
    print(f"recordings {len(verified)}: clean {clean}, truncated {len(truncated)} (repaired copy verifies: "
          f"{repaired}), unreadable {unreadable}")
    for v in verified:
        if v["kinds"]:
            print(f"  {Path(v['recording']).parent.name}/{Path(v['recording']).name}: {v['kinds']}")
    unexplained = r.get("unexplained", [])
    print(f"unexplained problems: {unexplained if unexplained else 'none'}")
    false_faults = r.get("false_faults", [])
    print(f"false faults: {len(false_faults)} of {r.get('polls', 0)} polls"
          + (f" (first: {false_faults[0]})" if false_faults else ""))
    ok = (not r.get("error") and not unexplained and not false_faults and unreadable == 0
          and len(truncated) == repaired and all(c["unaccounted"] == 0 and c["not_served"] == 0
                                                 for c in sides.values()))
    print("soak: OK" if ok else "soak: NOT OK")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
