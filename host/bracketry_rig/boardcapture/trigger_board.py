"""Board capture on the rig of a config: the cameras triggered by the trigger board with a one-entry bracket table
(``bracketry calibrate capture --config rig.toml``).

The trigger board runs ``SET_BRACKETS`` with one exposure (``exposure_us``, zero gain from the cameras' profiles)
at a low rate (``rate_hz``); each pulse starts both cameras' exposures: in hardware for line-triggered profiles
(``basler_ace2``: ExposureMode TriggerWidth on Line3, the exposure is the pulse width), through the one
software-trigger adapter for the others (``bracketry_rig.cameras.triggering.camera_trigger``, as the daemon). Frames are
paired with their pulse by the recording session's pairer (the k-th frame since START of each camera belongs to
pulse k, cross-checked by timestamps), with nothing recorded (``DiscardSink``): each paired set is one stereo pair,
judged by the selection. The devices are opened through the daemon's seams (``open_trigger``, ``open_camera``), so
a test runs the real firmware in QEMU with cameras of its own.
"""

from __future__ import annotations

import contextlib
import queue
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_rig.boardcapture.selection import Echo, FolderBackend, Selection, serve_monitor
from bracketry_rig.daemon.config import RigConfig, check_brackets_ms
from bracketry_rig.daemon.sensors import OpenCamera, OpenTrigger, open_gige_camera, open_trigger_client


@dataclass(frozen=True)
class TriggerCaptureOptions:
    """``exposure_us``: the one pulse width (exposure) of every pulse; ``rate_hz``: pulses per second (low: the
    board is moved by hand, each pair is detected before the next); ``max_pairs``: stop after this many pairs;
    ``pair_timeout_s``: no pair for this long is an error (cameras not wired to the trigger, or not streaming);
    ``session_id`` of the trigger's START; ``width``/``height``: region of interest (None: the cameras')."""

    exposure_us: int = 1000
    rate_hz: float = 2.0
    max_pairs: int = 120
    max_blur_px: float = 2.5
    pair_timeout_s: float = 10.0
    session_id: int = 1
    width: int | None = None
    height: int | None = None


def check_options(opts: TriggerCaptureOptions) -> int:
    """The trigger period (us) of ``opts``; a one-entry table the trigger refuses is one line."""
    problem = check_brackets_ms([opts.exposure_us / 1000], opts.rate_hz)
    if problem:
        raise BracketryError(f"--exposure-us {opts.exposure_us} at --rate-hz {opts.rate_hz:g}: {problem[1]}")
    return round(1e6 / opts.rate_hz)


def capture_through_trigger(config: RigConfig, out: Path, board: Any, board_yaml: str,
                            opts: TriggerCaptureOptions = TriggerCaptureOptions(), *, monitor_port: int | None = None,
                            echo: Echo = None, open_trigger: OpenTrigger = open_trigger_client,
                            open_camera: OpenCamera = open_gige_camera) -> tuple[dict[str, Any], int]:
    """Drive the rig of ``config`` in calibration mode until the kept set is enough or ``opts.max_pairs`` pairs;
    kept pairs go to ``out`` (16-bit PNG, as recorded). Returns the coverage status and the number of pairs."""
    from bracketry_base.png import write_png
    from bracketry_rig.cameras.profiles import settings_from_config
    from bracketry_rig.cameras.triggering import camera_trigger
    from bracketry_rig.monitor.calibration_feed import CaptureFeed
    from bracketry_rig.recording.session import DiscardSink, RecordingSession

    period_us = check_options(opts)
    sets: queue.Queue[Any] = queue.Queue()
    handler: list[Any] = []  # the pulse handler, set once the session runs

    def on_event(event: Any) -> None:
        if handler:
            handler[0](event)

    trigger = open_trigger(config.trigger, on_event, period_us, [opts.exposure_us])
    cams: dict[str, Any] = {}
    session = server = None
    served_us: list[int] = []
    pairs = skipped = 0
    out.mkdir(parents=True, exist_ok=True)
    try:
        for cc in config.cameras:
            cams[cc.side] = open_camera(cc, settings_from_config(cc, width=opts.width, height=opts.height,
                                                                 exposure_us=opts.exposure_us))
        pulses = camera_trigger(cams, {cc.side: cc.profile for cc in config.cameras})
        session = RecordingSession(cams, DiscardSink(out), initial_alignment=pulses.initial_alignment,
                                   tap=sets.put_nowait).start()
        pulses.arm()

        def pulse(event: Any) -> None:
            served_us.append(int(event.exposure_us))
            pulses.fire(event, session.cameras if session is not None else None)
            if session is not None:
                session.on_trigger_event(event)

        handler.append(pulse)
        trigger.start(opts.session_id)
        feed = sel = None
        while pairs < opts.max_pairs:
            try:
                pset = sets.get(timeout=opts.pair_timeout_s)
            except queue.Empty:
                raise BracketryError(f"no stereo pair in {opts.pair_timeout_s:g} s ({len(served_us)} pulses sent): "
                                     "check that both cameras are wired to the trigger's lines and "
                                     "streaming") from None
            pairs += 1
            name = f"{pset.trigger_seq:06d}.png"
            frames = [pset.frames.get(side) for side in ("left", "right")]
            if feed is None or sel is None:
                first = next((f.image for f in frames if f is not None and f.image is not None), None)
                if first is None:
                    skipped += 1
                    continue
                feed = CaptureFeed(board, (int(first.shape[1]), int(first.shape[0])), opts.max_blur_px)
                if monitor_port is not None:
                    server = serve_monitor(feed, FolderBackend(out, "board capture: rig in calibration mode"),
                                           monitor_port)
                    if echo is not None:
                        echo(f"monitor: {server.url}")
                sel = Selection(feed, board, out, True, echo)
            if any(f is None or f.image is None for f in frames) or pset.notes:
                skipped += 1
                sel.skip(name, "incomplete pair" if not pset.notes else f"not paired cleanly: {pset.notes}")
                continue
            imgs = (frames[0].image, frames[1].image)

            def save(dest: Path, name: str, imgs: tuple[Any, Any] = imgs) -> None:
                for side, img in zip(("left", "right"), imgs, strict=True):
                    write_png(dest / side / name, img)

            if sel.offer(name, imgs, save):
                break
        if sel is None:
            raise BracketryError(f"no complete stereo pair in {pairs} pairs: check the cameras")
    finally:
        handler.clear()
        with contextlib.suppress(Exception):
            trigger.stop()
        if session is not None:
            with contextlib.suppress(Exception):
                session.stop(drain_s=0.5)
        for cam in cams.values():
            with contextlib.suppress(Exception):
                cam.close()
        with contextlib.suppress(Exception):
            trigger.close()
        if server is not None:
            server.close()
    status = sel.finish(board_yaml, {"source": f"rig {config.source or ''}".strip(), "trigger": config.trigger.kind,
                                     "exposure_us": opts.exposure_us, "period_us": period_us, "gain": 0,
                                     "pulse_exposures_us": served_us, "pairs_skipped": skipped,
                                     "time_ns": time.time_ns()})
    return status, pairs
