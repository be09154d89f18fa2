"""The simulated rig's frames: each bracket of a cycle at its own trigger instant with its own blur, from one render
per cycle; what the renderer process writes is that frame, carrying its index."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bracketry.sim.frames import (
    FrameSchedule,
    WorldSpec,
    cycle_rates,
    expose_frame,
    frame_time_s,
    noise_bank,
    read_frame_id,
    reference_time_s,
    trigger_time_s,
)
from bracketry_emulator.synth import World
from bracketry_emulator.synth.trajectory import LoopTrajectory

BRACKETS_US = [1000, 2000, 4000, 8000, 16000, 32000]
FPS = 22.0


def _log_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(np.log(a + 1e-3) - np.log(b + 1e-3)).mean())


def test_each_bracket_shows_its_own_instant() -> None:
    """Bracket j of a cycle (reprojected from the cycle's one render) is closer to the full render at its own
    mid-exposure than to the one at the mid-exposure of a bracket three triggers away, and each has its own pose."""
    world = World("forest-winter", seed=0, resolution=(320, 200), trajectory=LoopTrajectory(speed_kmh=5.0))
    c = 5
    rates = cycle_rates(world, "left", c, BRACKETS_US, FPS)
    ref = reference_time_s(c, BRACKETS_US, FPS)
    assert trigger_time_s(c * 6, FPS) < ref < trigger_time_s(c * 6 + 5, FPS)
    poses = []
    for j, rate in enumerate(rates):
        k = c * 6 + j
        other = c * 6 + (j + 3) % 6
        own = _log_err(rate, world.rate_e_per_us("left", frame_time_s(k, BRACKETS_US, FPS)))
        far = _log_err(rate, world.rate_e_per_us("left", frame_time_s(other, BRACKETS_US, FPS)))
        assert own < 0.75 * far, (j, own, far)
        poses.append(world.pose(frame_time_s(k, BRACKETS_US, FPS))[:3, 3])
    assert (np.linalg.norm(np.diff(np.array(poses), axis=0), axis=1) > 0.04).all()  # 5 km/h: ~6 cm apart


def test_renderer_process_writes_each_frame_with_its_index(tmp_path: Path) -> None:
    """The renderer process (as the rig starts it) writes frame k = the cycle's reprojected bracket k exposed with the
    rig's noise, carrying k; two cycles, both sides."""
    res = (64, 40)
    sched = FrameSchedule(tmp_path, WorldSpec("forest-winter", 3), BRACKETS_US, FPS, 12, resolution=res).start()
    try:
        sched.wait(timeout_s=120)
    finally:
        sched.stop()
    world = World("forest-winter", seed=3, resolution=res)
    for i, side in enumerate(("left", "right")):
        bank = noise_bank(world, i)
        for c in range(2):
            rates = cycle_rates(world, side, c, BRACKETS_US, FPS)
            for j in range(6):
                k = c * 6 + j
                got = np.array(sched.frames[side][k])
                assert read_frame_id(got) == k
                want = expose_frame(world, bank, side, rates[j], trigger_time_s(k, FPS), float(BRACKETS_US[j]))
                assert np.array_equal(got[1:], want[1:]) and np.array_equal(got[0, 4:], want[0, 4:]), (side, k)
