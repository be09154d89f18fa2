"""The capture's bookkeeping, whatever the stream: judge each stereo pair (board found in both images, sharp, not a
near-duplicate: ``bracketry_rig.monitor.calibration_feed.CaptureFeed``), save the kept ones, log every pair with why,
and the monitor page's backend while no rig daemon runs."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: a line of progress (the CLI prints it on stderr; None: quiet)
Echo = Callable[[str], None] | None


class FolderBackend:
    """The monitor's backend during a capture: no sensors to show or switch."""

    def __init__(self, source: Path, message: str | None = None) -> None:
        self.source = source
        self.message = message or f"board capture from {source.name}"

    def monitor_status(self) -> dict[str, Any]:
        free_mb = shutil.disk_usage(self.source).free // (1024 * 1024)
        return {"time_ns": time.time_ns(), "sensors": {}, "errors": {}, "cameras": {},
                "disk": {"free_mb": free_mb, "time_left_s": None},
                "recording": {"active": False, "name": None, "segment": 0, "seconds": 0},
                "message": self.message, "brackets_us": [], "fps_target": 0, "sensors_on": False}

    def monitor_action(self, action: str, body: dict[str, Any]) -> dict[str, Any]:
        from bracketry_rig.monitor.server import ActionError

        raise ActionError("no rig here: this page shows a board capture")

    def monitor_limits_us(self) -> tuple[tuple[int, ...], int, int]:
        return (), 1, 1


def serve_monitor(feed: Any, backend: FolderBackend, port: int) -> Any:
    """The monitor page with the capture's corners and coverage on 127.0.0.1:``port`` (0: any); ``close()`` it."""
    from bracketry_rig.monitor.hub import PreviewHub
    from bracketry_rig.monitor.server import MonitorServer

    return MonitorServer(backend, PreviewHub(), "127.0.0.1", port, calibration=feed).start()


class Selection:
    """Judge a pair, save it when kept, log it, report a line (``echo``)."""

    def __init__(self, feed: Any, board: Any, out: Path, bayer: bool, echo: Echo = None) -> None:
        self.feed, self.board, self.out, self.bayer, self.echo = feed, board, out, bayer, echo
        self.log: list[dict[str, Any]] = []
        for side in ("left", "right"):
            (out / side).mkdir(parents=True, exist_ok=True)

    def skip(self, name: str, why: str) -> None:
        """A pair that cannot be judged (incomplete, not one instant's): logged as not kept."""
        self.log.append({"pair": name, "kept": False, "why": why})

    def offer(self, name: str, imgs: tuple[Any, Any], save: Callable[[Path, str], None]) -> bool:
        """Judge the pair ``imgs`` (raw images); ``save(out, name)`` writes it when kept. Returns the set is
        enough."""
        from bracketry_base.calibration.detect import detect, to_gray8

        grays = (to_gray8(imgs[0], bayer=self.bayer), to_gray8(imgs[1], bayer=self.bayer))
        kept, why = self.feed.offer(grays, (detect(grays[0], self.board), detect(grays[1], self.board)))
        self.log.append({"pair": name, "kept": kept, "why": why})
        if kept:
            save(self.out, name)  # one name for both: solve pairs by name
        st = self.feed.coverage.status()
        if self.echo is not None:
            bars = " ".join(f"{k} {v:.0%}" for k, v in st["bars"].items())
            self.echo(f"{name}: {'kept' if kept else why}; {st['kept']} kept; {bars}")
        return bool(st["enough"])

    def finish(self, board_yaml: str, extra: dict[str, Any]) -> dict[str, Any]:
        """Write ``board.yaml`` and ``capture.json`` (every pair: kept or why not, with ``extra``); returns the
        coverage status (``kept``, ``enough``, ``advice``, ...)."""
        self.feed.finish()
        (self.out / "board.yaml").write_text(board_yaml)
        status: dict[str, Any] = self.feed.coverage.status()
        (self.out / "capture.json").write_text(json.dumps({**extra, **status, "pairs": self.log}, indent=1) + "\n")
        return status
