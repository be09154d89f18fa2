"""The simulated backpack end to end and under faults: fake GigE cameras, trigger simulator, panel firmware simulator
and the daemon, driven by panel button presses (``bracketry.testing.faults`` scenarios, each one run in its own private
network namespace; the test process stays outside and asserts on the scenario's JSON result, the daemon's JSON logs,
the panel screen and the recorded files).

Ground truth for drops: the Aravis fake camera may miss a software trigger under machine load; what each fake camera
really served (``FakeCameraServer.exposures()``) is compared with what ``verify`` reports, so a reported drop must be
a frame the camera never sent (no false positives).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from bracketry.cli import main as cli_main
from bracketry.testing.faults import scenario_argv
from bracketry_base.recording import topics as T
from bracketry_base.recording.decode import decode
from bracketry_base.recording.reader import RecordingReader
from bracketry_base.recording.verify import VerifyReport, recording_files, verify_recording
from bracketry_rig.cameras.netns import netns_available
from bracketry_rig.recording.session import PRIMING_EXPOSURE_US
from bracketry_testkit import missing_component

pytestmark = [pytest.mark.aravis, pytest.mark.socat, pytest.mark.slow]
BRACKETS_US = [1000, 2000, 4000, 8000, 16000, 32000]
FPS = 10  # pulses per second: the fake cameras keep up at this rate on a loaded 2-core machine


def run_scenario(tmp_path: Path, scenario: str, *args: str, tmpfs_mb: int | None = None,
                 timeout_s: float = 240) -> dict[str, Any]:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    out, result = tmp_path / scenario, tmp_path / f"{scenario}.json"
    res = subprocess.run(scenario_argv(scenario, out, result, "--quiet", "--fps", str(FPS), *args, tmpfs_mb=tmpfs_mb),
                         capture_output=True, text=True, timeout=timeout_s)
    data = json.loads(result.read_text()) if result.exists() else {}
    log = (out / "daemon.log").read_text()[-3000:] if (out / "daemon.log").exists() else ""
    assert res.returncode == 0 and "error" not in data, (
        f"{data.get('error')}\n{data.get('traceback')}\nstderr: {res.stderr[-2000:]}\ndaemon.log: {log}")
    data["out"] = out
    return data


def step(result: dict[str, Any], name: str) -> dict[str, Any]:
    return next(s for s in result["steps"] if s["name"] == name)


def daemon_log(result: dict[str, Any]) -> list[dict[str, Any]]:
    """The daemon's structured log: every line is one JSON object."""
    lines = Path(result["daemon_log"]).read_text().splitlines()
    return [json.loads(line) for line in lines if line.strip()]


def logged(entries: list[dict[str, Any]], text: str, level: str | None = None) -> list[dict[str, Any]]:
    return [e for e in entries if text in e["msg"] and (level is None or e["level"] == level)]


def served_real(result: dict[str, Any], side: str, start: str, end: str) -> list[int]:
    """Exposures of the bracket frames the fake camera of ``side`` served between two steps (priming excluded)."""
    served = result["served"][side]
    return [e for e in served[step(result, start)["served_at"][side]:step(result, end)["served_at"][side]]
            if e != PRIMING_EXPOSURE_US]


def late_frames(exposures: list[int]) -> int:
    """Frames the fake camera served with another pulse's exposure (rendered late under machine load)."""
    return sum(1 for k, e in enumerate(exposures) if e != BRACKETS_US[k % 6])


