"""The simulated rig in calibration mode: two fake GigE cameras looking at a board moved by hand.

The cameras are the simulated rig's (:data:`bracketry.sim.rig.CAMERA_ADDRESSES`, Aravis ``GvFakeCamera`` servers
in a private network namespace), but their pixels come from the board-session renderer
(:mod:`bracketry_emulator.synth.board_session`) instead of the forest world: the k-th frame a camera fills shows the
k-th hand-held view of a seeded session (:func:`random_views`: distance, place, tilt, partial and blurred views,
over-exposed ones), exposed at the exposure the camera was triggered with (the session's light puts the white
squares at 60 % of full well at :data:`bracketry_emulator.synth.board_session.EXPOSURE_US`). Each served frame
carries its view index in row 0 (:func:`bracketry.sim.frames.embed_frame_id`), so a pair whose two images show
different views is recognised, never used. The rig's default (forest world, bracket cycle) is untouched: this is a
separate source for :class:`bracketry_rig.cameras.fake.FakeCameraServer`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bracketry.sim.frames import embed_frame_id
from bracketry.sim.rig import CAMERA_ADDRESSES
from bracketry_base.calibration.board import BoardSpec
from bracketry_rig.cameras.triggering import PRIMING_EXPOSURE_US

#: views in one simulated hand-held session (frames beyond repeat them)
DEFAULT_VIEWS = 60


class BoardSource:
    """Pixels of a hand-held board session for the two fake cameras (thread-safe: one lock per render).

    Args:
        board: the printed board; resolution: (width, height) of the cameras; seed: the session's views;
        n_views: views in the session (the k-th fill of a side shows view ``k % n_views``).
    """

    def __init__(self, board: BoardSpec, resolution: tuple[int, int], seed: int,
                 n_views: int = DEFAULT_VIEWS) -> None:
        from bracketry_emulator.synth import default_calibration
        from bracketry_emulator.synth.board_session import BoardRenderer, background_field, random_views
        from bracketry_emulator.synth.camera_model import CameraModel

        w, h = resolution
        self.board = board
        self.seed = seed
        self.calib = default_calibration(w, h)
        rng = np.random.default_rng(np.random.SeedSequence([seed, 35]))
        self.views = random_views(board, self.calib.left, n_views, rng)
        self.backgrounds = [background_field(w, h, rng) for _ in self.views]
        self.renderer = BoardRenderer(board, self.calib, CameraModel(), 2 if w <= 1280 else 1)
        for side in ("left", "right"):  # the rays of each pixel, cast once here: never inside a camera's fill
            self.renderer.reflectance(side, self.views[0], self.backgrounds[0])
        self._lock = threading.Lock()
        self._count = {"left": 0, "right": 0}
        #: exposures (us) each side was filled at, priming frames included
        self.exposures_us: dict[str, list[int]] = {"left": [], "right": []}

    def source(self, side: str) -> Callable[[int, int, int], np.ndarray]:
        """The fake camera's image source of ``side``: ``fill(exposure_us, width, height) -> uint16 (H, W)``."""
        side_index = ("left", "right").index(side)

        def fill(exposure_us: int, width: int, height: int) -> np.ndarray:
            with self._lock:
                self.exposures_us[side].append(int(exposure_us))
                if exposure_us == PRIMING_EXPOSURE_US:  # the priming trigger: no view
                    return np.zeros((height, width), np.uint16)
                k = self._count[side]
                self._count[side] += 1
                n = len(self.views)
                rng = np.random.default_rng(np.random.SeedSequence([self.seed, 35, k, side_index]))
                img = self.renderer.render(side, self.views[k % n], self.backgrounds[k % n], rng,
                                           exposure_us=float(exposure_us))
            embed_frame_id(img, k)
            return img

        return fill

    def write_truth(self, out: Path) -> None:
        """The true calibration of the simulated cameras as camera_info (``out/left.yaml``, ``right.yaml``,
        ``calib_kitti.txt``)."""
        from bracketry_emulator.synth.calibration import write_calibration

        write_calibration(self.calib, out)


def start_board_cameras(source: BoardSource) -> dict[str, Any]:
    """Start the two fake cameras serving ``source`` on the simulated rig's addresses (needs the private network
    namespace, :func:`bracketry.sim.rig.in_private_netns`). Returns side -> server (``stop()`` each)."""
    from bracketry_rig.cameras.fake import FakeCameraServer

    servers: dict[str, Any] = {}
    try:
        for side, addr in CAMERA_ADDRESSES.items():
            servers[side] = FakeCameraServer(addr, serial=f"SIM{side.upper()}",
                                             image_source=source.source(side)).start()
    except BaseException:
        for s in servers.values():
            s.stop()
        raise
    return servers
