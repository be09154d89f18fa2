"""Synthetic HDR stereo world: bracketed walks with ground-truth poses, and static calibration stacks.

    from bracketry_emulator.synth import World
    world = World("forest-winter", seed=0, resolution=(960, 600))
    raw = world.render("left", t_s=1.0, exposure_us=8000)   # uint16 (600, 960) RGGB 12-bit codes
    T = world.pose(1.0)                                       # 4x4 left camera pose, ground-truth frame

Scenarios (route, pace, time of day, weather, lighting events over time, as YAML): :func:`load_scenario`,
:func:`world_from_scenario`; :func:`world_from_dataset` rebuilds the exact World of a written trajectory folder.

Writers: :func:`write_trajectory` (``bracketry synth trajectory``) and :func:`write_static`
(``bracketry synth static``); layouts in :mod:`bracketry_emulator.synth.writer`.
"""

from bracketry_emulator.synth.calibration import CameraIntrinsics, StereoCalibration, default_calibration
from bracketry_emulator.synth.camera_model import CameraModel, srgb_lut
from bracketry_emulator.synth.scenario import Scenario, load_scenario
from bracketry_emulator.synth.scene import PRESETS
from bracketry_emulator.synth.trajectory import LoopTrajectory
from bracketry_emulator.synth.world import World, parse_resolution, world_from_dataset, world_from_scenario
from bracketry_emulator.synth.writer import write_static, write_trajectory

__all__ = ["PRESETS", "CameraIntrinsics", "CameraModel", "LoopTrajectory", "Scenario", "StereoCalibration", "World",
           "default_calibration", "load_scenario", "parse_resolution", "srgb_lut", "world_from_dataset",
           "world_from_scenario", "write_static", "write_trajectory"]