def assert_matches_served(report: VerifyReport, served: dict[str, list[int]]) -> None:
    """Every frame a camera sent is recorded, and every drop verify reports is a pulse the camera did not answer.

    When the fake camera served every pulse with its exposure, the recording must verify clean. A frame the fake
    rendered late (with the next pulse's exposure) is a real anomaly of the camera; the pairing may then count one
    drop (and one event-less or doubled frame) per such frame, never more."""
    assert report.readable and not report.truncated, report.problems
    late = {side: late_frames(exposures) for side, exposures in served.items()}
    assert report.events > 0 and report.events_missing <= sum(late.values()), (report.problems, late)
    for side, exposures in served.items():
        sr = report.sides[side]
        # a late frame may land on its neighbour's trigger_seq ("two frames for trigger_seq k"): counted once
        assert len(exposures) - late[side] <= sr.frames == sr.images <= len(exposures), (side, sr, len(exposures))
        missed = report.events - len(exposures)  # pulses the fake camera never answered
        assert missed <= sr.drops <= missed + late[side], (side, sr.drops, report.events, len(exposures), late)
        assert sr.incomplete == sr.missing_packets == sr.bracket_order_breaks == 0, (side, sr)
    if not any(late.values()) and all(len(e) == report.events for e in served.values()):
        assert report.ok, report.problems  # the fakes answered every pulse with its exposure: clean


def assert_intact(report: VerifyReport) -> None:
    """A closed segment: complete file, no broken frame, no bracket-order break, no exposure mismatch."""
    assert report.readable and not report.truncated, report.problems
    assert report.events > 0 and report.events_missing == 0
    for side, sr in report.sides.items():
        assert sr.incomplete == sr.missing_packets == sr.bracket_order_breaks == sr.exposure_mismatches == 0, \
            (side, sr)
        assert sr.frames + sr.drops == report.events, (side, sr)


def test_simulated_rig_buttons_record_verify_sigterm_and_oneshot_record(tmp_path: Path) -> None:
    result = run_scenario(tmp_path, "e2e", "--seconds", "10", "--record-seconds", "10")
    # panel screen buffer: SENSORS -> IDLE, RECORD -> REC (free disk and FPS shown), RECORD -> IDLE + SAVED
    assert step(result, "ready")["seen"][0] == "L:OFF R:OFF TRIG:OFF"
    assert step(result, "idle")["seen"][0] == "L:IDL R:IDL TRIG:IDL"
    assert step(result, "rec")["seen"][0] == "L:REC R:REC TRIG:REC"
    rec_screen = step(result, "before_stop")["screen"]
    assert rec_screen[0] == "L:REC R:REC TRIG:REC" and rec_screen[3].startswith("RECORDING")
    fps = re.match(r"\s*([\d.]+)/\s*([\d.]+)", rec_screen[2])
    assert fps, rec_screen
    fps_left, fps_right = float(fps.group(1)), float(fps.group(2))
    assert fps_left > 3 and fps_right > 3  # 10 fps nominal; loose on a loaded machine
    cli = step(result, "before_stop")["status_cli"]  # `bracketry status` asks the running daemon
    assert cli["exit_code"] == 0 and "cam_left=REC  cam_right=REC  trigger=REC" in cli["stdout"], cli
    assert "recording: " in cli["stdout"] and "message: RECORDING" in cli["stdout"]
    cli_json = json.loads(step(result, "before_stop")["status_cli_json"]["stdout"])
    assert cli_json["ok"] and cli_json["state"]["states"]["trigger"] == "REC" and cli_json["state"]["free_disk_mb"] > 0
    stopped = step(result, "stopped")
    assert stopped["seen"][0] == "L:IDL R:IDL TRIG:IDL" and stopped["seen"][3].startswith("SAVED")
    assert stopped["states"]["cam_left"] == stopped["states"]["trigger"] == "IDLE" and stopped["recording"] is None
    # SIGTERM: clean exit
    assert result["daemon_exit_code"] == 0
    notes = result["sd_notify"]  # systemd notifications: ready, watchdog pings while alive, stopping
    assert notes[0] == "READY=1" and notes.count("WATCHDOG=1") >= 5 and "STOPPING=1" in notes, notes
    log = daemon_log(result)
    for text in ("button sensors", "button record", "segment rec_", "segment closed", "daemon stopped"):
        assert logged(log, text), text
    assert not logged(log, "", "ERROR")

    segments = [Path(p) for p in result["segments"]]
    assert len(segments) == 2 and all(p.name == "seg01" for p in segments)
    report = verify_recording(segments[0])
    assert report.events >= 8 * FPS  # ~10 s at 22 Hz
    assert_matches_served(report, {s: served_real(result, s, "idle", "stopped") for s in ("left", "right")})

    # `bracketry record --config F --duration 10s`: one-shot, verified by the command itself
    oneshot = verify_recording(segments[1])
    assert result["record"]["exit_code"] == (0 if oneshot.ok else 1), result["record"]
    assert "recording 10 s to" in result["record"]["stderr"]
    assert oneshot.events >= 8 * FPS
    assert_matches_served(oneshot, {s: served_real(result, s, "sigterm", "record_oneshot") for s in ("left", "right")})


