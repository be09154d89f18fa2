"""What each ``bracketry emulate --png-compression`` choice costs: time to encode and write one image, and its size.

Usage:
    .venv/bin/python benchmarks/bench_png_compression.py [IMAGES_DIR] [--images N] [--repeats R]

IMAGES_DIR: a folder of 16-bit PNGs (e.g. ``<emulate out>/<method>/images_left``); default: images emulated at 8 ms
from the real BorealHDR sample's first sequences (1920x1200, 12-bit). Each image is written ``--repeats`` times with
every choice, one after the other (the same images, side by side); it prints the median ms per image (encode + write
to a temporary folder on this disk) and the median MB per image, and checks that every file decodes (OpenCV) to the
exact codes.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bracketry import paths
from bracketry_emulator.emulation.writer import PNG_COMPRESSIONS, write_png


def sample_images(n: int) -> list[np.ndarray]:
    from bracketry_emulator.dataset import open_dataset
    from bracketry_emulator.emulation import Emulator, EmulatorConfig

    seq_dir = paths.sample_sequence_dir()
    if seq_dir is None:
        raise SystemExit("no IMAGES_DIR and no BorealHDR sample (../shared/data/borealhdr_sample or "
                         "$BRACKETRY_SAMPLE_DATA)")
    emu = Emulator(EmulatorConfig())
    out: list[np.ndarray] = []
    for seq in open_dataset(seq_dir).sequences():
        for side in seq.sides:
            out.append(emu.emulate(seq.load(side), 8000.0).image)
            if len(out) == n:
                return out
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("images_dir", nargs="?", type=Path, default=None)
    ap.add_argument("--images", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    images: list[np.ndarray] = []
    if args.images_dir is not None:
        for f in sorted(args.images_dir.glob("*.png"))[: args.images]:
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if img is None or img.dtype != np.uint16 or img.ndim != 2:
                raise SystemExit(f"{f}: not a 16-bit gray PNG")
            images.append(np.asarray(img))
        if not images:
            raise SystemExit(f"{args.images_dir}: no PNGs")
    else:
        images = sample_images(args.images)
    times: dict[str, list[float]] = {c: [] for c in PNG_COMPRESSIONS}
    sizes: dict[str, list[int]] = {c: [] for c in PNG_COMPRESSIONS}
    with tempfile.TemporaryDirectory(prefix="bench-png-") as tmp:
        for _ in range(args.repeats):
            for k, img in enumerate(images):
                for c in PNG_COMPRESSIONS:
                    path = Path(tmp) / f"{c}-{k}.png"
                    path.unlink(missing_ok=True)
                    t0 = time.perf_counter()
                    write_png(path, img, c)
                    times[c].append(time.perf_counter() - t0)
                    sizes[c].append(path.stat().st_size)
                    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
                    if back is None or not np.array_equal(back, img):
                        raise SystemExit(f"{c}: the PNG does not decode to the written codes")
    h, w = images[0].shape
    print(f"{len(images)} images {w}x{h} 12-bit, {args.repeats} repeats, encode + write, medians:")
    print(f"{'choice':<8} {'ms/image':>9} {'MB/image':>9}")
    for c in PNG_COMPRESSIONS:
        print(f"{c:<8} {1000 * statistics.median(times[c]):9.1f} {statistics.median(sizes[c]) / 1e6:9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
