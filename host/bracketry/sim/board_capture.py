"""Board capture on the simulated rig in calibration mode (``bracketry calibrate capture --rig sim``): the two fake
GigE cameras serve a board moved by hand (:class:`bracketry.sim.board_rig.BoardSource`), configured by their
profile and fired together by the software-trigger adapter with a one-entry bracket table
(:class:`bracketry_rig.cameras.lockstep.LockstepPair`). Runs inside the private network namespace."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path
from typing import Any

from bracketry_rig.boardcapture.selection import Echo, FolderBackend, Selection, serve_monitor


def capture_sim(out: Path, board: Any, board_yaml: str, size: tuple[int, int], *, seed: int = 0,
                exposure_us: int = 1000, max_pairs: int = 120, max_blur_px: float = 2.5, rate_hz: float = 0.0,
                hold_s: float = 0.0, monitor_port: int | None = None, echo: Echo = None) -> tuple[dict[str, Any], int]:
    """Capture until the kept set is enough or ``max_pairs`` pulses; ``out`` gets the kept pairs, ``truth/`` (the
    simulated cameras' calibration) and ``capture.json``. With ``monitor_port`` the page is served here and reached
    from outside the namespace through ``monitor_socket(out)``. Returns the coverage status and the pulses."""
    from bracketry.sim.board_rig import BoardSource, start_board_cameras
    from bracketry.sim.frames import read_frame_id
    from bracketry.sim.rig import CAMERA_ADDRESSES, monitor_socket
    from bracketry_base.png import write_png
    from bracketry_rig.cameras.lockstep import LockstepPair
    from bracketry_rig.cameras.profiles import CameraSettings
    from bracketry_rig.monitor.calibration_feed import CaptureFeed

    out.mkdir(exist_ok=True)
    feed = CaptureFeed(board, size, max_blur_px)
    source = BoardSource(board, size, seed)
    servers = start_board_cameras(source)
    server = bridge_in = None
    pairs = mismatched = 0
    try:
        if monitor_port is not None:
            server = serve_monitor(feed, FolderBackend(out), monitor_port)
            bridge_in = subprocess.Popen(["socat", f"UNIX-LISTEN:{monitor_socket(out)},fork,mode=600",
                                          f"TCP:127.0.0.1:{monitor_port}"], stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            if echo is not None:
                echo(f"monitor: http://127.0.0.1:{monitor_port}/")
        sel = Selection(feed, board, out, True, echo)
        settings = CameraSettings(profile="aravis_fake", pixel_format="Mono16", width=size[0], height=size[1],
                                  trigger_source="Software", exposure_us=float(exposure_us))
        with LockstepPair(CAMERA_ADDRESSES, settings) as cams:
            t_next = time.monotonic()
            while pairs < max_pairs:
                left, right = cams.grab()
                pairs += 1
                name = f"{pairs - 1:06d}.png"
                if left.image is None or right.image is None:
                    sel.skip(name, "incomplete frame")
                    continue
                ids = (read_frame_id(left.image), read_frame_id(right.image))
                if ids[0] is None or ids[0] != ids[1]:  # the two images are not one instant's
                    mismatched += 1
                    sel.skip(name, f"not a pair (views {ids[0]}, {ids[1]})")
                    continue
                imgs = (left.image, right.image)

                def save(dest: Path, name: str, imgs: tuple[Any, Any] = imgs) -> None:
                    for side, img in zip(("left", "right"), imgs, strict=True):
                        write_png(dest / side / name, img)

                if sel.offer(name, imgs, save):
                    break
                if rate_hz > 0:
                    t_next += 1.0 / rate_hz
                    time.sleep(max(0.0, t_next - time.monotonic()))
        source.write_truth(out / "truth")
        status = sel.finish(board_yaml, {"source": "rig sim", "seed": seed, "exposure_us": exposure_us,
                                         "gain": 0, "served_exposures_us": source.exposures_us,
                                         "pairs_not_matched": mismatched})
        if server is not None and hold_s > 0:
            time.sleep(hold_s)
    finally:
        if bridge_in is not None:
            bridge_in.terminate()
            bridge_in.wait(timeout=10)
        if server is not None:
            server.close()
        for cam in servers.values():
            cam.stop()
    return status, pairs
