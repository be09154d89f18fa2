"""Pixels for the simulated cameras: frame k of the bracket cycle, pre-rendered from the synthetic world.

The fake camera calls its image source once per triggered frame with the exposure it was set to; the k-th call of a
side serves frame k (the k-th trigger pulse: world time ``k / fps``, exposure ``brackets[k % n]``). Rendering happens
before the rig starts, so the camera thread only copies memory. When the served exposure does not match the
schedule (a dropped trigger), the source resynchronises on the next frame with that exposure.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ProgressFn = Callable[[int, int], None]


class FrameSchedule:
    """Pre-rendered frames of both sides: ``frames[side]`` is uint16 (n_frames, height, width), 12-bit Bayer codes.

    ``world`` is a :class:`bracketry_emulator.synth.World` (None: a moving test pattern, for rigs without the
    emulator extra); ``brackets_us`` the exposure cycle; ``fps`` the trigger rate.
    """

    def __init__(self, world: Any, brackets_us: Sequence[int], fps: float, n_frames: int,
                 sides: Sequence[str] = ("left", "right"), resolution: tuple[int, int] = (640, 400),
                 progress: ProgressFn | None = None) -> None:
        self.world = world
        self.brackets_us = [int(b) for b in brackets_us]
        self.fps = float(fps)
        self.n_frames = int(n_frames)
        self.width, self.height = resolution
        self.frames: dict[str, np.ndarray] = {}
        self.served: dict[str, int] = {s: 0 for s in sides}
        #: per side, every frame served: (exposure_us, frame index k or None when not a bracket exposure)
        self.log: dict[str, list[tuple[int, int | None]]] = {s: [] for s in sides}
        self.mismatches = 0
        self._lock = threading.Lock()
        total = self.n_frames * len(sides)
        for i, side in enumerate(sides):
            arr = np.empty((self.n_frames, self.height, self.width), np.uint16)
            for k in range(self.n_frames):
                arr[k] = self.render(side, k)
                if progress is not None:
                    progress(i * self.n_frames + k + 1, total)
            self.frames[side] = arr

    def t_s(self, k: int) -> float:
        """World time of frame k, seconds."""
        return k / self.fps

    def exposure_us(self, k: int) -> int:
        """Exposure of frame k, microseconds."""
        return self.brackets_us[k % len(self.brackets_us)]

    def render(self, side: str, k: int) -> np.ndarray:
        """Frame k of ``side``: uint16 (height, width)."""
        t_s, exp_us = self.t_s(k), float(self.exposure_us(k))
        if self.world is not None:
            return self.world.render(side, t_s, exp_us, rng=self.world.frame_rng(side, t_s, exp_us))
        yy, xx = np.mgrid[0:self.height, 0:self.width]
        shift = 8 * k + (12 if side == "right" else 0)
        pattern = ((xx + shift) // 16 + yy // 16) % 2 * 0.8 + 0.1
        return np.clip(pattern * exp_us / 8.0, 0, 4094).astype(np.uint16)

    def source(self, side: str) -> Callable[[int, int, int], np.ndarray]:
        """The fake camera image source of ``side``: (exposure_us, width, height) -> uint16 (height, width)."""

        def fill(exposure_us: int, width: int, height: int) -> np.ndarray:
            with self._lock:
                k = self.served[side]
                n = len(self.brackets_us)
                matched = None
                for step in range(n):
                    if abs(self.exposure_us(k + step) - exposure_us) <= 1:
                        if step:
                            self.mismatches += 1
                        matched = k + step
                        break
                if matched is not None:  # not a bracket (e.g. the priming trigger): frame k, no advance
                    k = matched
                    self.served[side] = k + 1
                self.log[side].append((int(exposure_us), matched))
            frame = self.frames[side][k % self.n_frames]
            if (height, width) != frame.shape:
                out = np.zeros((height, width), np.uint16)
                h, w = min(height, frame.shape[0]), min(width, frame.shape[1])
                out[:h, :w] = frame[:h, :w]
                return out
            return frame

        return fill

    def frame_indices(self, recorded_exposures_us: Sequence[float], side: str = "left") -> list[int | None]:
        """World frame index of each recorded frame (in recording order), from the exposures the fake camera
        reported for them: the served log is walked forward to the next entry with that exposure, so frames lost
        between camera and disk, priming frames and merged triggers do not shift the later ones."""
        log = self.log[side]
        out: list[int | None] = []
        j = 0
        for e in recorded_exposures_us:
            k = None
            for jj in range(j, min(j + 4 * len(self.brackets_us), len(log))):
                if log[jj][1] is not None and abs(log[jj][0] - float(e)) <= 1.0:
                    k, j = log[jj][1], jj + 1
                    break
            out.append(k)
        return out

    def write_groundtruth(self, path: Path, frames: Sequence[tuple[int, float]]) -> int:
        """Write the left camera's TUM ground truth of recorded frames ``(stamp_ns, reported exposure_us)`` in
        recording order: each stamp gets the pose of the world frame that camera really served for it.

        Returns the number of poses written (0 without a world)."""
        if self.world is None:
            return 0
        from bracketry_emulator.synth.writer import tum_line

        ks = self.frame_indices([e for _t, e in frames])
        lines = ["# bracketry simulated rig ground truth (TUM): t_s tx ty tz qx qy qz qw, left camera, host time"]
        n = 0
        for (t_ns, _e), k in zip(frames, ks):
            if k is not None:
                lines.append(tum_line(int(t_ns), self.world.pose(self.t_s(k))))
                n += 1
        path.write_text("\n".join(lines) + "\n")
        return n
