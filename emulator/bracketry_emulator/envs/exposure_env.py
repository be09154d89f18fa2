"""``ExposureEnv``: a gymnasium environment whose episode is a trajectory replayed through the exposure emulator.

Python API::

    from bracketry_emulator.envs import ExposureEnv
    env = ExposureEnv("suite/manifest.yaml", split="train", reward="feat")   # or a dataset folder / .mcap / list
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

An episode replays one trajectory (picked by the environment's seeded generator among its trajectories), from its
first bracket sequence to its last (or a window of ``episode_steps`` steps at a random start). At every step the
agent's exposure is emulated from that sequence's brackets (:class:`~bracketry_emulator.emulation.Emulator`, at the
working resolution, as the DRL authors' simulator re-exposed resized brackets), the image goes into the observation
and the reward. Step k's action sets the exposure of sequence k+1.

- action ``"continuous"``: Box(-1, 1, (1,)) float32, the DRL paper's: t <- t * 2^(2a) (us), clamped to
  [``min_exposure_us``, ``max_exposure_us``] (default the benchmark's bounds, 20 us .. 64 ms);
  ``"discrete"``: Discrete(``n_actions``), action i = the continuous action ``linspace(-1, 1, n)[i]``.
- observation ``"frames"``: Box(0, 1, (4, 84, 84)) float32, the DRL actor's input (the last 4 images area-resized,
  codes / 4096, oldest first; the first image four times after a reset); ``"stats"``: Box(-2, 2, (8,)) float32,
  :data:`~.core.STATS_FIELDS`.
- reward ``"feat"`` (0.005 per ORB keypoint + 0.005 per homography inlier, unitless, [0, 5]) or ``"stat"``
  (-sqrt(|mean - 0.5|) - 0.2 sqrt(|mean change|) of the image in [0, 1] full scale, unitless, [-1.28, 0]); see
  :mod:`.core`.
- ``terminated`` is always False; ``truncated`` is True at the end of the trajectory or window (the scene goes on:
  a learner bootstraps there).
- ``info``: ``exposure_us`` (of the image just emulated), ``source_exposure_us``, ``mean`` (of that image, [0, 1]),
  ``sequence`` (index in the trajectory), ``trajectory`` (name).
- seeded: ``reset(seed=...)`` fixes the trajectory picks, starting exposures, windows and augmentations;
  ``reset(options={"trajectory": i, "init_exposure_us": t, "start": n})`` fixes them for one episode.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from bracketry_base.errors import BracketryError

from ..defaults import DEFAULT_MAX_EXPOSURE_US, DEFAULT_MIN_EXPOSURE_US
from ..emulation import Emulator, EmulatorConfig
from ..metrics.manifest import TrajectorySpec
from .core import (
    FRAME_SIZE,
    N_FRAMES,
    OBSERVATIONS,
    REWARDS,
    STATS_FIELDS,
    FeatureReward,
    discrete_actions,
    frame_of,
    next_exposure_us,
    stat_reward,
    stats_observation,
)
from .trajectories import Trajectory, load_trajectory, resolve_trajectories

Source = str | Path | TrajectorySpec | Trajectory


class ExposureEnv(gym.Env):  # type: ignore[type-arg]
    """See the module docstring.

    Args:
        dataset_path: a dataset folder, an ``.mcap``, a manifest ``.yaml``, a :class:`Trajectory` (already
            loaded, e.g. a constructed scene), or a list of these.
        split: the manifests' entries used ("train", "test" or "all"; dataset folders are always used).
        action: "continuous" or "discrete" (``n_actions`` values, odd).
        observation: "frames" or "stats".
        reward: "feat" or "stat".
        width: working image width (px) the brackets are resized to (256, as the DRL authors' 256x192).
        side: camera side replayed.
        min_exposure_us, max_exposure_us: exposure bounds (us).
        init_exposure_us: the first exposure of every episode (us); None = log-uniform at random between a quarter
            of the shortest and 4x the longest bracket (within the bounds), as their training randomised it.
        episode_steps: steps of an episode (a window at a random start); None = the whole trajectory.
        augment: their augmentations, drawn per episode: time reversal, horizontal and vertical flips.
        crf: the camera response of the emulator ("srgb" or a pcalib.txt path).
        cache_trajectories: trajectories kept loaded at once (least recently used dropped).
        max_sequences: load at most this many sequences of each trajectory (None = all).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, dataset_path: Source | list[Source], *, split: str = "train", action: str = "continuous",
                 n_actions: int = 9, observation: str = "frames", reward: str = "feat", width: int = 256,
                 side: str = "left", min_exposure_us: float = DEFAULT_MIN_EXPOSURE_US,
                 max_exposure_us: float = DEFAULT_MAX_EXPOSURE_US, init_exposure_us: float | None = None,
                 episode_steps: int | None = None, augment: bool = False, crf: str | Path = "srgb",
                 cache_trajectories: int = 4, max_sequences: int | None = None) -> None:
        super().__init__()
        if action not in ("continuous", "discrete"):
            raise BracketryError(f"unknown action space {action!r} (use continuous or discrete)")
        if observation not in OBSERVATIONS:
            raise BracketryError(f"unknown observation {observation!r} (use {', '.join(OBSERVATIONS)})")
        if reward not in REWARDS:
            raise BracketryError(f"unknown reward {reward!r} (use {', '.join(REWARDS)})")
        if not 0 < min_exposure_us < max_exposure_us:
            raise BracketryError(f"bad exposure bounds {min_exposure_us}..{max_exposure_us} us")
        if episode_steps is not None and episode_steps < 1:
            raise BracketryError(f"episode_steps must be >= 1, got {episode_steps}")
        items = dataset_path if isinstance(dataset_path, list) else [dataset_path]
        self._sources: list[TrajectorySpec | Trajectory] = []
        paths: list[str | Path] = []
        for item in items:
            if isinstance(item, Trajectory | TrajectorySpec):
                self._sources.append(item)
            else:
                paths.append(item)
        if paths:
            self._sources += resolve_trajectories(paths, split)
        if not self._sources:
            raise BracketryError("an exposure environment needs at least one trajectory")
        self.action_kind, self.observation_kind, self.reward_kind = action, observation, reward
        self.width, self.side, self.crf = width, side, crf
        self.bounds_us = (float(min_exposure_us), float(max_exposure_us))
        self.init_exposure_us = init_exposure_us
        self.episode_steps, self.augment = episode_steps, augment
        self.cache_trajectories, self.max_sequences = max(1, cache_trajectories), max_sequences
        self._loaded: OrderedDict[int, Trajectory] = OrderedDict()
        self.emulator = Emulator(EmulatorConfig(crf=crf))
        self._feature_reward = FeatureReward() if reward == "feat" else None
        self.actions = discrete_actions(n_actions) if action == "discrete" else None
        self.action_space: gym.Space[Any]
        if action == "discrete":
            self.action_space = gym.spaces.Discrete(n_actions)
        else:
            self.action_space = gym.spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
        self.observation_space: gym.Space[Any]
        if observation == "frames":
            self.observation_space = gym.spaces.Box(0.0, 1.0, (N_FRAMES, FRAME_SIZE, FRAME_SIZE), dtype=np.float32)
        else:
            self.observation_space = gym.spaces.Box(-2.0, 2.0, (len(STATS_FIELDS),), dtype=np.float32)
        self._traj: Trajectory | None = None

    # -- trajectories -------------------------------------------------------------------------------------------
    @property
    def n_trajectories(self) -> int:
        """How many trajectories the episodes are drawn from."""
        return len(self._sources)

    def trajectory(self, i: int) -> Trajectory:
        """Trajectory ``i`` (loaded on first use, kept among the ``cache_trajectories`` most recent)."""
        if i in self._loaded:
            self._loaded.move_to_end(i)
            return self._loaded[i]
        src = self._sources[i]
        traj = src if isinstance(src, Trajectory) else load_trajectory(
            src.path, self.width, self.side, src.name, self.max_sequences)
        self._loaded[i] = traj
        while len(self._loaded) > self.cache_trajectories:
            self._loaded.popitem(last=False)
        return traj

    # -- gymnasium API ------------------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        opts = options or {}
        rng = self.np_random
        i = int(opts["trajectory"]) if "trajectory" in opts else int(rng.integers(self.n_trajectories))
        traj = self._traj = self.trajectory(i)
        steps = traj.steps - 1 if self.episode_steps is None else min(self.episode_steps, traj.steps - 1)
        reverse = bool(self.augment and rng.integers(2))
        self._flips = (bool(self.augment and rng.integers(2)), bool(self.augment and rng.integers(2)))
        if "start" in opts:
            start = int(opts["start"])
        else:
            start = int(rng.integers(traj.steps - steps)) if steps < traj.steps - 1 else 0
            if reverse:
                start = traj.steps - 1 - start
        self._dir = -1 if reverse else 1
        self._n, self._end = start, start + self._dir * steps
        if "init_exposure_us" in opts:
            t0 = float(opts["init_exposure_us"])
        elif self.init_exposure_us is not None:
            t0 = float(self.init_exposure_us)
        else:
            lo = max(self.bounds_us[0], traj.exposures_us[0] / 4.0)
            hi = min(self.bounds_us[1], traj.exposures_us[-1] * 4.0)
            t0 = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        self._exposure_us = float(np.clip(t0, *self.bounds_us))
        image, source = self._emulate()
        self._image = image
        if self.observation_kind == "frames":
            self._frames = np.repeat(frame_of(image)[None], N_FRAMES, axis=0)
        return self._observation(), self._info(image, source)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._traj is None:
            raise BracketryError("call reset() before step()")
        if self.actions is not None:
            a = float(self.actions[int(action)])
        else:
            a = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
        self._exposure_us = next_exposure_us(self._exposure_us, a, *self.bounds_us)
        self._n += self._dir
        prev = self._image
        image, source = self._emulate()
        self._image = image
        if self.observation_kind == "frames":
            self._frames = np.concatenate([self._frames[1:], frame_of(image)[None]], axis=0)
        reward = self.reward_of(prev, image)
        truncated = self._n == self._end
        return self._observation(), reward, False, truncated, self._info(image, source)

    # -- helpers ------------------------------------------------------------------------------------------------
    def reward_of(self, prev: np.ndarray, image: np.ndarray) -> float:
        """The reward of the new working image ``image`` after ``prev`` (uint16 codes; see the module docstring)."""
        x0 = prev.astype(np.float32) / np.float32(4095.0)
        x1 = image.astype(np.float32) / np.float32(4095.0)
        if self._feature_reward is not None:
            return float(self._feature_reward(x0, x1))
        return stat_reward(x0, x1)

    def _emulate(self) -> tuple[np.ndarray, int]:
        assert self._traj is not None
        out = self.emulator.emulate(self._traj.images(self._n), self._exposure_us)
        image = out.image
        if self._flips[0]:
            image = image[:, ::-1]
        if self._flips[1]:
            image = image[::-1, :]
        return np.ascontiguousarray(image), out.source_exposure_us

    def _observation(self) -> np.ndarray:
        if self.observation_kind == "frames":
            return self._frames.copy()
        return stats_observation(self._image, self._exposure_us)

    def _info(self, image: np.ndarray, source_us: int) -> dict[str, Any]:
        assert self._traj is not None
        return {"exposure_us": self._exposure_us, "source_exposure_us": int(source_us),
                "mean": float(image.mean()) / 4095.0, "sequence": self._n, "trajectory": self._traj.name}
