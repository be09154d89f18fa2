"""Board capture from a recorded session folder, read as a live stream of stereo pairs (``bracketry calibrate
capture --from SESSION``)."""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_rig.boardcapture.files import check_png_sizes, image_pairs, read_image
from bracketry_rig.boardcapture.selection import Echo, FolderBackend, Selection, serve_monitor


def capture_folder(source: Path, out: Path, board: Any, board_yaml: str, *, max_blur_px: float = 2.5,
                   bayer: bool = True, monitor_port: int | None = None, rate_hz: float = 0.0, hold_s: float = 0.0,
                   echo: Echo = None) -> tuple[dict[str, Any], int]:
    """Offer the pairs of ``source`` in order (``rate_hz`` > 0: at that rate) to the selection; kept pairs are
    copied into ``out``. Returns the coverage status and the number of pairs read."""
    from bracketry_rig.monitor.calibration_feed import CaptureFeed

    pairs = image_pairs(source)
    first = read_image(pairs[0][0])
    size = (int(first.shape[1]), int(first.shape[0]))
    check_png_sizes(pairs, size)  # before anything is written
    feed = CaptureFeed(board, size, max_blur_px)
    server = serve_monitor(feed, FolderBackend(source), monitor_port) if monitor_port is not None else None
    if server is not None and echo is not None:
        echo(f"monitor: {server.url}")
    out.mkdir(exist_ok=True)
    sel = Selection(feed, board, out, bayer, echo)
    try:
        t_next = time.monotonic()
        for pair in pairs:
            imgs = (read_image(pair[0]), read_image(pair[1]))
            for p, img in zip(pair, imgs, strict=True):
                if (int(img.shape[1]), int(img.shape[0])) != size:
                    raise BracketryError(f"{p} is {img.shape[1]}x{img.shape[0]} but the stream is "
                                         f"{size[0]}x{size[1]}: a session's images must all have one size")

            def save(dest: Path, name: str, pair: tuple[Path, Path] = pair) -> None:
                for side, p in zip(("left", "right"), pair, strict=True):
                    shutil.copyfile(p, dest / side / name)

            sel.offer(pair[0].name, imgs, save)
            if rate_hz > 0:
                t_next += 1.0 / rate_hz
                time.sleep(max(0.0, t_next - time.monotonic()))
        status = sel.finish(board_yaml, {"source": str(source)})
        if server is not None and hold_s > 0:
            time.sleep(hold_s)
    finally:
        if server is not None:
            server.close()
    return status, len(pairs)
