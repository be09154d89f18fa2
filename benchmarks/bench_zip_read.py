"""Reading a trajectory from its zip in place against reading the unpacked folder (issue 42: within 10 %).

Usage:
    .venv/bin/python benchmarks/bench_zip_read.py [TRAJECTORY_DIR] [--repeats R]

TRAJECTORY_DIR: a trajectory folder (default: the real BorealHDR sample's root, ``calibration/`` beside its recording
folder). It is zipped twice into a temporary folder, with the PNGs stored and deflated (as an archiver may hold
them). Each repeat reads the three, one after the other in a rotating order: ``open_dataset`` then every bracket of
every complete sequence, both cameras, decoded into one frame buffer (``Frame.load_into``, as the closed loops
read them). Prints per source the median and min wall seconds over the repeats, per frame, the ratio of the
zip's median to the folder's, and the same for the CPU seconds of the process (the figure to read on a shared
machine). The files are read from the page cache (each is read once before timing), so the
figure is the reader's cost, not the disk's. The pixels of every source are checked equal once.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from bracketry_base import paths
from bracketry_emulator.dataset import open_dataset


def zip_folder(folder: Path, archive: Path, compression: int) -> Path:
    """Every file under ``folder`` into ``archive``, inside one top-level folder named as ``folder``."""
    with zipfile.ZipFile(archive, "w", compression=compression) as zf:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                zf.write(f, f"{folder.name}/{f.relative_to(folder).as_posix()}")
    return archive


def read_all(source: Path) -> tuple[float, float, int, int]:
    """(wall seconds, CPU seconds of this process, frames read, checksum) of opening ``source`` and decoding every
    bracket of every sequence."""
    t0, c0 = time.perf_counter(), time.process_time()
    ds = open_dataset(source)
    n, total = 0, 0
    buf: np.ndarray | None = None
    for seq in ds.sequences():
        for side in ds.sides:
            for exp in seq.exposures_us:
                frame = seq.frames[side][exp]
                if buf is None:
                    buf = frame.load().copy()
                else:
                    img = frame.load_into(buf)
                    if img is not buf:
                        buf = img.copy()
                total += int(buf[::97, ::89].sum())
                n += 1
    return time.perf_counter() - t0, time.process_time() - c0, n, total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trajectory", nargs="?", type=Path, default=None)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    folder = args.trajectory or paths.sample_data_dir()
    if folder is None:
        raise SystemExit("no TRAJECTORY_DIR and no BorealHDR sample (../shared/data/borealhdr_sample or "
                         "$BRACKETRY_SAMPLE_DATA)")
    with tempfile.TemporaryDirectory() as tmp:
        sources = {"folder": folder,
                   "zip (stored)": zip_folder(folder, Path(tmp) / "stored.zip", zipfile.ZIP_STORED),
                   "zip (deflated)": zip_folder(folder, Path(tmp) / "deflated.zip", zipfile.ZIP_DEFLATED)}
        checks = {name: read_all(src) for name, src in sources.items()}  # warms the page cache; the same pixels?
        if len({(n, s) for _, _, n, s in checks.values()}) != 1:
            raise SystemExit(f"the sources differ: {checks}")
        n_frames = checks["folder"][2]
        wall: dict[str, list[float]] = {name: [] for name in sources}
        cpu: dict[str, list[float]] = {name: [] for name in sources}
        names = list(sources)
        for r in range(args.repeats):
            for name in names[r % len(names):] + names[: r % len(names)]:
                w, c, _, _ = read_all(sources[name])
                wall[name].append(w)
                cpu[name].append(c)
        w0, c0 = statistics.median(wall["folder"]), statistics.median(cpu["folder"])
        print(f"{folder}: {n_frames} frames (both cameras), {args.repeats} repeats, page cache warm")
        print(f"{'source':16s} {'wall median s':>14s} {'min s':>7s} {'ms/frame':>9s} {'ratio':>6s} "
              f"{'CPU median s':>13s} {'ratio':>6s}")
        for name in names:
            w, c = statistics.median(wall[name]), statistics.median(cpu[name])
            print(f"{name:16s} {w:14.3f} {min(wall[name]):7.3f} {1000 * w / n_frames:9.1f} {w / w0:6.3f} "
                  f"{c:13.3f} {c / c0:6.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
