"""What each ``bracketry emulate --png-compression`` choice costs: time to encode and write one image, and its size;
and what reading a bracket PNG costs: our decoder against OpenCV and Pillow.

Usage:
    .venv/bin/python benchmarks/bench_png_compression.py [IMAGES_DIR] [--images N] [--repeats R]

IMAGES_DIR: a folder of 16-bit PNGs (e.g. ``<emulate out>/<method>/images_left``); default: images emulated at 8 ms
from the real BorealHDR sample's first sequences (1920x1200, 12-bit). Each image is written ``--repeats`` times with
every choice, one after the other (the same images, side by side); it prints the median ms per image (encode + write
to a temporary folder on this disk) and the median MB per image, and checks that every file decodes (OpenCV) to the
exact codes. ``stored`` is timed twice: as ``write_png`` writes it now (the compiled encoder, the file written in
pieces) and as it did before (``stored-before``: Python's zlib, one write() of the whole file; the same bytes,
checked).

Decoding: the real sample's bracket PNGs (1920x1200, 16-bit, as the cameras and the synthetic worlds write them),
each read ``--repeats`` times by every decoder in turn, into a frame buffer as ``bracketry emulate`` does: ours
(``read_png12`` into the buffer's slot), ``cv2.imread`` + copy into the slot (before), Pillow + copy. Medians per
image and the ratios; every decoder's pixels are checked equal.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from bracketry_base import paths
from bracketry_emulator.dataset import imageio
from bracketry_emulator.emulation.writer import PNG_COMPRESSIONS, WRITE_PIECE_BYTES, encode_png, write_png
from bracketry_emulator.extensions import extensions_disabled


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


def write_stored_before(path: Path, image: np.ndarray) -> None:
    """The ``stored`` PNG as it was written before the compiled encoder: Python's zlib, then one write() of the
    whole file (the same bytes)."""
    with extensions_disabled():
        path.write_bytes(encode_png(image, "stored"))


def bench_decode(repeats: int) -> None:
    """Median ms to read one real bracket PNG into a frame buffer slot: ours, OpenCV, Pillow."""
    from PIL import Image

    seq_dir = paths.sample_sequence_dir()
    if seq_dir is None:
        print("decode: no BorealHDR sample (../shared/data/borealhdr_sample or $BRACKETRY_SAMPLE_DATA): skipped")
        return
    if imageio.png_decoder() is None:
        raise SystemExit("the _pngcodec extension is not built (./setup.sh builds it)")
    files = sorted(seq_dir.rglob("*.png"))
    slot = np.empty(cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED).shape, np.uint16)

    def ours(f: Path) -> None:
        imageio.read_png12(f, slot)

    def opencv(f: Path) -> None:
        slot[...] = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)

    def pillow(f: Path) -> None:
        with Image.open(f) as im:
            slot[...] = np.asarray(im)

    decoders = {"ours (read_png12)": ours, "cv2.imread + copy": opencv, "Pillow + copy": pillow}
    times: dict[str, list[float]] = {d: [] for d in decoders}
    for _ in range(repeats):
        for f in files:
            ref = None
            for name, fn in decoders.items():
                t0 = time.perf_counter()
                fn(f)
                times[name].append(time.perf_counter() - t0)
                if ref is None:
                    ref = slot.copy()
                elif not np.array_equal(slot, ref):
                    raise SystemExit(f"{name}: other pixels than ours for {f}")
    h, w = slot.shape
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"decode one {w}x{h} 16-bit bracket PNG into a frame buffer ({len(files)} files x {repeats} repeats, "
          "medians):")
    ms = {d: 1000 * statistics.median(t) for d, t in times.items()}
    base = ms["ours (read_png12)"]
    for d, v in ms.items():
        print(f"{d:<20} {v:7.1f} ms  {v / base:5.2f}x ours")


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
    choices = ("stored", "stored-before", *PNG_COMPRESSIONS[1:])
    times: dict[str, list[float]] = {c: [] for c in choices}
    sizes: dict[str, list[int]] = {c: [] for c in choices}
    with tempfile.TemporaryDirectory(prefix="bench-png-") as tmp:
        for _ in range(args.repeats):
            for k, img in enumerate(images):
                for c in choices:
                    path = Path(tmp) / f"{c}-{k}.png"
                    path.unlink(missing_ok=True)
                    t0 = time.perf_counter()
                    write_stored_before(path, img) if c == "stored-before" else write_png(path, img, c)
                    times[c].append(time.perf_counter() - t0)
                    sizes[c].append(path.stat().st_size)
                    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
                    if back is None or not np.array_equal(back, img):
                        raise SystemExit(f"{c}: the PNG does not decode to the written codes")
                if (Path(tmp) / f"stored-{k}.png").read_bytes() != (Path(tmp) / f"stored-before-{k}.png").read_bytes():
                    raise SystemExit("the compiled stored encoder and the zlib route wrote different bytes")
    h, w = images[0].shape
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{len(images)} images {w}x{h} 12-bit, {args.repeats} repeats, encode + write, medians:")
    print(f"{'choice':<12} {'ms/image':>9} {'MB/image':>9}")
    for c in choices:
        print(f"{c:<12} {1000 * statistics.median(times[c]):9.1f} {statistics.median(sizes[c]) / 1e6:9.2f}")
    before, after = statistics.median(times["stored-before"]), statistics.median(times["stored"])
    print(f"stored: now (compiled encoder, writes of {WRITE_PIECE_BYTES >> 10} KB) {1000 * after:.1f} ms vs before "
          f"(zlib, one write) {1000 * before:.1f} ms per image: {before / after:.2f}x")
    bench_decode(args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
