"""Export a recording as a BorealHDR tree: ``camera_left|camera_right/<exposure_ms>/<timestamp_ns>.png``.

- ``<exposure_ms>`` is the commanded exposure (trigger pulse width) in milliseconds written as a float, e.g. ``1.0``,
  ``32.0``, ``0.025`` (the emulator parses folder names as floats);
- ``<timestamp_ns>`` is the frame time (the trigger start in host time, the Image header stamp), identical for the
  left and right frames of one trigger;
- pixels are the raw 12-bit Bayer codes, unshifted, in 16-bit single-channel PNGs (lossless).

A recording that carries a stereo calibration (the rig config's ``calibration``; RECORDING.md) gets it as the
tree's ``calibration/`` (``left.yaml``, ``right.yaml`` and the other files ``bracketry calibrate solve`` wrote, byte
for byte); one without gets no ``calibration/``.

Frames without pixels (incomplete) or without a TRIGGER event (unknown exposure) are not exported; they are counted.
PNG encoding runs in a thread pool (the encoders release the GIL) with a progress bar. ``png_compression`` chooses the
lossless encoding (:mod:`bracketry_base.png`, the choices of ``bracketry emulate --png-compression``): ``opencv``
(``cv2.imwrite``'s defaults, the default here), ``stored`` (no compression, zlib: ~3.5x faster to write at 640x400,
3.5 vs 12.6 ms an image, and ~1.4x larger, 2 bytes a pixel; the same bytes as the emulator's compiled encoder, which
the rig does not use), ``fast`` or ``small``; every choice reads back as exactly the recorded codes.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.png import PNG_COMPRESSIONS, write_png
from bracketry_base.recording import topics as T
from bracketry_base.recording.calibration import recorded_calibration, write_calibration
from bracketry_base.recording.decode import decode, decode_image_msg
from bracketry_base.recording.reader import RecordingReader
from bracketry_base.recording.verify import recording_files

#: the tree's calibration folder (emulator/DATASET.md), written from the calibration the recording carries
CALIBRATION_FOLDER = "calibration"


def exposure_folder(exposure_us: int) -> str:
    """Folder name of an exposure: milliseconds as a float (``1000`` -> ``1.0``, ``25`` -> ``0.025``)."""
    return repr(exposure_us / 1000.0)


@dataclass
class ExportSummary:
    written: dict[str, int] = field(default_factory=dict)
    skipped_no_event: int = 0
    skipped_no_pixels: int = 0
    #: frames whose partner of the other camera (same trigger) is missing from the recording
    unpaired: int = 0
    #: frames of a camera with the same time and exposure as one already exported (a camera that delivered two
    #: frames for one trigger): the first is kept
    duplicates: int = 0
    out_dir: str = ""
    #: the ``calibration/`` folder written from the calibration the recording carries (None: it carries none)
    calibration: str | None = None


def _write_png(path: Path, image: np.ndarray, compression: str) -> None:
    """The lossless PNG writer both packages share; its OSError as a one-line error."""
    try:
        write_png(path, image, compression)
    except OSError as exc:
        raise BracketryError(f"cannot write {path}: {exc.strerror or exc}") from exc


def export_borealhdr(recording: str | Path, out_dir: str | Path, *, workers: int = 2,
                     progress: bool = True, keep_unpaired: bool = False,
                     png_compression: str = "opencv") -> ExportSummary:
    """Export ``recording`` (file or folder of split files) under ``out_dir`` (created).

    In a stereo recording a frame whose partner of the other camera (same trigger) is missing is counted in
    ``unpaired`` and written only with ``keep_unpaired``, so a BorealHDR tree never holds half a pair silently.
    ``png_compression``: one of :data:`bracketry_base.png.PNG_COMPRESSIONS`.
    """
    try:
        import cv2  # noqa: F401
    except ImportError as exc:
        raise BracketryError("export needs OpenCV (pip install -e '.[host]')") from exc
    if png_compression not in PNG_COMPRESSIONS:
        raise BracketryError(f"unknown PNG compression {png_compression!r} (use {', '.join(PNG_COMPRESSIONS)})")
    out = Path(out_dir)
    files = recording_files(recording)
    summary = ExportSummary(out_dir=str(out))
    # pass 1 (one read of the chunks, images not decoded): the exposure of each trigger_seq from the events, the
    # trigger_seqs each side has a frame of
    exposures: dict[int, int] = {}
    total = 0
    image_topics = {T.image_topic(s): s for s in T.SIDES}
    seen: dict[str, set[int]] = {s: set() for s in T.SIDES}
    carried: dict[str, str] | None = None
    for path in files:
        reader = RecordingReader(path)
        for msg in reader.messages({T.TRIGGER_TOPIC, *image_topics}):
            if msg.topic == T.TRIGGER_TOPIC:
                ev = decode(msg.schema_name, msg.data)
                exposures[int(ev.trigger_seq)] = int(ev.exposure_us)
            else:
                seen[image_topics[msg.topic]].add(msg.sequence)
                total += 1
        carried = carried or recorded_calibration(reader.report.metadata)
    if carried is not None:
        summary.calibration = str(write_calibration(carried, out / CALIBRATION_FOLDER))
    stereo = all(seen[s] for s in T.SIDES)
    paired = set.intersection(*(seen[s] for s in T.SIDES)) if stereo else set()
    lock = threading.Lock()
    bar: Any = None
    if progress:
        from bracketry_base.progress import Progress

        bar = Progress("export", total=total, unit="img")
    made: set[Path] = set()
    written: set[Path] = set()

    def job(path: Path, image: np.ndarray, side: str) -> None:
        _write_png(path, image, png_compression)
        with lock:
            summary.written[side] = summary.written.get(side, 0) + 1
            if bar is not None:
                bar.update(1)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        futures = []
        for path in files:
            for msg in RecordingReader(path).messages(set(image_topics)):
                side = image_topics[msg.topic]
                if stereo and msg.sequence not in paired:
                    summary.unpaired += 1
                    if not keep_unpaired:
                        continue
                exposure = exposures.get(msg.sequence)
                if exposure is None:
                    summary.skipped_no_event += 1
                    continue
                img = decode_image_msg(msg.data)
                if img.image.dtype != np.uint16 or img.image.size == 0:
                    summary.skipped_no_pixels += 1
                    continue
                folder = out / f"camera_{side}" / exposure_folder(exposure)
                if folder not in made:
                    folder.mkdir(parents=True, exist_ok=True)
                    made.add(folder)
                target = folder / f"{img.stamp_ns}.png"
                if target in written:  # never two writes of one file (on threads: a corrupt PNG)
                    summary.duplicates += 1
                    continue
                written.add(target)
                futures.append(pool.submit(job, target, img.image, side))
                if len(futures) > 4 * workers:
                    futures.pop(0).result()
        for f in futures:
            f.result()
    if bar is not None:
        bar.close()
    return summary