def test_simulated_rig_faults_trigger_camera_panel_and_sigkill(tmp_path: Path) -> None:
    result = run_scenario(tmp_path, "faults", "--seconds", "3")
    log = daemon_log(result)
    all_segments = [Path(p) for p in result["segments"]]
    segments = [p for p in all_segments if p.parent == all_segments[0].parent]  # the recording the faults hit
    names = [p.name for p in segments]
    assert names[:4] == ["seg01", "seg02", "seg03", "seg04"], names

    # trigger simulator killed: ERR on panel and status, segment closed; restarted: REC again in a new segment
    err = step(result, "trigger_err")
    assert err["states"]["trigger"] == "ERR" and "TRIG:ERR" in err["seen"][0]
    assert logged(log, "trigger lost", "ERROR")
    back = step(result, "trigger_back")
    assert back["states"] == {**back["states"], "cam_left": "REC", "cam_right": "REC", "trigger": "REC"}
    assert back["seen"][0] == "L:REC R:REC TRIG:REC"
    seg1 = verify_recording(segments[0])  # the segment before the fault verifies (against what the fakes served)
    assert_matches_served(seg1, {s: served_real(result, s, "idle", "trigger_err") for s in ("left", "right")})

    # right camera off the network: ERR, the left camera records on in its own segment; back: both again
    cam_err = step(result, "camera_err")
    assert cam_err["states"]["cam_right"] == "ERR" and cam_err["states"]["cam_left"] == "REC"
    assert "R:ERR" in cam_err["seen"][0]
    assert "error cam_right: no frames" in cam_err["status_cli"]["stdout"], cam_err["status_cli"]
    assert logged(log, "camera right: no frame", "ERROR")
    assert step(result, "camera_back")["seen"][0] == "L:REC R:REC TRIG:REC"
    seg2, seg3 = verify_recording(segments[1]), verify_recording(segments[2])
    assert_intact(seg2)
    assert seg3.sides.keys() == {"left"}  # recording continued with what still works
    assert_intact(seg3)
    assert seg3.sides["left"].frames >= FPS // 2

    # panel rebooted: the daemon recorded on, the rebooted panel shows the state again
    down = step(result, "panel_down")
    assert down["states"]["cam_left"] == down["states"]["cam_right"] == down["states"]["trigger"] == "REC"
    assert step(result, "panel_back")["seen"][0] == "L:REC R:REC TRIG:REC"
    assert step(result, "panel_back")["segments"] == step(result, "panel_kill")["segments"]  # no new segment
    assert step(result, "panel_back")["panel"]["hellos"] >= 1  # the rebooted panel said HELLO
    assert logged(log, "(re)booted")
    assert step(result, "panel_back")["counters"]["trigger_events"] > down["counters"]["trigger_events"]

    # every closed segment is intact; all frames the fakes served went into some segment
    closed = [verify_recording(p) for p in segments[:-1]]
    for rep in closed:
        assert_intact(rep)

    # SIGKILL mid-recording: the last segment is truncated but recoverable, with <= 1 s lost
    assert result["daemon_exit_code"] == -9
    last = segments[-1]
    report = verify_recording(last)
    assert report.readable
    assert cli_main(["verify", "--repair", str(last)]) in (0, 1)
    repaired = sorted(last.glob("*.repaired.mcap"))
    truncated = [f for f in report.files if f["truncated"]]
    assert len(repaired) == len(truncated) >= 1
    stamps = [m.log_time for f in sorted(last.glob("*.mcap")) if not f.name.endswith(".repaired.mcap")
              for m in RecordingReader(f).messages({"/stereo/left/frame_meta"})]
    assert recording_files(last) == repaired  # from now on the repaired copy stands in for the truncated file
    rstamps = [m.log_time for f in repaired for m in RecordingReader(f).messages({"/stereo/left/frame_meta"})]
    assert rstamps and max(rstamps) == max(stamps)
    lost_s = (result["t_kill_ns"] - max(rstamps)) / 1e9
    assert -0.5 < lost_s <= 1.0, lost_s  # host clock both sides: the kill time and the frames' log times
    clean = verify_recording(repaired[0])
    assert clean.readable and not clean.truncated and clean.events > 0
    # a new daemon (systemd restarts it) comes up over the stale socket and brings the sensors up again
    assert step(result, "restarted_idle")["seen"][0] == "L:IDL R:IDL TRIG:IDL"
    # SIGTERM while the restarted daemon records: exit 0, its recording closed cleanly (footer, nothing lost)
    assert result["restarted_exit_code"] == 0
    after = [p for p in all_segments if p.parent != segments[0].parent]
    assert len(after) == 1 and after[0].name == "seg01", all_segments
    final = verify_recording(after[0])
    assert_intact(final)
    assert final.events >= FPS // 2


