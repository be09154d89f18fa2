"""AE methods in closed loop, end to end: our runner vs the authors' architecture, side by side in one run.

Usage: .venv/bin/python benchmarks/bench_ae.py [--quick] [--repeats N]

Workload: the 8 paper methods (fix, ae30, ae50, ae70, shim, wang, kim, drl) in closed loop on the real BorealHDR
sample (both cameras, every complete bracket sequence, 16-bit PNG outputs at depth 12). DRL uses a seeded randomly
initialised actor written to a temporary .pth (the public weights are not shipped; the cost is the same).

- ours: ``run_methods`` with its default ``workers=0`` (auto, as ``bracketry emulate``): on this short sample one
  process, each needed bracket decoded once on 2 threads, LUT emulation, identical emulations shared, stored PNGs
  written on 2 threads (``--workers 2`` forces 2 forked worker processes);
- authors' architecture, re-implemented: one thread per method; each thread, at every step, re-decodes the 6
  brackets of both cameras (cv2.imread), computes their saturation, selects with closer_least_sat, emulates with the
  authors' per-pixel interp1d formula (their pcalib), writes both 16-bit PNGs with cv2.imwrite, then runs the SAME
  AE method objects on the left image (Shim, Kim, Wang on the full-resolution gray image as the authors; ours
  work at 480 columns, a documented deviation); exposure_times.png is plotted at the end. A second baseline keeps our
  480-column methods, so that ratio isolates the architecture. The authors' own Shim, Kim and Zhang are slower per
  call still (0.5 s, 0.35 s, 1 s measured with their code), so both ratios are lower bounds.

Prints the end-to-end wall time (median over repeats), the ratio, and each method's AE cost per step.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2

from bracketry_base import paths
from bracketry_emulator.ae import get_method, run_methods
from bracketry_emulator.ae.drl import save_random_actor
from bracketry_emulator.crf import load_pcalib
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation.reference import UpstreamFormula, closer_least_sat, upstream_saturation
from bracketry_emulator.runtime_policy import apply_profile

METHODS = ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl"]


def authors_architecture(dataset: Path, pcalib: Path, out: Path, methods: list[str], weights: str,
                         n_seq: int, full_resolution: bool = True) -> dict[str, list[float]]:
    """One thread per method, each re-decoding every PNG it needs at every step (see the module docstring)."""
    ds = open_dataset(dataset)
    seqs = ds.sequences()[:n_seq]
    formula = UpstreamFormula(load_pcalib(pcalib))
    results: dict[str, list[float]] = {}
    errors: list[BaseException] = []

    def one(method_id: str) -> None:
        try:
            method = get_method(method_id, drl_weights=weights)
            if full_resolution and hasattr(method, "work_width"):
                method.work_width = 0  # the authors run Shim, Kim, Wang on the full-resolution gray image
            method.reset(4000.0)
            t_ms = 4.0
            traj = []
            folder = out / method_id
            for side in ("left", "right"):
                (folder / f"images_{side}").mkdir(parents=True, exist_ok=True)
            for step, seq in enumerate(seqs):
                traj.append(t_ms)
                emulated = {}
                for side in ("left", "right"):
                    exps = list(seq.exposures_us)
                    imgs = [cv2.imread(seq.frames[side][e].source, cv2.IMREAD_ANYDEPTH) for e in exps]
                    sat = [upstream_saturation(im) for im in imgs]
                    brackets_ms = [e / 1000.0 for e in exps]
                    src_ms = closer_least_sat(brackets_ms, sat, t_ms)
                    i = brackets_ms.index(src_ms)
                    img = formula.radiance_emulation(imgs[i], t_ms, src_ms)
                    ts = seq.timestamps_ns[side][exps[i]]
                    cv2.imwrite(str(folder / f"images_{side}" / f"{ts}.png"), img)
                    with open(folder / f"times_images_{side}.txt", "a") as f:
                        f.write(f"{ts} {ts} {t_ms}\n")
                    emulated[side] = img
                t_ms = method.next_exposure_us(emulated["left"], t_ms * 1000.0, {"step": step}) / 1000.0
            results[method_id] = traj
        except BaseException as exc:  # surfaced after join
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(m,)) for m in methods]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    if errors:
        raise errors[0]
    # the authors' final exposure_times.png (same plotting helper as ours)
    from bracketry_emulator.ae.plot import plot_exposures

    plot_exposures({m: (list(range(len(t))), t) for m, t in results.items()}, out / "exposure_times.png")
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 sequences, 1 repeat")
    parser.add_argument("--repeats", type=int, default=None)
    parser.add_argument("--workers", type=int, default=0, help="ours: worker processes (0 = auto, the default)")
    args = parser.parse_args()
    root = paths.sample_data_dir()
    if root is None:
        print("BorealHDR sample not found (../shared/data/borealhdr_sample or $BRACKETRY_SAMPLE_DATA)")
        return 1
    dataset = next(c for c in sorted(root.iterdir()) if (c / "camera_left").is_dir())
    pcalib = root / "calibration" / "pcalib_inside1.txt"
    n_all = len(open_dataset(dataset).sequences())
    n_seq = 2 if args.quick else n_all
    repeats = args.repeats or (1 if args.quick else 2)
    apply_profile("timing")
    tmp = Path(tempfile.mkdtemp(prefix="bench_ae_"))
    try:
        weights = str(save_random_actor(tmp / "actor.pth", seed=0))
        get_method("drl", drl_weights=weights)  # warm the torch import for both sides
        base_s, base_same_s, ours_s = [], [], []
        ours_summary = None
        for r in range(repeats):
            out_b = tmp / f"authors{r}"
            t0 = time.perf_counter()
            authors_architecture(dataset, pcalib, out_b, METHODS, weights, n_seq)
            base_s.append(time.perf_counter() - t0)
            shutil.rmtree(out_b, ignore_errors=True)
            t0 = time.perf_counter()
            authors_architecture(dataset, pcalib, out_b, METHODS, weights, n_seq, full_resolution=False)
            base_same_s.append(time.perf_counter() - t0)
            shutil.rmtree(out_b, ignore_errors=True)
            out_o = tmp / f"ours{r}"
            t0 = time.perf_counter()
            ours_summary = run_methods(dataset, METHODS, out_o, workers=args.workers, progress=False,
                                       drl_weights=weights, max_sequences=n_seq)
            ours_s.append(time.perf_counter() - t0)
            shutil.rmtree(out_o, ignore_errors=True)
            print(f"repeat {r + 1}/{repeats}: authors' architecture {base_s[-1]:.2f} s (same AE resolution as ours "
                  f"{base_same_s[-1]:.2f} s), ours {ours_s[-1]:.2f} s", flush=True)
        t0 = time.perf_counter()
        no_img = run_methods(dataset, METHODS, tmp / "noimg", workers=args.workers, progress=False,
                             drl_weights=weights, max_sequences=n_seq, write_images=False)
        noimg_s = time.perf_counter() - t0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    mb, mo = statistics.median(base_s), statistics.median(ours_s)
    mbs = statistics.median(base_same_s)
    n_img = len(METHODS) * n_seq * 2
    print(f"\nworkload: {len(METHODS)} methods x {n_seq} sequences x 2 cameras = {n_img} emulated images "
          f"(1920x1200), repeats {repeats}")
    print(f"authors' architecture (thread per method, re-decode, interp1d): median {mb:.2f} s "
          f"({1e3 * mb / n_img:.0f} ms per image)")
    mode = "auto" if args.workers == 0 else f"{args.workers} processes"
    print(f"ours (decode once, LUT, workers {mode}):               median {mo:.2f} s "
          f"({1e3 * mo / n_img:.0f} ms per image)")
    print(f"  same, with our 480-column AE methods (architecture only): median {mbs:.2f} s")
    print(f"speed-up end to end: {mb / mo:.1f}x vs the authors' setup, {mbs / mo:.1f}x architecture only "
          f"(goal >= 20x)")
    print(f"ours without writing images (exposure trajectories only): {noimg_s:.2f} s -> {mb / noimg_s:.1f}x")
    assert ours_summary is not None
    print("\nAE cost per step (ms, median over the run, measured inside our run):")
    for name, run in ours_summary.runs.items():
        s = run.summary()
        print(f"  {name:<6} {s['ae_ms_per_step']['median']:8.1f}   exposures ms: "
              + " ".join(f"{e:.2f}" for e in run.exposures_ms))
    del no_img
    return 0


if __name__ == "__main__":
    sys.exit(main())
