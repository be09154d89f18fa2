"""Learning environments on the emulator: :class:`ExposureEnv` (gymnasium), vectorised over trajectories, and the
adapter that runs any observation -> exposure policy as a benchmark method (:class:`PolicyAE`). See docs/LEARNING.md.

Python API::

    from bracketry_emulator.envs import ExposureEnv, make_vector_env
    env = ExposureEnv("suite/manifest.yaml", split="train")              # one episode = one trajectory
    venv = make_vector_env(["suite/manifest.yaml"], n_envs=2, seed=0)    # gymnasium SyncVectorEnv

Needs the ``learn`` extra (gymnasium; training also stable-baselines3 and torch).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .core import REWARDS, STATS_FIELDS, discrete_actions, frame_of, next_exposure_us, stats_observation
from .exposure_env import ExposureEnv
from .policy import PolicyAE
from .scenes import constructed_trajectory
from .trajectories import Trajectory, load_trajectory, resolve_trajectories

__all__ = ["REWARDS", "STATS_FIELDS", "ExposureEnv", "PolicyAE", "Trajectory", "constructed_trajectory",
           "discrete_actions", "env_sources", "frame_of", "load_trajectory", "make_vector_env",
           "next_exposure_us", "resolve_trajectories", "stats_observation"]


def env_sources(datasets: list[Any], n_envs: int, split: str = "train") -> list[list[Any]]:
    """The trajectories of ``datasets`` dealt round-robin to ``n_envs`` environments (each gets at least one:
    with fewer trajectories than environments, some share). Items: TrajectorySpec or Trajectory."""
    paths = [d for d in datasets if isinstance(d, str | Path)]
    items = [d for d in datasets if not isinstance(d, str | Path)]
    items += resolve_trajectories(paths, split) if paths else []
    return [items[i::n_envs] or [items[i % len(items)]] for i in range(n_envs)]


def make_vector_env(datasets: list[Any], n_envs: int = 2, seed: int | None = 0, split: str = "train",
                    **env_kwargs: Any) -> Any:
    """A gymnasium ``SyncVectorEnv`` of ``n_envs`` :class:`ExposureEnv`, the trajectories dealt among them
    (:func:`env_sources`), reset with seeds ``seed, seed + 1, ...`` when ``seed`` is given. ``env_kwargs`` go to
    every ExposureEnv."""
    import gymnasium as gym

    groups = env_sources(datasets, n_envs, split)
    def factory(group: list[Any]) -> Any:
        return lambda: ExposureEnv(group, split=split, **env_kwargs)

    venv = gym.vector.SyncVectorEnv([factory(g) for g in groups])
    if seed is not None:
        venv.reset(seed=[seed + i for i in range(n_envs)])
    return venv