def test_simulated_rig_disk_filling_stops_cleanly_and_refuses_idle_camera_recovers(tmp_path: Path) -> None:
    try:
        probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "true"], capture_output=True,
                               timeout=10)
    except (OSError, subprocess.TimeoutExpired) as exc:
        missing_component(f"unshare --mount failed: {exc}")
    if probe.returncode != 0:
        missing_component(f"private mount namespace unavailable: {probe.stderr.decode()[:200]}")
    result = run_scenario(tmp_path, "disk", "--min-free-mb", "32", "--stop-free-mb", "16", tmpfs_mb=64)
    assert step(result, "filling")["free_mb"] > 32
    full = step(result, "disk_full")
    assert full["states"]["cam_left"] == full["states"]["trigger"] == "IDLE" and full["recording"] is None
    assert "DISK FULL" in full["seen"][3]
    refused = step(result, "refused")
    assert "DISK LOW" in refused["seen"][3] and refused["recording"] is None
    log = daemon_log(result)
    assert logged(log, "stop_free_mb 16: stopping the recording", "ERROR")
    assert logged(log, "recording refused", "ERROR")
    assert not logged(log, "recorder failed")
    # idle camera off the network: ERR (GVCP check), back: IDLE without any button
    assert "L:ERR" in step(result, "idle_camera_err")["seen"][0]
    assert logged(log, "camera left: no answer while idle", "ERROR")
    assert step(result, "idle_camera_back")["seen"][0] == "L:IDL R:IDL TRIG:IDL"
    assert result["daemon_exit_code"] == 0
    reports = result["verify"]
    assert len(reports) == 1
    rep = reports[0]
    assert rep["readable"] and not rep["truncated"] and rep["events"] >= 2 * FPS
    for side in ("left", "right"):
        sr = rep["sides"][side]
        assert sr["incomplete"] == sr["missing_packets"] == sr["bracket_order_breaks"] == 0
        assert sr["frames"] + sr["drops"] == rep["events"]


