"""End to end: two fake GigE cameras (in-process Aravis GvFakeCamera on 127.0.0.2/.3 inside a private network
namespace), software-triggered at each TRIGGER event, paired, recorded, verified and exported.

Each run is ``python -m bracketry.testing.simrun`` in ``unshare --net`` (the test process stays in the host
namespace); its JSON summary is the ground truth (what was fired, dropped, served, counted by the streams).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bracketry.cli import main as cli_main
from bracketry.testing.simrun import sim_pixels
from bracketry_base.recording import topics as T
from bracketry_base.recording.verify import verify_recording
from bracketry_rig.cameras.netns import netns_argv, netns_available
from bracketry_rig.recording.session import PRIMING_EXPOSURE_US
from bracketry_testkit import missing_component, stop_process

pytestmark = [pytest.mark.aravis,
              pytest.mark.filterwarnings("ignore::DeprecationWarning:mcap_ros2.reader")]
FPS = 10  # pulses per second; the fake cameras keep up at this rate on a loaded 2-core machine


def need_netns() -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")


def simrun_argv(out: Path, summary: Path, *args: str) -> list[str]:
    return [sys.executable, "-m", "bracketry.testing.simrun", "--out", str(out), "--summary", str(summary),
            "--fps", str(float(FPS)), *args]


def run_sim(tmp_path: Path, *args: str, timeout_s: float = 240) -> tuple[Path, dict]:
    need_netns()
    out, summary = tmp_path / "rec", tmp_path / "summary.json"
    res = subprocess.run(netns_argv(simrun_argv(out, summary, *args)), capture_output=True, text=True,
                         timeout=timeout_s)
    assert res.returncode == 0, res.stderr[-2000:]
    return out, json.loads(summary.read_text())


BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]


def produced(summary: dict, side: str) -> int:
    """Frames the fake camera produced for the fired pulses (priming frames excluded)."""
    return sum(1 for e in summary["served_exposures_us"][side] if e != PRIMING_EXPOSURE_US)


def assert_fake_was_exact(summary: dict, skipped: dict[str, set[int]] | None = None) -> None:
    """Both fakes served exactly one frame per pulse they were fired for, with that pulse's exposure.

    The fake camera stamps and exposes each frame at its trigger and never merges two triggers
    (``bracketry_rig.cameras.fake``), whatever the load: a test whose fake did otherwise is a fake's defect, not
    luck."""
    for s in ("left", "right"):
        want = [BRACKETS[k % 6] for k in range(summary["fired"]) if k not in (skipped or {}).get(s, set())]
        served = [e for e in summary["served_exposures_us"][s] if e != PRIMING_EXPOSURE_US]
        assert served == want, (s, len(served), len(want))


def frame_metas(rec: Path, side: str) -> list:
    """The FrameMeta messages of ``side`` recorded in ``rec``, in recording order."""
    from bracketry_base.recording.decode import decode
    from bracketry_base.recording.reader import RecordingReader

    return [decode(m.schema_name, m.data) for f in sorted(rec.glob("*.mcap"))
            for m in RecordingReader(f).messages({T.frame_meta_topic(side)})]


def recorded_frames(rec: Path) -> dict[str, dict[int, tuple[str, np.ndarray]]]:
    """side -> trigger_seq -> (status, image) of every frame recorded in ``rec`` with pixels (image and metadata
    share their log time)."""
    from bracketry_base.recording.decode import decode, decode_image_msg
    from bracketry_base.recording.reader import RecordingReader

    out: dict[str, dict[int, tuple[str, np.ndarray]]] = {"left": {}, "right": {}}
    for f in sorted(rec.glob("*.mcap")):
        metas, images = {}, {}
        for side in out:
            topics = {T.image_topic(side), T.frame_meta_topic(side)}
            for m in RecordingReader(f).messages(topics):
                if m.topic == T.image_topic(side):
                    images[(side, m.log_time)] = decode_image_msg(m.data).image
                else:
                    meta = decode(m.schema_name, m.data)
                    metas[(side, m.log_time)] = meta
        for key, meta in metas.items():
            if key in images:  # (a buffer without pixels has no image message)
                out[key[0]][int(meta.trigger_seq)] = (meta.status, images[key])
    return out


def test_record_10s_verify_clean_and_export_round_trips_pixels(tmp_path: Path) -> None:
    rec, summary = run_sim(tmp_path, "--seconds", "10", "--width", "160", "--height", "100")
    fired = summary["fired"]
    assert fired == 10 * FPS
    assert_fake_was_exact(summary)
    report = verify_recording(rec)
    assert report.ok, report.problems
    assert cli_main(["verify", str(rec)]) == 0
    n_frames = {}
    for side in ("left", "right"):
        sr = report.sides[side]
        # every frame the camera sent is recorded; every pulse it did not answer is a drop, nothing else
        assert sr.frames == sr.images == produced(summary, side) == summary["streams"][side]["frames"] - \
            summary["pairing"]["sides"][side]["before_start"]
        assert sr.drops == fired - sr.frames
        assert sr.incomplete == sr.bracket_order_breaks == sr.missing_packets == 0
        n_frames[side] = sr.frames

    # independent readers
    files = sorted(rec.glob("*.mcap"))
    from rosbags.highlevel import AnyReader

    with AnyReader(files) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert (counts[T.image_topic("left")], counts[T.image_topic("right")]) == (n_frames["left"], n_frames["right"])
    assert counts[T.TRIGGER_TOPIC] == fired and counts[T.STATUS_TOPIC] >= 10
    from mcap_ros2.reader import read_ros2_messages

    metas = [m.ros_msg for m in read_ros2_messages(str(files[0]), topics=[T.frame_meta_topic("left")])]
    assert len(metas) == n_frames["left"] and all(m.status == "success" for m in metas)
    assert [m.trigger_seq for m in metas] == list(range(fired)) and all(m.paired for m in metas)

    # BorealHDR export: every pixel equals what the fake camera served for that side and exposure
    import cv2

    from bracketry_base.recording.decode import decode_image_msg
    from bracketry_base.recording.reader import RecordingReader

    stored = {}
    for f in files:
        for m in RecordingReader(f).messages({T.image_topic("left"), T.image_topic("right")}):
            img = decode_image_msg(m.data)
            stored[(m.topic.split("/")[2], img.stamp_ns)] = img.image

    out = tmp_path / "tree"
    assert cli_main(["export", str(rec), "--format", "borealhdr", "--out", str(out), "-q"]) == 0
    stamps = {}
    for side in ("left", "right"):
        pngs = sorted((out / f"camera_{side}").glob("*/*.png"))
        assert len(pngs) == n_frames[side]
        assert {p.parent.name for p in pngs} == {"1.0", "2.0", "4.0", "8.0", "16.0", "32.0"}
        candidates = {e: sim_pixels(side, e, 160, 100) for e in BRACKETS}
        for p in pngs:
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            assert img.dtype == np.uint16
            assert np.array_equal(img, stored[(side, int(p.stem))])  # export round-trips the recording exactly
            exposure_us = round(float(p.parent.name) * 1000)
            assert np.array_equal(img, candidates[exposure_us]), p  # exactly what the camera served for that pulse
        stamps[side] = {p.name for p in pngs}
    assert n_frames["left"] == n_frames["right"] == fired
    assert stamps["left"] == stamps["right"]  # left and right share their trigger's timestamp

    # ROS 1 bag with the upstream metadata topic
    bag = tmp_path / "rec.bag"
    assert cli_main(["export", str(rec), "--format", "rosbag1", "--out", str(bag)]) == 0
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/stereo/camera1/metadata"]
        exposures = [reader.deserialize(raw, c.msgtype).ExposureTime for c, _t, raw in reader.messages(conns)]
    assert len(exposures) == n_frames["left"]
    assert set(exposures) == {float(b) for b in BRACKETS}


def test_packet_loss_dropped_events_and_missed_trigger_are_all_reported(tmp_path: Path) -> None:
    rec, summary = run_sim(tmp_path, "--seconds", "6", "--width", "160", "--height", "100", "--lost-ratio", "0.002",
                           "--packet-size", "576", "--drop-events", "7,33,45", "--skip-trigger", "right:50")
    fired = summary["fired"]
    report = verify_recording(rec)
    assert not report.ok
    assert report.events_missing_seqs == [7, 33, 45]
    for side in ("left", "right"):
        sr = report.sides[side]
        stream = summary["streams"][side]
        # every frame fired is either recorded or reported as a drop
        assert sr.frames + sr.drops == fired
        # every pulse without a frame is reported (the one the right camera never saw, any the fake missed)
        assert sr.drops >= fired - produced(summary, side) - (side == "right")
        # every incomplete buffer the stream saw is reported
        ignored = summary["pairing"]["sides"][side]["before_start"]  # priming frames, before every pulse
        assert stream["frames_incomplete"] - ignored <= sr.incomplete <= stream["frames_incomplete"]
        assert sr.missing_packets <= stream["n_missing_packets"]
        if sr.incomplete:
            assert sr.missing_packets > 0
        # frames of the three seqs without events are unpaired, and listed
        for seq in (7, 33, 45):
            if seq not in sr.seqs.get("drops", []):
                assert seq in sr.seqs["unpaired"]
    assert summary["streams"]["left"]["frames_incomplete"] + summary["streams"]["right"]["frames_incomplete"] > 0
    # the fakes did exactly what they were asked: the right camera never saw pulse 50
    assert_fake_was_exact(summary, {"right": {50}})
    # that pulse, and only it, is the right camera's drop (its frames after it re-synced on their own pulses)
    assert report.sides["right"].seqs.get("drops", []) == [50], report.sides["right"].seqs
    assert report.sides["left"].seqs.get("drops", []) == [], report.sides["left"].seqs
    # no frame is labelled with another pulse's exposure: every complete frame holds the pixels of its pulse's bracket
    frames = recorded_frames(rec)
    for side, by_seq in frames.items():
        for seq, (status, image) in by_seq.items():
            if status == "success":
                assert np.array_equal(image, sim_pixels(side, BRACKETS[seq % 6], 160, 100)), (side, seq)
    assert sum(status == "success" for by_seq in frames.values() for status, _ in by_seq.values()) > fired


@pytest.mark.parametrize("seed", [3, 4])
def test_under_heavy_packet_loss_every_drop_is_a_lost_frame_and_every_frame_has_its_pulse(tmp_path: Path,
                                                                                        seed: int) -> None:
    """1 % GVSP packet loss (four frames in ten incomplete, some without their leader: no id, no timestamp), three
    missed triggers: the drops are the missed pulses and the frames the stream never delivered, nothing else; every
    complete frame holds its own pulse's pixels. Seeds 3 and 4 each lose whole frames and leaders next to a skip."""
    skipped = {"right": {50}, "left": {23, 24}}
    rec, summary = run_sim(tmp_path, "--seconds", "6", "--width", "160", "--height", "100", "--lost-ratio", "0.01",
                           "--packet-size", "576", "--skip-trigger", "right:50,left:23,left:24", "--seed", str(seed))
    assert_fake_was_exact(summary, skipped)
    report = verify_recording(rec)
    for side in ("left", "right"):
        drops = set(report.sides[side].seqs.get("drops", []))
        assert skipped[side] <= drops, (side, sorted(drops))
        # the other drops are frames the camera sent whose ids never arrived
        assert len(drops - skipped[side]) == summary["streams"][side]["skipped_ids"], (side, sorted(drops))
        # a frame is unpaired only where the other camera has no frame, or it is a second buffer of a frame already
        # recorded on that pulse (Aravis hands over a frame id again when packets of a timed-out frame come late)
        other = "left" if side == "right" else "right"
        other_drops = set(report.sides[other].seqs.get("drops", []))
        metas = frame_metas(rec, side)
        ids = {(m.trigger_seq, m.cam_frame_id) for m in metas if m.paired or m.trigger_seq in other_drops}
        for m in metas:
            if not m.paired and m.trigger_seq not in other_drops:
                assert m.note in ("late", "duplicate") and (m.trigger_seq, m.cam_frame_id) in ids, (side, m)
    frames = recorded_frames(rec)
    complete = [(side, seq, image) for side, by_seq in frames.items() for seq, (status, image) in by_seq.items()
                if status == "success"]
    assert len(complete) > summary["fired"] // 2
    for side, seq, image in complete:
        assert np.array_equal(image, sim_pixels(side, BRACKETS[seq % 6], 160, 100)), (side, seq)


