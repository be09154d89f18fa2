"""``bracketry simulate --seconds N --out DIR``: the whole rig on this machine, driven by scripted button presses."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from bracketry.errors import BracketryError


def parse_resolution(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` -> (width, height), both even and >= 16."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise BracketryError(f"--resolution {text!r}: expected WIDTHxHEIGHT, e.g. 640x400") from None
    if w < 16 or h < 16 or w % 2 or h % 2:
        raise BracketryError(f"--resolution {text!r}: width and height must be even and >= 16")
    return w, h


@click.command("simulate")
@click.option("--seconds", type=click.FloatRange(1.0, 3600.0), default=10.0, show_default=True,
              help="How long to record.")
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the recordings, logs, config, panel screen and summary.")
@click.option("--trigger", type=click.Choice(["simulator", "qemu"]), default="simulator", show_default=True,
              help="The Python trigger simulator, or the real firmware ELF in QEMU (no timing fidelity).")
@click.option("--resolution", default="640x400", show_default=True, help="Camera resolution WIDTHxHEIGHT.")
@click.option("--fps", type=click.FloatRange(1.0, 60.0), default=22.0, show_default=True)
@click.option("--preset", type=click.Choice(["forest-winter", "campus-summer"]), default="forest-winter",
              show_default=True, help="Synthetic world.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--no-world", is_flag=True, help="Serve a test pattern instead of the synthetic world.")
@click.option("--monitor", "monitor_port", type=click.IntRange(1024, 65535), default=None,
              help="Serve the browser monitor on 127.0.0.1:PORT (the URL with its token is printed).")
def command(seconds: float, out_dir: Path, trigger: str, resolution: str, fps: float, preset: str, seed: int,
            no_world: bool, monitor_port: int | None) -> int:
    """Run the simulated backpack: fake GigE cameras, trigger, panel firmware and the daemon under test."""
    res = parse_resolution(resolution)
    from bracketry.sim.rig import in_private_netns, reexec_in_netns

    if not in_private_netns():
        bridge = None
        if monitor_port is not None:
            from bracketry.sim.rig import monitor_bridge_outside

            out_dir.mkdir(parents=True, exist_ok=True)
            bridge = monitor_bridge_outside(out_dir, monitor_port)
        try:
            return reexec_in_netns(sys.argv[1:] if sys.argv[1:2] == ["simulate"] else
                                   ["simulate", "--seconds", str(seconds), "--out", str(out_dir), "--trigger",
                                    trigger, "--resolution", resolution, "--fps", str(fps), "--preset", preset,
                                    "--seed", str(seed), *(["--no-world"] if no_world else []),
                                    *(["--monitor", str(monitor_port)] if monitor_port is not None else [])])
        finally:
            if bridge is not None:
                bridge.terminate()
                bridge.wait(timeout=10)
    return run(out_dir, seconds, trigger, res, fps, preset, seed, not no_world, monitor_port)


def run(out_dir: Path, seconds: float, trigger: str, res: tuple[int, int], fps: float, preset: str, seed: int,
        world: bool, monitor_port: int | None = None) -> int:
    """The simulation inside the private network namespace."""
    from tqdm import tqdm

    from bracketry.recording.verify import format_report, verify_recording
    from bracketry.sim.rig import SimOptions, SimulatedRig, summary_json
    from bracketry.sim.scenario import run_session

    opts = SimOptions(out_dir=out_dir, resolution=res, fps=fps, world_seconds=seconds + 5.0, trigger=trigger,
                      preset=preset, seed=seed, world=world, echo=lambda s: click.echo(s, err=True),
                      monitor_port=monitor_port)
    rig = SimulatedRig(opts)
    try:
        bar = tqdm(total=1, desc="rendering camera frames", unit="frame", file=sys.stderr, leave=False)

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        rig.prepare_frames(progress)
        bar.close()
        rig.start()
        session = run_session(rig, seconds)
    finally:
        rig.close()
    reports = [verify_recording(seg) for seg in rig.recordings()]
    for r in reports:
        click.echo(format_report(r))
    gt = rig.write_groundtruth()
    summary = summary_json(rig, reports, {"session": session, "groundtruth": str(gt) if gt else None,
                                          "frame_mismatches": rig.schedule.mismatches if rig.schedule else None})
    frames = {s: sum(r.sides[s].frames for r in reports if s in r.sides) for s in ("left", "right")}
    drops = {s: sum(r.sides[s].drops for r in reports if s in r.sides) for s in ("left", "right")}
    click.echo(f"simulated rig: recorded {session['recorded_s']} s, frames {frames}, drops {drops}, "
               f"{'verified clean' if summary['ok'] else 'PROBLEMS FOUND'}; summary {out_dir / 'simulation.json'}")
    return 0 if summary["ok"] else 1
