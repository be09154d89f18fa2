"""Frame identity of the simulated cameras: the index embedded in a frame's pixels, the render-ahead schedule and the
image source that serves it (no rig, no network)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bracketry.sim.clock import SteppedClock
from bracketry.sim.frames import (
    FRAME_ID_PIXELS,
    MAX_FRAME_ID,
    FrameSchedule,
    clear_frame_id,
    embed_frame_id,
    frame_time_s,
    read_frame_id,
    reference_time_s,
)

BRACKETS_US = [1000, 2000, 4000, 8000, 16000, 32000]


@pytest.mark.parametrize("k", [0, 1, 255, 256, 65535, 65536, 123456, MAX_FRAME_ID])
def test_frame_id_round_trip(k: int) -> None:
    img = np.full((8, 16), 4094, np.uint16)
    embed_frame_id(img, k)
    assert read_frame_id(img) == k
    assert read_frame_id(img << 4) == k  # codes scaled to 16 bits
    assert img.max() <= 4095 and (img[1:] == 4094).all() and (img[0, FRAME_ID_PIXELS:] == 4094).all()


def test_frames_without_identity_read_none() -> None:
    rng = np.random.default_rng(0)
    hits = sum(read_frame_id(rng.integers(0, 4096, (4, 8), dtype=np.uint16)) is not None for _ in range(2000))
    assert hits == 0
    img = np.zeros((4, 8), np.uint16)
    embed_frame_id(img, 77)
    img[0, 3] ^= 1  # a corrupted check code
    assert read_frame_id(img) is None
    embed_frame_id(img, 77)
    clear_frame_id(img)
    assert read_frame_id(img) is None
    with pytest.raises(ValueError):
        embed_frame_id(img, MAX_FRAME_ID + 1)


def test_frame_times_are_each_frames_own_mid_exposure() -> None:
    """Frame k is triggered at k / fps; its pose is at its mid-exposure; a cycle's one render at its span's middle."""
    got = [frame_time_s(k, BRACKETS_US, 20.0) for k in (0, 1, 5, 6, 12)]
    assert got == pytest.approx([0.0005, 0.051, 0.266, 0.3005, 0.6005], abs=1e-12)
    assert reference_time_s(1, BRACKETS_US, 20.0) == pytest.approx(0.5 * (0.3 + 0.55 + 0.032))


def test_source_serves_each_side_its_next_bracket_frame(tmp_path: Path) -> None:
    """The source serves each side its next bracket frame by count; each carries its own index, equal to what the
    renderer wrote; an exposure outside the cycle has no frame and no identity."""
    sched = FrameSchedule(tmp_path, None, BRACKETS_US, 20.0, 24, resolution=(32, 16), wait_for_render_s=0.0)
    late = sched.source("right")(1000, 32, 16)  # nothing rendered yet (not started): served without identity
    assert read_frame_id(late) is None and sched.unidentified["right"] == 1 and sched.waited["right"] == 1
    sched.served["right"] = 0
    sched._fill_s.clear()  # as if that fill had not happened
    sched.wait_for_render_s = 60.0
    sched.start()
    try:
        lost_first = sched.source("right")(2000, 32, 16)  # the right camera lost the first trigger: frame 1
        assert read_frame_id(lost_first) == 1 and sched.served["right"] == 2
        src = sched.source("left")
        first = src(1000, 32, 16)  # waits for the renderer
        assert read_frame_id(first) == 0
        assert read_frame_id(src(2000, 32, 16)) == 1
        # a fill that found another pulse's exposure in the register (filled late): still this side's next frame,
        # as the pairer counts it (a stereo pair never shows two rendered frames)
        assert read_frame_id(src(8000, 32, 16)) == 2 and sched.mismatches == 1
        priming = src(77, 32, 16)  # not a bracket exposure: no frame, not counted
        assert read_frame_id(priming) is None and sched.unidentified["left"] == 1
        assert read_frame_id(src(8000, 32, 16)) == 3
        assert read_frame_id(src(16000, 32, 16)) == 4
        cropped = src(32000, 16, 8)
        assert read_frame_id(cropped) == 5
        sched.wait(timeout_s=60)
        assert sched.render_done_ns() is not None
        frames = np.load(tmp_path / "frames_left.npy")
        assert np.array_equal(first, frames[0]) and np.array_equal(cropped, frames[5][:8, :16])
        assert [read_frame_id(f) for f in frames] == list(range(24))
        right = np.load(tmp_path / "frames_right.npy")
        assert [read_frame_id(f) for f in right] == list(range(24)) and not np.array_equal(right[0], frames[0])
        assert sched.mismatches == 1
    finally:
        sched.stop()


def test_a_renderer_behind_holds_the_world_for_both_sides(tmp_path: Path) -> None:
    """Frames not rendered yet: both sides get the latest rendered frame of the same exposure (same index), never a
    delayed trigger and never a frame without identity."""
    sched = FrameSchedule(tmp_path, None, BRACKETS_US, 20.0, 60, resolution=(32, 16), wait_for_render_s=0.0)
    sched._counter[:, 0] = 14  # frames 0..13 "rendered" (pattern frames, written here)
    for k in range(14):
        for side in ("left", "right"):
            img = np.zeros((16, 32), np.uint16)
            embed_frame_id(img, k)
            sched.frames[side][k] = img
    left, right = sched.source("left"), sched.source("right")
    sched.served = {"left": 12, "right": 12}
    got = [(read_frame_id(left(e, 32, 16)), read_frame_id(right(e, 32, 16))) for e in BRACKETS_US]
    assert got == [(12, 12), (13, 13), (8, 8), (9, 9), (10, 10), (11, 11)]
    assert sched.held == 4 and sched.unidentified == {"left": 0, "right": 0}


def test_a_side_filling_a_period_after_the_other_skips_the_trigger_it_missed(tmp_path: Path) -> None:
    """Fills of one side a period after the other side's fills of the same frames, six in a row: that camera took
    one trigger for two (the pairer moves its frames on by one pulse for the same reason); its later fills skip one
    frame. Both sides late together is the host's lateness: nothing moves."""
    fps = 50.0
    clock = SteppedClock()  # fills take no time but the lateness the test gives them
    sched = FrameSchedule(tmp_path, None, BRACKETS_US, fps, 60, resolution=(32, 16), wait_for_render_s=0.0,
                          clock=clock)
    sched._counter[:, 0] = 60
    left, right = sched.source("left"), sched.source("right")
    for m in range(20):
        e = BRACKETS_US[m % 6]
        left(e, 32, 16)
        if m == 4:
            clock.sleep(2.0 / fps)  # both late together
        if m >= 8:
            clock.sleep(1.0 / fps)  # from frame 8 the right camera fills a period after the left one
        right(e, 32, 16)
    assert sched.resyncs == 1 and sched.served["right"] == 21