def test_with_the_stm32_trigger_simulator(tmp_path: Path) -> None:
    """TRIGGER events from the trigger simulator (wire protocol on a pty, TriggerClient, clock model)."""
    rec, summary = run_sim(tmp_path, "--trigger", "simulator", "--seconds", "4", "--width", "160", "--height", "100")
    report = verify_recording(rec)
    assert summary["fired"] == report.events == 4 * FPS
    for side in ("left", "right"):
        sr = report.sides[side]
        assert sr.frames == produced(summary, side) and sr.drops == summary["fired"] - sr.frames
        assert sr.incomplete == sr.bracket_order_breaks == 0
    assert_fake_was_exact(summary)
    assert report.ok, report.problems


def test_kill_9_loses_at_most_one_second(tmp_path: Path) -> None:
    need_netns()
    out, summary, progress = tmp_path / "rec", tmp_path / "s.json", tmp_path / "progress.txt"
    argv = netns_argv(simrun_argv(out, summary, "--seconds", "60", "--width", "160", "--height", "100",
                                  "--progress", str(progress)))
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if progress.exists() and len(progress.read_text().splitlines()) >= 40:
                break
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            time.sleep(0.1)
        os.kill(proc.pid, signal.SIGKILL)  # unshare and sh exec'd: this is the recording process itself
        proc.wait(timeout=10)
    finally:
        stop_process(proc)
    assert proc.returncode == -signal.SIGKILL
    last_fired = int(progress.read_text().splitlines()[-1].split()[0])
    report = verify_recording(out)
    assert report.readable and report.truncated
    lost_s = (last_fired - report.last_seq) / FPS
    assert lost_s <= 1.0, f"{lost_s:.2f} s lost (last fired {last_fired}, last recorded {report.last_seq})"
    assert cli_main(["verify", str(out), "--repair"]) == 1
    assert list(out.glob("*.repaired.mcap"))


