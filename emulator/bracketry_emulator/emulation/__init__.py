"""Exposure emulation from bracketed images: LUT kernel, HigherNoSat / upstream selection, fusion, gain, RunWriter.

Python API (used by ``bracketry emulate`` and the AE methods)::

    from bracketry_emulator.dataset import open_dataset
    from bracketry_emulator.emulation import Emulator, EmulatorConfig, RunWriter

    ds = open_dataset(path)
    emu = Emulator(EmulatorConfig(selection="highernosat", crf="srgb"))
    with RunWriter(out_dir, "constant-8", ds.sides) as writer:
        for step, seq in enumerate(ds.sequences()):
            imgs = emu.emulate_sequence(seq, 8000.0)          # {side: EmulatedImage}; or emu.emulate(seq.load(side), t)
            writer.write_step(step, seq, imgs, 8000.0)
"""

from __future__ import annotations

from .align import estimate_motion, warp_mosaic
from .emulator import SELECTIONS, EmulatedImage, Emulator, EmulatorConfig
from .fusion import FusionResult, fuse
from .kernel import LutCache, apply_lut
from .noise import NoiseModel, calibrate_noise
from .selection import bounding_brackets, saturation_fraction, select_highernosat, select_upstream
from .writer import STEPS_HEADER, RunWriter

__all__ = ["SELECTIONS", "STEPS_HEADER", "EmulatedImage", "Emulator", "EmulatorConfig", "FusionResult",
           "LutCache", "NoiseModel", "RunWriter", "apply_lut", "bounding_brackets", "calibrate_noise",
           "estimate_motion", "fuse", "saturation_fraction", "select_highernosat", "select_upstream",
           "warp_mosaic"]