def test_simulate_cli_prints_the_panel_screen_and_verifies(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    out = tmp_path / "sim"
    res = subprocess.run([sys.executable, "-m", "bracketry", "simulate", "--duration-s", "3", "--out", str(out),
                          "--resolution", "160x100", "--fps", str(FPS), "--no-world"],
                         capture_output=True, text=True, timeout=240)
    summary = json.loads((out / "simulation.json").read_text())
    assert res.returncode == (0 if summary["ok"] else 1), res.stderr[-3000:]
    for screen_line in ("|L:IDL R:IDL TRIG:IDL|", "|L:REC R:REC TRIG:REC|", "|SAVED               |"):
        assert screen_line in res.stderr  # the panel screen, printed as it changes
    assert summary["session"]["daemon_exit_code"] == 0
    (report,) = summary["verify"]
    assert report["readable"] and not report["truncated"] and report["events"] >= 2 * FPS
    assert ("verified clean" if summary["ok"] else "PROBLEMS FOUND") in res.stdout


@pytest.mark.qemu
def test_simulated_rig_with_the_real_trigger_firmware_in_qemu(tmp_path: Path) -> None:
    """`bracketry simulate --trigger qemu`: the STM32 ELF in QEMU fires the software triggers of the fake cameras
    through the daemon (wire protocol over QEMU's serial port); the recording is paired and verifies."""
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    out = tmp_path / "simq"
    res = subprocess.run([sys.executable, "-m", "bracketry", "simulate", "--trigger", "qemu", "--duration-s", "3",
                          "--out", str(out), "--resolution", "160x100", "--fps", str(FPS), "--no-world"],
                         capture_output=True, text=True, timeout=300)
    summary = json.loads((out / "simulation.json").read_text())
    assert res.returncode == (0 if summary["ok"] else 1), res.stderr[-3000:]
    assert "|L:REC R:REC TRIG:REC|" in res.stderr
    assert summary["session"]["daemon_exit_code"] == 0
    (report,) = summary["verify"]  # only this run's recording
    assert report["readable"] and not report["truncated"] and report["events"] >= 2 * FPS
    for side in ("left", "right"):
        sr = report["sides"][side]
        assert sr["frames"] + sr["drops"] == report["events"] and sr["frames"] >= report["events"] // 2, (side, sr)
        assert sr["bracket_order_breaks"] == sr["exposure_mismatches"] == 0, (side, sr)
    log = (out / "daemon.log").read_text()
    assert "trigger" in log and "segment closed" in log


def test_monitor_previews_while_idle_then_a_normal_recording(tmp_path: Path) -> None:
    """With the monitor on, sensors up and not recording stream to the previews only (nothing on disk); a bracket
    table applied while idle reaches the previews; a recording then records normally and the previews resume."""
    result = run_scenario(tmp_path, "preview", "--seconds", "4")
    table, new_table = result["brackets_us"], result["applied_us"]
    assert step(result, "ready")["previews"] == {}
    idle = step(result, "idle_previews")
    assert idle["states"] == {**idle["states"], "cam_left": "IDLE", "cam_right": "IDLE", "trigger": "IDLE"}
    assert idle["recording"] is None and idle["files"] == [], idle["files"]  # previews only: nothing written
    for side in ("left", "right"):
        assert [idle["previews"][side][str(k)]["exposure_us"] for k in range(len(table))] == table
        assert idle["status"]["cameras"][side]["state"] == "IDLE" and idle["status"]["cameras"][side]["frames"] > 0
    assert not idle["status"]["recording"]["active"]
    applied = step(result, "applied_previews")
    assert applied["applied"] == [200, {"ok": True, "brackets_us": new_table}], applied["applied"]
    assert applied["files"] == []
    for side in ("left", "right"):
        assert [applied["previews"][side][str(k)]["exposure_us"] for k in range(len(new_table))] == new_table
    resumed = step(result, "resumed_previews")  # after the recording: previews again, sensors still on
    assert resumed["states"] == {**resumed["states"], "cam_left": "IDLE", "cam_right": "IDLE", "trigger": "IDLE"}
    assert resumed["recording"] is None and resumed["status"]["sensors_on"]
    assert result["daemon_exit_code"] == 0
    log = daemon_log(result)
    assert len(logged(log, "previews started")) >= 3 and logged(log, "previews stopped")
    assert not logged(log, "", "ERROR")

    segments = [Path(p) for p in result["segments"]]
    assert [p.name for p in segments] == ["seg01"]  # the one recording; the previews wrote nothing
    report = verify_recording(segments[0])
    assert_intact(report)
    assert report.events >= 3 * FPS and report.sides.keys() == {"left", "right"}
    recorded_us = {int(decode(m.schema_name, m.data).exposure_us) for f in recording_files(segments[0])
                   for m in RecordingReader(f).messages({T.TRIGGER_TOPIC})}
    assert recorded_us == set(new_table)  # the table applied while idle is the one recorded
