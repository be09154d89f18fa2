"""When the simulated rig starts recording: once the renderer's rate over the last second keeps it ahead of the
cameras for the whole recording, else at the deadline. The rate is sampled from when the renderer starts (while the
rig starts), so a fast renderer costs no extra second of measuring after the rig is up."""

from __future__ import annotations

import time

from bracketry.cli.simulate import LEAD_DEADLINE_S, RenderProgress, wait_for_lead


class Renderer:
    """A frame schedule whose renderer, started at ``t0_s`` (monotonic), renders ``fast`` frames per second for
    ``fast_s`` seconds, then ``slow`` frames per second."""

    def __init__(self, t0_s: float, fast: float, fast_s: float = 1e9, slow: float = 0.0) -> None:
        self.t0_s, self.fast, self.fast_s, self.slow = t0_s, fast, fast_s, slow
        self.n_frames = 100_000

    def rendered(self) -> int:
        t = max(0.0, time.monotonic() - self.t0_s)
        return int(min(t, self.fast_s) * self.fast + max(0.0, t - self.fast_s) * self.slow)

    def wait(self, timeout_s: float, frames: int) -> None:
        while self.rendered() < frames:
            time.sleep(0.01)

    def failed(self) -> bool:
        return False


def test_a_fast_renderer_sampled_while_the_rig_starts_lets_it_record_at_once() -> None:
    started = time.monotonic()
    renderer = Renderer(started, fast=7 * 22.0)
    progress = RenderProgress(renderer)
    time.sleep(1.2)  # the rig coming up
    t = time.monotonic()
    wait_for_lead(renderer, seconds=40.0, fps=22.0, started_mono_s=started, progress=progress)
    assert time.monotonic() - t < 0.3
    progress.stop()
    # without samples from before, a second is measured first
    t = time.monotonic()
    wait_for_lead(renderer, seconds=40.0, fps=22.0, started_mono_s=time.monotonic())
    assert 0.95 < time.monotonic() - t < 2.0


def test_a_renderer_not_fast_enough_holds_the_recording_until_the_deadline() -> None:
    started = time.monotonic() - (LEAD_DEADLINE_S - 1.5)  # half real time: 121 frames ahead, 946 needed
    t = time.monotonic()
    wait_for_lead(Renderer(started, fast=11.0), seconds=40.0, fps=22.0, started_mono_s=started)
    assert 1.3 < time.monotonic() - t < 2.5


def test_the_last_second_counts_not_the_average_since_the_start() -> None:
    """100 frames/s for 0.3 s, then 5/s (the rig took the CPU): the average since the start (~24/s) would let a
    40 s recording at 10 fps start; the last second (5/s) holds it until the deadline."""
    t0 = time.monotonic()
    renderer = Renderer(t0, fast=100.0, fast_s=0.3, slow=5.0)
    progress = RenderProgress(renderer)
    time.sleep(1.5)
    started = t0 - (LEAD_DEADLINE_S - 2.3)  # the deadline ~0.8 s from now
    t = time.monotonic()
    wait_for_lead(renderer, seconds=40.0, fps=10.0, started_mono_s=started, progress=progress)
    assert time.monotonic() - t > 0.6
    progress.stop()