def test_disk_full_stops_cleanly(tmp_path: Path) -> None:
    need_netns()
    mnt, keep, summary = tmp_path / "small", tmp_path / "kept", tmp_path / "s.json"
    mnt.mkdir()
    keep.mkdir()
    sim = " ".join(f"'{a}'" for a in simrun_argv(mnt, summary, "--seconds", "12", "--width", "640",
                                                   "--height", "400"))
    script = (f"mount -t tmpfs -o size=256k tmpfs '{mnt}' || exit 97; {sim}; rc=$?; cp '{mnt}'/*.mcap '{keep}'/; "
              f"umount '{mnt}'; exit $rc")
    argv = ["unshare", "--mount", *netns_argv(["sh", "-c", script])]
    res = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    if res.returncode == 97:
        missing_component(f"cannot mount a tmpfs in a private mount namespace: {res.stderr.strip()[:200]}")
    assert res.returncode == 3, res.stderr[-2000:]
    assert "disk full" in res.stderr and "Traceback" not in res.stderr
    data = json.loads(summary.read_text())
    assert data["recorder"]["error"].startswith("recording stopped: disk full")
    assert data["recorder"]["lost_after_error"] > 0
    files = list(keep.glob("*.mcap"))
    assert len(files) == 1
    report = verify_recording(files[0])
    assert report.readable and report.truncated and report.sides["left"].frames > 0


@pytest.mark.slow
def test_clean_two_minute_run_has_no_false_positives(tmp_path: Path) -> None:
    rec, summary = run_sim(tmp_path, "--seconds", "120", "--width", "160", "--height", "100", "--split-s", "45",
                           timeout_s=400)
    report = verify_recording(rec)
    assert len(list(rec.glob("*.mcap"))) == 3  # split every 45 s
    assert summary["fired"] == 120 * FPS
    assert_fake_was_exact(summary)
    for side in ("left", "right"):
        sr = report.sides[side]
        # no false positives: the fakes answered every pulse, so nothing is a drop, a re-sync or unpaired
        assert sr.frames == summary["fired"] and sr.drops == sr.timestamp_mismatches == sr.unpaired == 0, \
            report.problems
        assert sr.incomplete == sr.bracket_order_breaks == sr.missing_packets == 0
    assert report.ok, report.problems
