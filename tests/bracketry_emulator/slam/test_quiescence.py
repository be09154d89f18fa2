"""The lockstep feed's wait (slam/quiescence.py): threads idle only after a whole quiet window, on injected samples
and an injected clock (no wall clock)."""

from __future__ import annotations

import os
import threading

from bracketry_emulator.slam.quiescence import (
    LockstepStats,
    ThreadSample,
    ThreadSampler,
    busy_now,
    run_ns_between,
    sample_threads,
    thread_ids,
    wait_idle,
    window_idle,
)


class FakeClock:
    """A clock that moves only when the code under test sleeps."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += dt


def _script(clock: FakeClock, busy_until_s: float, idle_run_ns_per_s: float = 1e6):
    """Samples of one thread: running (R, 1 ns per ns) until ``busy_until_s``, then sleeping with idle polls."""

    def sample() -> dict[int, ThreadSample]:
        t = clock()
        if t < busy_until_s:
            return {7: ThreadSample("R", int(t * 1e9))}
        return {7: ThreadSample("S", int(busy_until_s * 1e9 + (t - busy_until_s) * idle_run_ns_per_s))}

    return sample


def test_waits_for_a_whole_quiet_window_after_the_threads_stop() -> None:
    clock, stats = FakeClock(), LockstepStats()
    ok = wait_idle(set(), stats, window_s=0.012, poll_s=0.001, clock=clock, sleep=clock.sleep,
                   sample=_script(clock, busy_until_s=0.5))
    assert ok and stats.waits == 1 and stats.timeouts == 0
    # the end of the busy stretch is seen at most one spaced-out poll (8 ms) late
    assert 0.5 + 0.012 <= clock.t < 0.5 + 0.012 + 0.008 + 0.003
    assert abs(stats.wait_s - clock.t) < 1e-9


def test_polls_space_out_while_a_thread_is_busy_and_not_in_the_quiet_window() -> None:
    clock, stats = FakeClock(), LockstepStats()
    # 2 s of busy work: at 1 ms a poll that would be ~2000 samples; spaced out to 8 ms about 250
    assert wait_idle(set(), stats, window_s=0.012, poll_s=0.001, max_busy_poll_s=0.008, clock=clock,
                     sleep=clock.sleep, sample=_script(clock, busy_until_s=2.0))
    assert 2.0 / 0.008 <= stats.polls < 2.0 / 0.008 + 30
    quiet_polls = stats.polls
    clock2, stats2 = FakeClock(), LockstepStats()
    assert wait_idle(set(), stats2, window_s=0.012, poll_s=0.001, max_busy_poll_s=0.001, clock=clock2,
                     sleep=clock2.sleep, sample=_script(clock2, busy_until_s=2.0))
    assert stats2.polls > 6 * quiet_polls  # the unspaced poll: every millisecond
    # idle threads are watched at the fine poll: the quiet window is 12 samples, not 2
    clock3, stats3 = FakeClock(), LockstepStats()
    assert wait_idle(set(), stats3, window_s=0.012, poll_s=0.001, max_busy_poll_s=0.008, clock=clock3,
                     sleep=clock3.sleep, sample=_script(clock3, busy_until_s=0.0))
    assert 12 <= stats3.polls <= 14


def test_a_thread_that_runs_while_sleeping_is_not_idle_and_the_wait_gives_up() -> None:
    clock, stats = FakeClock(), LockstepStats()
    # state S but running half of the time (a busy thread between samples): never idle
    ok = wait_idle(set(), stats, window_s=0.012, poll_s=0.001, max_wait_s=1.0, clock=clock, sleep=clock.sleep,
                   sample=_script(clock, busy_until_s=0.0, idle_run_ns_per_s=0.5e9))
    assert not ok and stats.timeouts == 1
    assert 1.0 < clock.t < 1.01


def test_busy_states_and_run_time() -> None:
    assert busy_now({1: ThreadSample("S", 0), 2: ThreadSample("R", 0)})
    assert busy_now({1: ThreadSample("D", 0)})
    assert not busy_now({1: ThreadSample("S", 0)})
    first = {1: ThreadSample("S", 100)}
    last = {1: ThreadSample("S", 150), 2: ThreadSample("S", 30)}  # thread 2 born in the window: all its run time
    assert run_ns_between(first, last) == 80
    assert window_idle(first, last, window_s=1e-6, max_run_fraction=0.1)  # 80 ns < 100 ns
    assert not window_idle(first, last, window_s=1e-6, max_run_fraction=0.05)


def test_real_threads_of_this_process_are_read_from_proc() -> None:
    stop = threading.Event()
    worker = threading.Thread(target=stop.wait)
    before = thread_ids()
    worker.start()
    try:
        new = thread_ids() - before
        assert len(new) == 1
        assert wait_idle(before, LockstepStats(), max_wait_s=30.0)  # a thread blocked on the event is idle
        (s,) = sample_threads(new).values()  # once idle it is asleep on the event (it may run a moment after start)
        assert s.state == "S" and s.run_ns > 0
    finally:
        stop.set()
        worker.join()


def test_a_sampler_rereads_its_open_files_and_drops_an_ended_thread() -> None:
    before = thread_ids()
    stop, spin_until = threading.Event(), threading.Event()

    def work() -> None:
        while not spin_until.is_set():  # runs on a CPU until told, then sleeps on the event
            pass
        stop.wait()

    worker = threading.Thread(target=work)
    worker.start()
    with ThreadSampler(before) as sampler:
        try:
            tid = worker.native_id  # other threads may start meanwhile (a library's pool): this test follows its own
            assert tid is not None and tid in thread_ids() - before
            first = sampler()[tid]
            while sampler()[tid].run_ns == first.run_ns:  # the same descriptors, read again: the run time moves
                pass
            spin_until.set()
            assert wait_idle(before, LockstepStats(), max_wait_s=30.0, sample=sampler)
            again = sampler()[tid]
            assert again.state == "S" and again.run_ns > first.run_ns
            assert again.state == sample_threads({tid})[tid].state
        finally:
            spin_until.set()
            stop.set()
            worker.join()
        while tid in thread_ids():  # join returns once the thread's Python work is done, before its OS thread ends
            os.sched_yield()
        assert tid not in sampler()  # ended: left out, its descriptors closed
        assert tid not in sampler._fds
