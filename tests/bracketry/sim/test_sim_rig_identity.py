"""The simulated rig records while other processes load both cores, and while its frames are still being rendered:
every recorded frame shows the rendered frame whose index it carries, and the ground truth gives it that frame's
pose (not one found by counting frames or triggers). ``bracketry simulate`` runs as a user runs it (its own private
network namespace); the test reads the recordings, the kept frame files and ``groundtruth.txt``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from bracketry.sim.frames import frame_time_s, read_frame_id
from bracketry_base.recording import topics as T
from bracketry_base.recording.decode import decode, decode_image_msg
from bracketry_base.recording.reader import RecordingReader
from bracketry_rig.cameras.netns import netns_available
from bracketry_testkit import missing_component

pytestmark = [pytest.mark.aravis, pytest.mark.socat, pytest.mark.slow]
BRACKETS_US = [1000, 2000, 4000, 8000, 16000, 32000]
HOG = "import time\nend = time.monotonic() + {s}\nwhile time.monotonic() < end:\n    pass\n"


@contextmanager
def cpu_hogs(n: int = 2, seconds: float = 150.0) -> Iterator[None]:
    """``n`` busy processes (one per core) that stop by themselves after ``seconds`` (ended at exit anyway)."""
    procs = [subprocess.Popen([sys.executable, "-c", HOG.format(s=seconds)]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait(10)


def test_simulated_rig_under_load_gives_each_frame_the_pose_of_the_frame_it_shows(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    out = tmp_path / "rig"
    w, h, fps = 320, 200, 10.0
    # 600 s of world: far more than the few seconds recorded, so rendering is still running while the rig records
    cmd = [sys.executable, "-m", "bracketry", "simulate", "--seconds", "5", "--out", str(out), "--resolution",
           f"{w}x{h}", "--fps", f"{fps:g}", "--world-seconds", "600", "--keep-frames"]
    with cpu_hogs():
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            stdout, stderr = proc.communicate(timeout=300)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the simulation and everything it started (its own session)
            stdout, stderr = proc.communicate(timeout=30)
    res = subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)
    summary_path = out / "simulation.json"
    assert summary_path.is_file(), res.stdout[-2000:] + res.stderr[-2000:]
    summary = json.loads(summary_path.read_text())
    # recording started before rendering finished: the first recorded frame predates the end of rendering
    assert summary["first_frame_ns"] is not None
    assert summary["render_done_ns"] is None or summary["first_frame_ns"] < summary["render_done_ns"]
    # and did not wait for the whole render (600 s of world: about 400 CPU-s at this size, more beside the busy
    # loops); the rig's start-up alone took up to 67 s on a machine loaded beyond the test's own busy loops
    assert (summary["first_frame_ns"] - summary["started_ns"]) / 1e9 < 180.0

    rendered = {s: np.load(out / "dev" / "frames" / f"frames_{s}.npy", mmap_mode="r") for s in ("left", "right")}
    n_frames = rendered["left"].shape[0]
    recorded: dict[str, list[tuple[int, int | None]]] = {"left": [], "right": []}
    labelled: dict[tuple[str, int], int] = {}  # (side, frame stamp) -> the exposure its pulse gave it
    for seg in summary["recordings"]:
        for f in sorted(Path(seg).glob("*.mcap")):
            for msg in RecordingReader(f).messages({T.frame_meta_topic(s) for s in recorded}):
                meta = decode("bracketry_msgs/msg/FrameMeta", msg.data)
                side = "left" if msg.topic == T.frame_meta_topic("left") else "right"
                labelled[(side, meta.trigger_host_ns)] = meta.exposure_us
            for msg in RecordingReader(f).messages({T.image_topic(s) for s in recorded}):
                side = "left" if msg.topic == T.image_topic("left") else "right"
                img = decode_image_msg(msg.data)
                k = read_frame_id(img.image)
                if k is not None:  # the recorded pixels are exactly those of the rendered frame it names
                    assert np.array_equal(img.image, rendered[side][k % n_frames]), (side, k)
                recorded[side].append((img.stamp_ns, k))
                # the image shows the exposure its pulse set (a camera that lost its first trigger, or a late fill,
                # must not give a frame its neighbour's exposure)
                assert k is None or labelled.get((side, img.stamp_ns)) == BRACKETS_US[k % 6], (side, k)
    for side in recorded:
        assert len(recorded[side]) >= 20, (side, len(recorded[side]))
        known = [k for _t, k in recorded[side] if k is not None]
        assert len(known) == len(recorded[side]), f"{side}: {len(known)} of {len(recorded[side])} identified"
    # the renderer kept ahead: every bracket frame showed its own rendered frame (the world never held), as idle
    assert summary["frames_held_for_renderer"] == 0

    # the ground truth: one pose per identified left frame, the world's pose at that frame's time; the rest listed
    from bracketry_emulator.synth import World

    world = World("forest-winter", seed=0, resolution=(w, h))
    gt: list[tuple[int, np.ndarray]] = []
    for line in (out / "groundtruth.txt").read_text().splitlines():
        if line.startswith("#"):
            continue
        sec, _, frac = line.split()[0].partition(".")
        gt.append((int(sec) * 1_000_000_000 + int(frac.ljust(9, "0")), np.array([float(x) for x in line.split()[1:]])))
    unknown_file = out / "groundtruth_unknown.txt"
    unknown = [int(x) for x in unknown_file.read_text().split()] if unknown_file.exists() else []
    assert summary["groundtruth"]["unknown"] == len(unknown)
    # both images of a stereo pair show the same rendered frame (one world time per pair), late fills included
    right_by_t = dict(recorded["right"])
    split_pairs = [(t, k, right_by_t[t]) for t, k in recorded["left"]
                   if k is not None and right_by_t.get(t) is not None and right_by_t[t] != k]
    assert not split_pairs, f"stereo pairs of two rendered frames: {split_pairs[:5]}"
    # a pair whose right image carries no identity has no known pose either
    left = sorted(((t, k if right_by_t.get(t, k) == k else None) for t, k in recorded["left"]), key=lambda tk: tk[0])
    assert len(left) == summary["groundtruth"]["frames"]
    assert sorted(t for t, k in left if k is None) == sorted(unknown)
    known_left = [(t, k) for t, k in left if k is not None]
    assert len(gt) == len(known_left)
    for (t_ns, k), (gt_ns, pose) in zip(known_left, gt):
        assert gt_ns == t_ns, "the ground-truth stamp is the recorded frame's own"
        T_wc = world.pose(frame_time_s(k, BRACKETS_US, fps))
        assert np.allclose(pose[:3], T_wc[:3, 3], atol=1e-5), (k, pose[:3], T_wc[:3, 3])
