"""Closed-loop replay, whole processes side by side in one run: the authors' ``emulator_threads.py`` itself vs
``bracketry emulate``, the same 7 methods, both cameras, 12-bit PNG outputs, on the real BorealHDR sample.

Usage:
    BRACKETRY_BOREALHDR_CODE=/path/to/BorealHDR [BRACKETRY_BOREALHDR_PYTHON=/path/to/their/venv/bin/python] \\
        .venv/bin/python benchmarks/bench_authors_emulate.py [--repeats N]

``BRACKETRY_BOREALHDR_CODE`` is a checkout of norlab-ulaval/BorealHDR (branch TFR2024: ``scripts/emulator_threads.py``,
``parameters.yaml``, ``calibration_files/``), never committed here and never downloaded by this script;
``BRACKETRY_BOREALHDR_PYTHON`` an interpreter with its requirements.txt installed (default: this one); their script
selects matplotlib's TkAgg backend, so without ``$DISPLAY`` it runs under ``xvfb-run`` (Debian xvfb). Each repeat
runs, as separate processes, the authors' script (methods classical-30/50/70, fixed-0, shim-0, kim-0, zhang-0, their
initial 4 ms, saving images) and ``bracketry emulate -m fix,ae30,ae50,ae70,shim,kim,zhang --parity upstream`` (PNGs of
both cameras, depth 12); it prints the median wall time of each, per (method, stereo step), and the ratio, and the
CPU time (user + system of the process and its children) of each with its ratio, and the load average around each
run: on a shared machine the wall-time ratio moves with the other jobs' load, the CPU-time ratio much less.
Before each timed process the page cache is flushed (``os.sync``), so neither side pays for the other's writes.

Without ``BRACKETRY_BOREALHDR_CODE`` it says so and runs ``bench_ae.py``, the RE-IMPLEMENTATION of the authors'
architecture, as a clearly labelled fallback.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import runpy
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bracketry_base import paths

CODE_ENV = "BRACKETRY_BOREALHDR_CODE"
PYTHON_ENV = "BRACKETRY_BOREALHDR_PYTHON"
AUTHORS_METHODS = ["classical-30", "classical-50", "classical-70", "fixed-0", "shim-0", "kim-0", "zhang-0"]
OUR_METHODS = "fix,ae30,ae50,ae70,shim,kim,zhang"


def timed(cmd: list[str], cwd: Path | None = None) -> tuple[float, float]:
    """(wall s, CPU s = user + system of the process and everything it waited for) of one whole process (its
    output kept out of ours; a failure stops the benchmark). The files the previous run wrote are flushed to disk
    first (``os.sync``, untimed): each side starts without the other's writeback (each writes 0.7-1 GB of PNGs)."""
    os.sync()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, cwd=cwd, stdin=subprocess.DEVNULL, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise SystemExit(f"failed ({res.returncode}): {' '.join(cmd)}\n{res.stderr[-2000:]}")
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def load() -> str:
    """The 1-minute load average (this machine's other jobs)."""
    return f"{os.getloadavg()[0]:.1f}"


def count_pngs(folder: Path) -> int:
    return sum(1 for _ in folder.rglob("*.png"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--dataset", type=Path, default=None,
                    help="A BorealHDR recording folder (camera_left/<ms>/..., e.g. from bracketry synth trajectory); "
                         "default: the real sample's")
    args = ap.parse_args()
    code = os.environ.get(CODE_ENV)
    if not code:
        print(f"{CODE_ENV} is not set: the authors' script is not available, so this runs the RE-IMPLEMENTATION of "
              "their architecture (benchmarks/bench_ae.py) instead; its ratio is not a measurement of their script.\n")
        sys.argv = [str(Path(__file__).with_name("bench_ae.py"))]
        runpy.run_path(sys.argv[0], run_name="__main__")
        return 0
    script = Path(code) / "scripts" / "emulator_threads.py"
    if not script.is_file():
        raise SystemExit(f"{CODE_ENV}={code}: no scripts/emulator_threads.py there (a BorealHDR TFR2024 checkout?)")
    python = os.environ.get(PYTHON_ENV) or sys.executable
    pcalib = Path(code) / "calibration_files" / "pcalib_inside1.txt"  # the response their script uses
    seq = args.dataset.resolve() if args.dataset is not None else paths.sample_sequence_dir()
    if seq is None or not (seq / "camera_left").is_dir():
        raise SystemExit("no dataset: the BorealHDR sample not found (../shared/data/borealhdr_sample or "
                         "$BRACKETRY_SAMPLE_DATA) or --dataset without camera_left/")
    bracketry = Path(sys.executable).with_name("bracketry")
    # their script selects matplotlib's TkAgg backend: without a display it runs under a private X server
    xvfb = ["xvfb-run", "-a"] if not os.environ.get("DISPLAY") and shutil.which("xvfb-run") else []
    authors_s: list[float] = []
    ours_s: list[float] = []
    authors_cpu: list[float] = []
    ours_cpu: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-authors-") as tmp:
        t = Path(tmp)
        for r in range(args.repeats):
            a_out, o_out = t / f"authors{r}", t / f"ours{r}"
            load_a = load()
            wall, cpu = timed([*xvfb, python, str(script), "--dataset_folder", str(seq.parent), "--experiment",
                               seq.name, "--save_path", str(a_out), "--exposure_time_init", "4.0",
                               "--automatic_exposure_techniques", *AUTHORS_METHODS], cwd=script.parent)
            authors_s.append(wall)
            authors_cpu.append(cpu)
            load_o = load()
            wall, cpu = timed([str(bracketry), "emulate", str(seq), "-m", OUR_METHODS, "--parity", "upstream",
                               "--crf", str(pcalib),
                               "--init-exposure-ms", "4", "--depth", "12", "-o", str(o_out), "--overwrite", "-q"])
            ours_s.append(wall)
            ours_cpu.append(cpu)
            n_seq = json.loads((o_out / "summary.json").read_text())["sequences"]
            print(f"repeat {r + 1}/{args.repeats}: authors' emulator_threads.py {authors_s[-1]:.1f} s, CPU "
                  f"{authors_cpu[-1]:.1f} s ({count_pngs(a_out)} PNGs, load {load_a}); bracketry emulate "
                  f"{ours_s[-1]:.1f} s, CPU {ours_cpu[-1]:.1f} s ({count_pngs(o_out)} PNGs, load {load_o}, then "
                  f"{load()}); ratio {authors_s[-1] / ours_s[-1]:.1f}x", flush=True)
            if r + 1 < args.repeats:
                shutil.rmtree(a_out, ignore_errors=True)
                shutil.rmtree(o_out, ignore_errors=True)
    steps = 7 * n_seq
    ma, mo = statistics.median(authors_s), statistics.median(ours_s)
    print(f"\nworkload: 7 methods x {n_seq} bracket sequences x 2 cameras, 12-bit PNGs, whole processes "
          f"({seq})")
    print(f"authors' emulator_threads.py (their code, {python}): median {ma:.1f} s = {ma / steps:.3f} s per "
          f"(method, stereo step)")
    print(f"bracketry emulate:                                 median {mo:.1f} s = {mo / steps:.3f} s per "
          f"(method, stereo step)")
    print(f"ratio: {ma / mo:.1f}x (medians of {args.repeats} runs each, side by side)")
    ca, co = statistics.median(authors_cpu), statistics.median(ours_cpu)
    print(f"CPU time (user + system): authors' median {ca:.1f} s, bracketry emulate median {co:.1f} s, "
          f"ratio {ca / co:.1f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
