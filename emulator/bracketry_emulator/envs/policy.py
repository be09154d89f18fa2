"""Any observation -> action policy as a benchmark AE method (the plug-in protocol of ``ae/PLUGINS.md``).

:class:`PolicyAE` builds, from the mosaic the closed loop hands it, the observation :class:`~.ExposureEnv` gives
(same working image, same frame stack or statistics), asks the policy, and maps its answer to the next exposure as
the environment does. Subclass it and override :meth:`PolicyAE.act`, or pass ``policy=callable``; name it in
``--methods module:Class`` (docs/LEARNING.md has a complete example).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError

from ..defaults import DEFAULT_MAX_EXPOSURE_US, DEFAULT_MIN_EXPOSURE_US
from .core import N_FRAMES, OBSERVATIONS, discrete_actions, frame_of, next_exposure_us, stats_observation, working_image

ACTIONS: tuple[str, ...] = ("continuous", "discrete", "exposure")


class PolicyAE:
    """A policy in closed loop.

    Class attributes (or constructor arguments of the same names):
        name: the method's name in outputs.
        observation: "frames" (float32 (4, 84, 84)) or "stats" (float32 (8,)), as ExposureEnv's.
        action: "continuous" (the policy returns a in [-1, 1]: t <- t * 2^(2a)), "discrete" (an index of
            ``linspace(-1, 1, n_actions)``) or "exposure" (the policy returns the next exposure in us).
        n_actions: the discrete variant's action count.
        width: working image width (px), as the environment's.
    """

    name = "policy"
    observation = "frames"
    action = "continuous"
    n_actions = 9
    width = 256
    step_cost = 3

    def __init__(self, policy: Callable[[np.ndarray], Any] | None = None, **settings: Any) -> None:
        for key, value in settings.items():
            if key not in ("name", "observation", "action", "n_actions", "width"):
                raise BracketryError(f"{type(self).__name__}: unknown option {key!r}")
            setattr(self, key, type(getattr(self, key))(value))
        if self.observation not in OBSERVATIONS:
            raise BracketryError(f"{self.name}: unknown observation {self.observation!r} (use frames or stats)")
        if self.action not in ACTIONS:
            raise BracketryError(f"{self.name}: unknown action {self.action!r} (use {', '.join(ACTIONS)})")
        self.policy = policy
        self._table = discrete_actions(int(self.n_actions)) if self.action == "discrete" else None
        self.reset(0.0)

    def act(self, observation: np.ndarray) -> Any:
        """The policy's answer to one observation (override this, or pass ``policy``)."""
        if self.policy is None:
            raise BracketryError(f"{self.name}: no policy (pass policy=... or override act())")
        return self.policy(observation)

    def reset(self, init_exposure_us: float) -> None:
        self._frames: np.ndarray | None = None

    def observe(self, image: np.ndarray, exposure_us: float) -> np.ndarray:
        """The environment's observation after the mosaic ``image`` (uint16 HxW codes) taken at ``exposure_us``."""
        work = working_image(image, int(self.width))
        if self.observation == "stats":
            return stats_observation(work, exposure_us)
        frame = frame_of(work)[None]
        if self._frames is None:
            self._frames = np.repeat(frame, N_FRAMES, axis=0)
        else:
            self._frames = np.concatenate([self._frames[1:], frame], axis=0)
        return self._frames

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        lo, hi = meta.get("bounds_us", (DEFAULT_MIN_EXPOSURE_US, DEFAULT_MAX_EXPOSURE_US))
        out = self.act(self.observe(image, exposure_us))
        value = float(np.asarray(out, dtype=np.float64).reshape(-1)[0])
        if self.action == "exposure":
            return float(np.clip(value, lo, hi))
        if self._table is not None:
            value = float(self._table[int(value)])
        return next_exposure_us(exposure_us, value, lo, hi)
