"""``bracketry simulate --duration-s N --out DIR``: the whole rig on this machine, driven by scripted button presses."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import click

from bracketry.sim.clock import MONOTONIC, Clock
from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    SEED,
    Duration,
    Integer,
    Number,
    input_dir,
    option,
    output_dir,
    overwrite_option,
    parse_resolution,
)


@click.command("simulate")
@option("--duration-s", "seconds", aliases=("--seconds",), type=Duration(3600.0), default=10.0, show_default=True,
        help="How long to record, in seconds (1 to 3600).")
@click.option("--out", "out_dir", required=True, type=output_dir(),
              help="Folder (new or empty) for the recordings, logs, config, panel screen and summary.")
@overwrite_option()
@click.option("--trigger", type=click.Choice(["simulator", "qemu"]), default="simulator", show_default=True,
              help="The Python trigger simulator, or the real firmware ELF in QEMU (no timing fidelity).")
@click.option("--resolution", default="640x400", show_default=True, help="Camera resolution WIDTHxHEIGHT.")
@click.option("--fps", type=Number(1.0, 60.0), default=22.0, show_default=True,
              help="Trigger rate: frames per second per camera (1 to 60).")
@click.option("--preset", type=click.Choice(["forest-winter", "campus-summer"]), default="forest-winter",
              show_default=True, help="Synthetic world.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the synthetic world.")
@click.option("--no-world", is_flag=True, help="Serve a test pattern instead of the synthetic world.")
@click.option("--monitor", "monitor_port", type=Integer(1024, 65535), default=None,
              help="Serve the browser monitor on 127.0.0.1:PORT (the URL with its token is printed).")
@click.option("--world-seconds", type=Number(1.0, 36000.0), default=None,
              help="Seconds of distinct world frames (later frames repeat them) [default: --duration-s + 5].")
@click.option("--keep-frames", is_flag=True,
              help="Keep the rendered frames in OUT/dev/frames (default: in memory, removed at the end).")
@click.option("--calibration", type=input_dir(), default=None,
              help="Stereo calibration folder (bracketry calibrate solve --out) the rig config names "
                   "(rig.calibration): every recording carries it and export writes it as calibration/.")
@click.option("--render-ahead", is_flag=True,
              help="Start recording only once the renderer will stay ahead of the cameras for the whole recording, "
                   "however long that takes (default: at the latest 7 s after the start; a renderer behind then "
                   "holds the world, which a loaded machine shows as repeated frames).")
def command(seconds: float, out_dir: Path, overwrite: bool, trigger: str, resolution: str, fps: float, preset: str,
            seed: int, no_world: bool, monitor_port: int | None, world_seconds: float | None,
            keep_frames: bool, calibration: Path | None, render_ahead: bool) -> int:
    """Run the simulated backpack: fake GigE cameras, trigger, panel firmware and the daemon under test."""
    if seconds < 1.0:
        raise BracketryError("--duration-s must be at least 1 s")
    res = parse_resolution(resolution)
    if calibration is not None:
        from bracketry_base.recording.calibration import read_calibration

        read_calibration(calibration)  # not a calibration: one line before anything starts
        calibration = calibration.resolve()
    from bracketry.sim.rig import in_private_netns, reexec_in_netns

    if not in_private_netns():
        bridge = None
        if monitor_port is not None:
            from bracketry.sim.rig import monitor_bridge_outside

            out_dir.mkdir(parents=True, exist_ok=True)
            bridge = monitor_bridge_outside(out_dir, monitor_port)
            _end_with_sigterm(bridge)
        try:
            # --out was checked here (before the bridge wrote into it): the re-executed process does not refuse it
            return reexec_in_netns([*sys.argv[1:], "--overwrite"] if sys.argv[1:2] == ["simulate"] else
                                   ["simulate", "--duration-s", str(seconds), "--out", str(out_dir), "--overwrite",
                                    "--trigger", trigger, "--resolution", resolution, "--fps", str(fps), "--preset",
                                    preset, "--seed", str(seed), *(["--no-world"] if no_world else []),
                                    *(["--monitor", str(monitor_port)] if monitor_port is not None else []),
                                    *(["--world-seconds", str(world_seconds)] if world_seconds else []),
                                    *(["--keep-frames"] if keep_frames else []),
                                    *(["--calibration", str(calibration)] if calibration else []),
                                    *(["--render-ahead"] if render_ahead else [])])
        finally:
            if bridge is not None:
                bridge.terminate()
                bridge.wait(timeout=10)
    return run(out_dir, seconds, trigger, res, fps, preset, seed, not no_world, monitor_port, world_seconds,
               keep_frames, calibration, lead_deadline_s=None if render_ahead else LEAD_DEADLINE_S)


def _end_with_sigterm(proc: subprocess.Popen) -> None:
    """On SIGTERM, end ``proc`` (a helper this process started), then terminate as SIGTERM would have."""

    def handler(signum: int, _frame: object) -> None:
        proc.terminate()
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)

    signal.signal(signal.SIGTERM, handler)


#: recording starts at the latest this long after the command (the rest of the session start follows: the first
#: frame is recorded within about 10 s)
LEAD_DEADLINE_S = 7.0


class RenderProgress:
    """Samples of the renderer's progress, (clock time, frames rendered): every 0.1 s on a thread from when the
    renderer was started (while the rig starts), so :func:`wait_for_lead` has its recent rate at once; with
    ``thread=False`` only when :meth:`sample` is called (:func:`wait_for_lead` samples on each of its steps)."""

    def __init__(self, schedule: Any, period_s: float = 0.1, clock: Clock = MONOTONIC, thread: bool = True) -> None:
        self._schedule = schedule
        self._clock = clock
        self.samples: list[tuple[float, int]] = []
        self.sample()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if thread:
            def sample() -> None:
                while not self._stop.wait(period_s):
                    self.sample()

            self._thread = threading.Thread(target=sample, name="bracketry-render-rate", daemon=True)
            self._thread.start()

    def sample(self, now_s: float | None = None, k: int | None = None) -> None:
        """Add a sample: ``k`` frames rendered at ``now_s`` (default: the schedule's count at the clock's time)."""
        self.samples.append((self._clock.now_s() if now_s is None else now_s,
                             self._schedule.rendered() if k is None else k))

    def rate(self, now_s: float, k: int, window_s: float = 1.0) -> float | None:
        """Frames per second per side over the last ``window_s`` (at least) before ``now_s``, when ``k`` frames are
        rendered; None before a whole window was sampled."""
        past = [(t, n) for t, n in self.samples if t <= now_s - window_s]
        if not past:
            return None
        t0_s, k0 = past[-1]
        return (k - k0) / (now_s - t0_s)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()


#: how often :func:`wait_for_lead` looks at the renderer's progress, seconds
LEAD_STEP_S = 0.1


def wait_for_lead(schedule: Any, seconds: float, fps: float, started_mono_s: float,
                  progress: RenderProgress | None = None, clock: Clock = MONOTONIC,
                  deadline_s: float | None = LEAD_DEADLINE_S) -> None:
    """Before recording: wait until the renderer, at the rate it has shown over the last second, will keep ahead of
    the cameras for the whole recording (every recorded frame then shows its own rendered frame: no world held), but
    no longer than ``deadline_s`` after the start (None: no deadline, at the latest until the recording's frames are
    all rendered), and at least until two seconds of frames are there.

    ``progress``: samples taken since the renderer was started (:class:`RenderProgress`), so the last second may lie
    while the rig was starting (without them the second is measured from now: ~1-2 s before every recording).
    ``clock``: the time ``started_mono_s`` and the samples are on, and the waits between looks (tests step it)."""
    schedule.wait(timeout_s=120.0, frames=round(2.0 * fps))
    needed = min(schedule.n_frames, round((seconds + 2.0) * fps))
    if progress is None:
        progress = RenderProgress(schedule, clock=clock, thread=False)
    while True:
        now_s, k = clock.now_s(), schedule.rendered()
        progress.sample(now_s, k)
        if k >= needed or (deadline_s is not None and now_s >= started_mono_s + deadline_s):
            return
        rate = progress.rate(now_s, k)  # frames per second per side
        if rate is not None and k + rate * seconds >= needed + fps:  # ahead until the end, one second to spare
            return
        if schedule.failed():
            raise BracketryError("the frame renderer failed")
        clock.sleep(LEAD_STEP_S)


def _read_frame_ids(rig: Any) -> None:
    with contextlib.suppress(Exception):
        rig.recorded_frame_ids("left")


def run(out_dir: Path, seconds: float, trigger: str, res: tuple[int, int], fps: float, preset: str, seed: int,
        world: bool, monitor_port: int | None = None, world_seconds: float | None = None,
        keep_frames: bool = False, calibration: Path | None = None,
        lead_deadline_s: float | None = LEAD_DEADLINE_S) -> int:
    """The simulation inside the private network namespace (``lead_deadline_s``: :func:`wait_for_lead`'s deadline;
    None waits for the renderer's lead however long it takes)."""
    import time

    from bracketry.sim.rig import SimOptions, SimulatedRig, summary_json
    from bracketry.sim.scenario import run_session
    from bracketry_base.recording.verify import format_report, verify_recording

    # SIGTERM ends the simulation through its clean-up (devices, daemon, renderers, the frames in /dev/shm)
    signal.signal(signal.SIGTERM, lambda signum, _frame: sys.exit(128 + signum))
    started_ns, started_mono_s = time.time_ns(), time.monotonic()
    opts = SimOptions(out_dir=out_dir, resolution=res, fps=fps, world_seconds=world_seconds or seconds + 5.0,
                      trigger=trigger, preset=preset, seed=seed, world=world, keep_frames=keep_frames,
                      echo=lambda s: click.echo(s, err=True), monitor_port=monitor_port, calibration=calibration)
    rig = SimulatedRig(opts)
    render_done_ns = None
    render_progress = None
    try:
        rig.prepare_frames()  # rendered ahead in a separate process while the rig starts and records
        render_progress = RenderProgress(rig.schedule)  # its recent rate is known when the rig is up
        rig.start()
        wait_for_lead(rig.schedule, seconds, fps, started_mono_s, render_progress, deadline_s=lead_deadline_s)
        render_progress.stop()
        session = run_session(rig, seconds)
        render_done_ns = rig.schedule.render_done_ns()
        rig.start_world_files()  # the ground truth's world is built on a thread while the recording is verified
    finally:
        if render_progress is not None:
            render_progress.stop()
        rig.close()
    # the frame ids (for the ground truth) are read on a thread while the recording is verified: ~0.7 s less for
    # the demo's 40 s; a failure there is raised again by the ground truth's own read below
    ids = threading.Thread(target=_read_frame_ids, args=(rig,), name="bracketry-frame-ids", daemon=True)
    ids.start()
    reports = [verify_recording(seg) for seg in rig.recordings()]
    ids.join()
    for r in reports:
        click.echo(format_report(r))
    gt = rig.write_groundtruth()
    first_ns = min((t for t, _k in rig.recorded_frame_ids("left")), default=None)
    summary = summary_json(rig, reports, {"session": session, "groundtruth": gt,
                                          "frame_mismatches": rig.schedule.mismatches if rig.schedule else None,
                                          "frames_without_identity": dict(rig.schedule.unidentified),
                                          "frames_waited_for_renderer": dict(rig.schedule.waited),
                                          "frames_held_for_renderer": rig.schedule.held,
                                          "started_ns": started_ns, "first_frame_ns": first_ns,
                                          "render_done_ns": render_done_ns})
    frames = {s: sum(r.sides[s].frames for r in reports if s in r.sides) for s in ("left", "right")}
    drops = {s: sum(r.sides[s].drops for r in reports if s in r.sides) for s in ("left", "right")}
    click.echo(f"simulated rig: recorded {session['recorded_s']} s, frames {frames}, drops {drops}, "
               f"{'verified clean' if summary['ok'] else 'PROBLEMS FOUND'}; summary {out_dir / 'simulation.json'}")
    if rig.schedule is not None and rig.schedule.held:
        click.echo(f"WARNING: the renderer fell behind the cameras: {rig.schedule.held} recorded frames show an "
                   "earlier rendered cycle (the world held); every pose is still the shown frame's, but the walk is "
                   "not that of an idle run")
    if first_ns is not None:
        click.echo(f"first frame recorded {(first_ns - started_ns) / 1e9:.1f} s after the start; rendering "
                   + ("still running then" if render_done_ns is None or render_done_ns > first_ns else
                      "had finished") + (" and stopped with the rig" if render_done_ns is None else ""))
    if gt is not None:
        unknown = f"; {gt['unknown']} frames WITHOUT a known pose (listed in groundtruth_unknown.txt)" \
            if gt["unknown"] else ""
        click.echo(f"ground truth: {gt['poses']} poses for {gt['frames']} recorded left frames, each from the "
                   f"rendered frame index its image carries{unknown}")
    return 0 if summary["ok"] else 1
