"""Truth runs: the closed loop's images rendered by the synthetic world instead of emulated from brackets.

For a synthetic trajectory (``bracketry synth trajectory``: ``camera_model.json`` holds the world and the
recording's ``t0_ns``, ``start_s``), each step's image is what the camera would have taken with the method's chosen
exposure at that frame's instant: the step's frame is the bracket the emulator would use (same selection, so the same
timestamp and ground-truth pose), triggered at its instant ``t_s = start_s + (t_ns - t0_ns) / 1e9 - E / 2`` (its
stamp is mid-exposure), and :meth:`World.render` renders the target exposure from that trigger (same camera, noise
model and response; the world's own motion blur; noise from the world's per-frame generator, so a run is
reproducible). Nothing is emulated: the emulator's errors (noise, blur, motion between brackets, gain) are what a
truth run leaves out.

Effects switched off (cause analysis, ``bracketry accuracy truth-causes``): ``camera_model.json`` may hold
``"truth_effects"`` (:data:`TRUTH_EFFECTS`: each key False removes that effect of the truth and makes it what the
emulator gives instead; absent keys are on):

- ``blur``: no motion blur over the exposure (the render at the frame's mid-exposure instant);
- ``noise``: the noise-free render;
- ``instant``: the frame centred on the source bracket's mid-exposure stamp (the instant an emulated image shows)
  rather than exposed from its trigger (centred E/2 after it; the longest exposures up to ~16 ms later);
- ``exposure``: a target beyond the longest bracket rendered as the emulator's ``beyond="gain"`` does, the longest
  bracket's exposure with its noise, amplified by the ratio (analog gain) instead of the longer exposure.

The camera beyond the longest bracket: the truth takes a target as the camera the emulation stands for would
(:meth:`~..emulation.Emulator.exposure_and_gain`): with the emulator's ``beyond="gain"`` (the benchmark's), the
longest bracket's exposure (its blur, its noise) plus analog gain, and the step records that exposure and gain as an
emulated step does; with ``beyond="extrapolate"``, the full exposure. (A truth that exposed 64 ms where the
emulated camera took 32 ms + 6 dB compared two cameras: on the demo suite 46 % of the steps were beyond 32 ms and
that difference drove most of the emulated-vs-truth gap.) Under ``beyond="gain"`` the ``exposure`` variant is the
truth itself.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError

from ..emulation import EmulatedImage, EmulatorConfig
from .emulation_cache import EmulationCache

#: the effects of a truth image that ``camera_model.json``'s ``truth_effects`` can switch off (module docstring)
TRUTH_EFFECTS: tuple[str, ...] = ("blur", "noise", "instant", "exposure")


def truth_effects(dataset_dir: str | Path) -> dict[str, bool]:
    """{effect: on} for every effect of :data:`TRUTH_EFFECTS` (``camera_model.json``'s ``truth_effects``, default
    on); raises BracketryError (one line) for an unknown effect or a value that is not a boolean."""
    try:
        doc = json.loads((Path(dataset_dir) / "camera_model.json").read_text()).get("truth_effects") or {}
    except (OSError, ValueError, AttributeError):
        doc = {}
    if not isinstance(doc, dict) or any(k not in TRUTH_EFFECTS or not isinstance(v, bool) for k, v in doc.items()):
        raise BracketryError(f"{dataset_dir}/camera_model.json: truth_effects must map some of "
                             f"{', '.join(TRUTH_EFFECTS)} to true/false (got {doc!r})")
    return {k: bool(doc.get(k, True)) for k in TRUTH_EFFECTS}


def truth_recording(dataset_dir: str | Path) -> dict[str, Any]:
    """The ``recording`` entry (t0_ns, start_s, fps) of a synthetic trajectory's ``camera_model.json``; raises
    BracketryError (one line) for any other dataset."""
    p = Path(dataset_dir) / "camera_model.json"
    try:
        info = json.loads(p.read_text())
        rec = info["recording"]
        info["world"]
        return {"t0_ns": int(rec["t0_ns"]), "start_s": float(rec.get("start_s", 0.0)), "fps": float(rec["fps"])}
    except (OSError, ValueError, KeyError, TypeError):
        raise BracketryError(f"truth images need a synthetic trajectory (bracketry synth trajectory): {dataset_dir} "
                             "has no camera_model.json with its world and recording") from None


class TruthCache(EmulationCache):
    """:class:`EmulationCache` whose images the world renders (module docstring); the source selection, the caches
    and the gray conversions are the emulation's."""

    def __init__(self, config: EmulatorConfig, dataset_dir: str | Path) -> None:
        super().__init__(config)
        self.dataset_dir = Path(dataset_dir)
        rec = truth_recording(dataset_dir)
        self.t0_ns, self.start_s = rec["t0_ns"], rec["start_s"]
        self.effects = truth_effects(dataset_dir)
        self._world: Any = None

    @property
    def world(self) -> Any:
        if self._world is None:
            from ..synth import world_from_dataset

            self._world = world_from_dataset(self.dataset_dir)
            if not self.effects["blur"]:
                self._world.motion_blur = False
        return self._world

    def trigger_s(self, t_ns: int, exposure_us: float) -> float:
        """World time (s) of the trigger of the frame stamped ``t_ns`` (mid-exposure) exposed ``exposure_us``."""
        return self.start_s + (t_ns - self.t0_ns) * 1e-9 - 0.5 * exposure_us * 1e-6

    def emulate(self, seq_index: int, side: str, images: dict[int, np.ndarray], target_us: float,
                source_us: int | None = None, times_ns: Mapping[int, int] | None = None,
                gain_db: float | None = None) -> EmulatedImage:
        """The world's render of ``side`` at ``target_us`` from the trigger of the step's frame (the source bracket,
        ``source_us`` or the emulator's own choice); needs ``times_ns`` ({exposure_us: stamp ns}). ``gain_db``: the
        gain a method set: the camera's exposure rendered and amplified by it, as beyond the longest bracket."""
        key = (seq_index, side, float(target_us), gain_db)
        hit = self._cache.get(key)
        if hit is None:
            if times_ns is None:
                raise BracketryError("a truth image needs the frames' timestamps")
            exposure_us, gain = self.emulator.exposure_and_gain(images, float(target_us), gain_db)
            chosen_for = float(target_us) if gain_db is None else exposure_us
            source = int(source_us) if source_us is not None else self.emulator.select(images, chosen_for)
            t_s = self.trigger_s(int(times_ns[source]), float(source))
            if not self.effects["instant"]:  # centred on the source's stamp, as the emulated image's content
                t_s = self.trigger_s(int(times_ns[source]), exposure_us)
            image = self._render(side, t_s, float(target_us), max(images), exposure_us)
            hit = self._cache[key] = EmulatedImage(image, float(target_us), source, float(target_us) / source,
                                                   "truth", (source,), exposure_us,
                                                   float(20.0 * np.log10(gain)) if gain > 0 else 0.0)
        return hit

    def _render(self, side: str, t_s: float, target_us: float, longest_us: float, exposure_us: float) -> np.ndarray:
        """The world's frame (uint16 codes) triggered at ``t_s`` with the effects of :attr:`effects`, for
        ``target_us`` taken as ``exposure_us`` plus analog gain (module docstring); with the ``exposure`` effect off,
        beyond the longest bracket at most that bracket's exposure."""
        noise = self.effects["noise"]
        if not self.effects["exposure"] and target_us > longest_us:
            exposure_us = min(exposure_us, longest_us)
        if exposure_us >= target_us:
            return self.world.render(side, t_s, target_us, noise=noise)
        # the camera's exposure (its noise, its blur) amplified to the target: what the gain emulation does
        raw = self.world.render(side, t_s, exposure_us, rng=self.world.frame_rng(side, t_s, target_us), noise=noise)
        response = self.emulator.response
        linear = response.icrf[raw].astype(np.float64) * (target_us / exposure_us)
        return response.encode(linear, self.emulator.rounding)
