"""When the simulated rig starts recording: once the renderer's rate over the last second keeps it ahead of the
cameras for the whole recording, else at the deadline. The rate is sampled from when the renderer starts (while the
rig starts), so a fast renderer costs no extra second of measuring after the rig is up.

Time is a stepped clock that moves only when the code waits on it: each test asserts the simulated time at which
``wait_for_lead`` decided, never how long the test took."""

from __future__ import annotations

from bracketry.cli.simulate import LEAD_DEADLINE_S, LEAD_STEP_S, RenderProgress, wait_for_lead
from bracketry.sim.clock import SteppedClock


class Renderer:
    """A frame schedule whose renderer, started at ``t0_s`` (on ``clock``), renders ``fast`` frames per second for
    ``fast_s`` seconds, then ``slow`` frames per second."""

    def __init__(self, clock: SteppedClock, t0_s: float, fast: float, fast_s: float = 1e9, slow: float = 0.0) -> None:
        self.clock, self.t0_s, self.fast, self.fast_s, self.slow = clock, t0_s, fast, fast_s, slow
        self.n_frames = 100_000

    def rendered(self) -> int:
        t = max(0.0, self.clock.now_s() - self.t0_s)
        return int(min(t, self.fast_s) * self.fast + max(0.0, t - self.fast_s) * self.slow)

    def wait(self, timeout_s: float, frames: int) -> None:
        while self.rendered() < frames:
            self.clock.sleep(0.01)

    def failed(self) -> bool:
        return False


def rig_starting(clock: SteppedClock, progress: RenderProgress, seconds: float) -> None:
    """``seconds`` of the rig coming up while the progress thread samples every 0.1 s (here: stepped)."""
    for _ in range(round(seconds / 0.1)):
        clock.sleep(0.1)
        progress.sample()


def test_a_fast_renderer_sampled_while_the_rig_starts_lets_it_record_at_once() -> None:
    clock = SteppedClock(100.0)
    started = clock.now_s()
    renderer = Renderer(clock, started, fast=7 * 22.0)
    progress = RenderProgress(renderer, clock=clock, thread=False)
    rig_starting(clock, progress, 1.2)
    t = clock.now_s()
    wait_for_lead(renderer, seconds=40.0, fps=22.0, started_mono_s=started, progress=progress, clock=clock)
    assert clock.now_s() == t  # decided on the first look: no wait once the rig is up
    # without samples from before, a second is measured first: decided on the look one second later
    t = clock.now_s()
    wait_for_lead(renderer, seconds=40.0, fps=22.0, started_mono_s=t, clock=clock)
    assert round(clock.now_s() - t, 6) == 1.0
    assert clock.slept[-10:] == [LEAD_STEP_S] * 10


def test_a_renderer_not_fast_enough_holds_the_recording_until_the_deadline() -> None:
    clock = SteppedClock(100.0)
    started = clock.now_s() - (LEAD_DEADLINE_S - 1.5)  # half real time: 121 frames ahead, 946 needed
    t = clock.now_s()
    wait_for_lead(Renderer(clock, started, fast=11.0), seconds=40.0, fps=22.0, started_mono_s=started, clock=clock)
    assert round(clock.now_s() - t, 6) == 1.5  # held until the deadline, not a step longer
    assert clock.now_s() >= started + LEAD_DEADLINE_S


def test_without_a_deadline_a_slow_renderer_holds_the_recording_until_it_stays_ahead() -> None:
    """``deadline_s=None`` (``simulate --render-ahead``, what the demo records with): half real time, the recording
    waits past the deadline until the frames still to render take no longer than the recording itself (with a
    second to spare): 946 needed at 11/s against 22/s of triggers."""
    clock = SteppedClock(100.0)
    started = clock.now_s() - (LEAD_DEADLINE_S - 1.5)
    renderer = Renderer(clock, started, fast=11.0)
    wait_for_lead(renderer, seconds=40.0, fps=22.0, started_mono_s=started, clock=clock, deadline_s=None)
    k = renderer.rendered()
    assert clock.now_s() > started + LEAD_DEADLINE_S
    assert k + 11.0 * 40.0 >= 42 * 22 + 22  # ahead until the end of the recording
    assert k - 11 + 11.0 * 40.0 < 42 * 22 + 22  # and not a look later than needed (one step renders ~1 frame)


def test_without_a_deadline_a_renderer_that_stops_is_waited_for_until_every_frame_is_there() -> None:
    """A renderer that renders everything at once after a stall: the wait ends when the frames are all there."""
    clock = SteppedClock(100.0)
    started = clock.now_s()

    class Burst(Renderer):
        def rendered(self) -> int:
            return 300 if self.clock.now_s() - self.t0_s >= 30.0 else super().rendered()

    burst = Burst(clock, started, fast=22.0, fast_s=2.0, slow=0.0)
    burst.n_frames = 300
    wait_for_lead(burst, seconds=40.0, fps=22.0, started_mono_s=started, clock=clock, deadline_s=None)
    assert 30.0 <= clock.now_s() - started < 30.0 + 2 * LEAD_STEP_S


def test_the_last_second_counts_not_the_average_since_the_start() -> None:
    """100 frames/s for 0.3 s, then 5/s (the rig took the CPU): the average since the start (~24/s) would let a
    40 s recording at 10 fps start; the last second (5/s) holds it until the deadline."""
    clock = SteppedClock(100.0)
    t0 = clock.now_s()
    renderer = Renderer(clock, t0, fast=100.0, fast_s=0.3, slow=5.0)
    progress = RenderProgress(renderer, clock=clock, thread=False)
    rig_starting(clock, progress, 1.5)
    started = t0 - (LEAD_DEADLINE_S - 2.3)  # the deadline 0.8 s from now
    t = clock.now_s()
    wait_for_lead(renderer, seconds=40.0, fps=10.0, started_mono_s=started, progress=progress, clock=clock)
    assert round(clock.now_s() - t, 6) == 0.8  # held until the deadline


def test_the_average_since_the_start_would_have_started_it() -> None:
    """The same renderer judged on the average since the start: the decision above is the last second's."""
    clock = SteppedClock(100.0)
    renderer = Renderer(clock, clock.now_s(), fast=100.0, fast_s=0.3, slow=5.0)
    clock.sleep(1.5)
    k = renderer.rendered()
    assert k + k / 1.5 * 40.0 >= min(renderer.n_frames, round(42.0 * 10.0)) + 10.0
