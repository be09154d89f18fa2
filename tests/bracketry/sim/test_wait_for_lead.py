"""When the simulated rig starts recording: once the renderer's average rate since it was started keeps it ahead of
the cameras for the whole recording (no extra second of measuring after the rig is up), else at the deadline."""

from __future__ import annotations

import time

from bracketry.cli.simulate import LEAD_DEADLINE_S, wait_for_lead


class RendererAt:
    """A frame schedule whose renderer started at ``t0_s`` (monotonic) and renders ``rate`` frames per second."""

    def __init__(self, t0_s: float, rate: float, n_frames: int = 10_000) -> None:
        self.t0_s, self.rate, self.n_frames = t0_s, rate, n_frames

    def rendered(self) -> int:
        return min(self.n_frames, int(max(0.0, time.monotonic() - self.t0_s) * self.rate))

    def wait(self, timeout_s: float, frames: int) -> None:
        while self.rendered() < frames:
            time.sleep(0.01)

    def failed(self) -> bool:
        return False


def test_a_fast_renderer_lets_the_rig_record_as_soon_as_it_is_up() -> None:
    started = time.monotonic() - 1.5  # the rig took 1.5 s to come up; the renderer has been at 7x real time
    t = time.monotonic()
    wait_for_lead(RendererAt(started, rate=7 * 22.0), seconds=40.0, fps=22.0, started_mono_s=started)
    assert time.monotonic() - t < 0.3


def test_a_renderer_not_fast_enough_holds_the_recording_until_the_deadline() -> None:
    started = time.monotonic() - (LEAD_DEADLINE_S - 0.6)  # half real time: 70 frames ahead, 946 needed
    t = time.monotonic()
    wait_for_lead(RendererAt(started, rate=11.0), seconds=40.0, fps=22.0, started_mono_s=started)
    assert 0.4 < time.monotonic() - t < 1.5


def test_the_renderer_start_up_counts_as_time_without_frames() -> None:
    """A renderer that starts 2 s after the command and renders 1.5x real time: k frames at T s after the start
    (k = 33 (T - 2)) keep it ahead once k + 40 k / T >= 946, at T ~5.45 s (a rate measured only after it started
    would have let the rig record at ~4.3 s)."""
    started = time.monotonic()
    wait_for_lead(RendererAt(started + 2.0, rate=1.5 * 22.0), seconds=40.0, fps=22.0, started_mono_s=started)
    assert 5.2 < time.monotonic() - started < LEAD_DEADLINE_S
