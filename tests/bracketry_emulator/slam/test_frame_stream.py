"""Stereo frames as records through a named pipe or a spool file (the benchmark's route to SLAM): exact pixels, clear
failures."""

from __future__ import annotations

import io
import os
import threading
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bracketry_emulator.emulation.emulator import EmulatedImage
from bracketry_emulator.emulation.writer import RunWriter
from bracketry_emulator.slam.frame_stream import (
    FrameFeed,
    FrameSpool,
    StreamError,
    iter_records,
    read_stream,
    write_end,
    write_frame,
)
from bracketry_emulator.vo.runner import png_frames, raw_to_gray8


def _frames(n: int, shape: tuple[int, int] = (40, 64)) -> list[tuple[int, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(5)
    return [(1_000_000 * k + 7, rng.integers(0, 4096, shape, dtype=np.uint16),
             rng.integers(0, 4096, shape, dtype=np.uint16)) for k in range(n)]


def test_records_round_trip_and_short_streams_are_errors() -> None:
    buf = io.BytesIO()
    frames = _frames(3)
    for t, a, b in frames:
        write_frame(buf, t, a, b)
    write_frame(buf, 99, np.full((2, 3), 200, np.uint8), np.zeros((2, 3), np.uint8))  # 8-bit runs too
    write_end(buf, 4)
    got = list(iter_records(io.BytesIO(buf.getvalue())))
    assert [g[0] for g in got] == [7, 1_000_007, 2_000_007, 99]
    for (_, a, b), (_, ga, gb) in zip(frames, got, strict=False):
        assert ga.dtype == np.uint16 and np.array_equal(ga, a) and np.array_equal(gb, b)
    assert got[3][1].dtype == np.uint8 and int(got[3][1][0, 0]) == 200
    with pytest.raises(StreamError, match="ended after"):  # the producer died mid-run: no end record
        list(iter_records(io.BytesIO(buf.getvalue()[:-40])))
    with pytest.raises(StreamError, match="announced 5 frames but carried 4"):
        end = io.BytesIO()
        write_end(end, 4)
        bad = io.BytesIO(buf.getvalue()[:-len(end.getvalue())])
        bad.seek(0, 2)
        write_end(bad, 5)
        list(iter_records(io.BytesIO(bad.getvalue())))
    with pytest.raises(ValueError, match="alike"):
        write_frame(io.BytesIO(), 0, frames[0][1], frames[0][1][:, :10])


def test_feed_sends_what_the_png_writer_writes(tmp_path: Path) -> None:
    """The same steps written as PNGs (RunWriter) and sent through a FIFO (FrameFeed): bit for bit the same images
    and names, and the same gray images for SLAM (read_gray8 of the PNG == to_gray8 of the streamed array)."""
    frames = _frames(4)
    fifo = FrameFeed.make_fifo(tmp_path / "frames.fifo")
    received: list = []
    reader = threading.Thread(target=lambda: received.extend(read_stream(fifo, max_buffered_bytes=1)))
    reader.start()  # a 1-byte budget: one frame waits at a time, the producer is held (back-pressure)
    feed = FrameFeed(fifo, reader_pid=os.getpid())
    writer = RunWriter(tmp_path / "runs", "m", ("left", "right"), depth=12, png_compression="stored")
    for k, (t, a, b) in enumerate(frames):
        src_us = 1000 * (k + 1)
        seq = SimpleNamespace(index=k, timestamps_ns={"left": {src_us: t}, "right": {src_us: t + 3}})
        images = {side: EmulatedImage(img, 2000.0, src_us, 2.0, "highernosat")
                  for side, img in (("left", a), ("right", b))}
        writer.write_step(k, seq, images, 2000.0)
        feed.write_step(k, seq, images, 2000.0)
    writer.close()
    feed.close()
    reader.join(timeout=30)
    assert feed.failed is None and feed.n_frames == 4 and len(received) == 4
    n, from_png = png_frames(tmp_path / "runs" / "m")
    assert n == 4
    for (t, a, b), (tp, gl, gr), (ts, sl, sr) in zip(frames, from_png, received, strict=True):
        assert ts == tp == t  # the name: the first side's source frame timestamp
        png_l = cv2.imread(str(tmp_path / "runs" / "m" / "images_left" / f"{t}.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(sl, png_l) and np.array_equal(sl, a) and np.array_equal(sr, b)
        (_, ml, mr), = raw_to_gray8([(ts, sl, sr)])
        assert np.array_equal(ml, gl) and np.array_equal(mr, gr)


def test_feed_gives_up_on_a_reader_that_is_gone(tmp_path: Path) -> None:
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    fifo = FrameFeed.make_fifo(tmp_path / "f.fifo")
    feed = FrameFeed(fifo, reader_pid=proc.pid, open_timeout_s=60)
    _t, a, b = _frames(1)[0]
    feed.send(0, a, b)  # nobody will ever open the other end: fails at once, not after 60 s
    assert feed.failed and "cannot open" in feed.failed
    feed.send(1, a, b)
    feed.close()
    assert feed.n_frames == 0


def test_spool_holds_the_steps_for_a_reader_that_starts_later(tmp_path: Path) -> None:
    """A spool file (written with nobody reading) read back afterwards: the same frames and names as a feed's; an
    unwritable spool says so in one line and drops the frames; a spool cut short is an error for its reader."""
    frames = _frames(3)
    spool = FrameSpool(tmp_path / "frames.stream")
    for t, a, b in frames:
        spool.send(t, a, b)
    spool.close()
    assert spool.failed is None and spool.n_frames == 3
    got = list(read_stream(tmp_path / "frames.stream"))
    assert [g[0] for g in got] == [t for t, _a, _b in frames]
    for (_t, a, b), (_g, ga, gb) in zip(frames, got, strict=True):
        assert np.array_equal(ga, a) and np.array_equal(gb, b)
    bad = FrameSpool(tmp_path / "no-such-folder" / "frames.stream")
    bad.send(*frames[0])
    bad.close()
    assert bad.failed is not None and bad.failed.startswith("cannot write the frame spool") and "\n" not in bad.failed
    assert bad.n_frames == 0
    cut = tmp_path / "cut.stream"
    cut.write_bytes((tmp_path / "frames.stream").read_bytes()[:-40])
    with pytest.raises(StreamError, match="ended after"):
        list(read_stream(cut))
