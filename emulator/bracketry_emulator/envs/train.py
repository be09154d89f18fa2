"""Train the DRL exposure actor from scratch on :class:`~.ExposureEnv` (stable-baselines3 SAC, CPU).

Why stable-baselines3's SAC and not our own: it is the reviewed reference implementation of the algorithm the DRL
authors used (SAC with an adaptive entropy weight), with its replay buffer, save/load of the whole learner (for
checkpoints and resume) and seeding; and its CNN actor is, layer for layer, the authors' actor: NatureCNN (conv
32@8x8/4, 64@4x4/2, 64@3x3/1, FC 3136 -> 512, ReLU) -> FC 512 -> 512 (ReLU) -> mean and log_std heads, tanh-squashed.
:func:`actor_state_dict` renames those tensors to the names ``ae/drl.py`` loads (``cnn.conv1..3``, ``l1``, ``l2``,
``mean_layer``, ``log_std_layer``), so the written weights run as ``--drl-weights`` in the benchmark.

Hyper-parameters are the authors' where memory and CPU allow (lr 1e-4, gamma 0.99, tau 0.005, log alpha_0 = -1,
adaptive alpha; episodes as :class:`~.ExposureEnv` windows); smaller by default here: batch 64 (theirs 256), replay
10,000 (theirs 50,000), warm-up 1,000 steps (theirs 5,000): one 2-core machine, not a GPU. Frames are stored as
uint8 (x 255) in the replay buffer (4x less memory); SB3 divides them by 255 again before the actor.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bracketry_base.errors import BracketryError
from bracketry_base.progress import Progress

from . import env_sources
from .exposure_env import ExposureEnv

#: SB3 actor tensor name -> ae/drl.py actor tensor name
ACTOR_KEYS: dict[str, str] = {
    "features_extractor.cnn.0.weight": "cnn.conv1.weight", "features_extractor.cnn.0.bias": "cnn.conv1.bias",
    "features_extractor.cnn.2.weight": "cnn.conv2.weight", "features_extractor.cnn.2.bias": "cnn.conv2.bias",
    "features_extractor.cnn.4.weight": "cnn.conv3.weight", "features_extractor.cnn.4.bias": "cnn.conv3.bias",
    "features_extractor.linear.0.weight": "l1.weight", "features_extractor.linear.0.bias": "l1.bias",
    "latent_pi.0.weight": "l2.weight", "latent_pi.0.bias": "l2.bias",
    "mu.weight": "mean_layer.weight", "mu.bias": "mean_layer.bias",
    "log_std.weight": "log_std_layer.weight", "log_std.bias": "log_std_layer.bias",
}


@dataclass(frozen=True)
class TrainConfig:
    """Training settings (see the module docstring; steps are environment steps summed over the environments)."""

    steps: int = 20_000
    seed: int = 0
    reward: str = "feat"
    n_envs: int = 1
    episode_steps: int | None = 200
    batch_size: int = 64
    buffer_size: int = 10_000
    learning_starts: int = 1_000
    learning_rate: float = 1e-4
    gamma: float = 0.99
    tau: float = 0.005
    train_freq: int = 1
    gradient_steps: int = 1
    critic_hidden: int = 256
    share_encoder: bool = True
    init_alpha: float = 0.368  # the entropy weight's start (theirs: log alpha_0 = -1), adapted from there
    width: int = 256
    augment: bool = True
    checkpoint_every: int = 5_000
    split: str = "train"
    #: further keyword arguments of every ExposureEnv (e.g. init_exposure_us, max_exposure_us)
    env_kwargs: dict[str, Any] = field(default_factory=dict)


def _sb3() -> Any:
    try:
        import stable_baselines3
    except ImportError as exc:
        raise BracketryError("training needs the learn extra: pip install -e '.[learn]' "
                             "(gymnasium, stable-baselines3, torch)") from exc
    return stable_baselines3


def uint8_frames(env: Any) -> Any:
    """``env`` with its float frames in [0, 1] stored as uint8 codes round(255 x) (SB3's image convention)."""
    import gymnasium as gym

    class _U8(gym.ObservationWrapper):  # type: ignore[type-arg]
        def __init__(self, inner: Any) -> None:
            super().__init__(inner)
            self.observation_space = gym.spaces.Box(0, 255, inner.observation_space.shape, np.uint8)

        def observation(self, observation: np.ndarray) -> np.ndarray:
            return np.rint(np.clip(observation, 0.0, 1.0) * 255.0).astype(np.uint8)

    return _U8(env)


def make_train_env(datasets: list[Any], cfg: TrainConfig) -> Any:
    """SB3's DummyVecEnv of ``cfg.n_envs`` ExposureEnv (frames, continuous action) over the trajectories of
    ``datasets`` (manifests: their ``cfg.split`` entries), dealt among them, seeded ``cfg.seed + i``."""
    sb3 = _sb3()
    from stable_baselines3.common.vec_env import DummyVecEnv

    groups = env_sources(datasets, cfg.n_envs, cfg.split)

    def factory(group: list[Any]) -> Any:
        return lambda: uint8_frames(ExposureEnv(group, split=cfg.split, reward=cfg.reward, width=cfg.width,
                                                episode_steps=cfg.episode_steps, augment=cfg.augment,
                                                **cfg.env_kwargs))

    venv = DummyVecEnv([factory(g) for g in groups])
    venv.seed(cfg.seed)
    del sb3
    return venv


def new_model(venv: Any, cfg: TrainConfig) -> Any:
    """A fresh SAC learner with the DRL actor's architecture (see the module docstring)."""
    sb3 = _sb3()
    policy_kwargs = {"net_arch": {"pi": [512], "qf": [cfg.critic_hidden]},
                     "features_extractor_kwargs": {"features_dim": 512},
                     "share_features_extractor": cfg.share_encoder}
    return sb3.SAC("CnnPolicy", venv, learning_rate=cfg.learning_rate, buffer_size=cfg.buffer_size,
                   learning_starts=cfg.learning_starts, batch_size=cfg.batch_size, tau=cfg.tau, gamma=cfg.gamma,
                   train_freq=cfg.train_freq, gradient_steps=cfg.gradient_steps, ent_coef=f"auto_{cfg.init_alpha:g}",
                   policy_kwargs=policy_kwargs, seed=cfg.seed, device="cpu", verbose=0)


def actor_state_dict(model: Any) -> dict[str, Any]:
    """The learner's actor as the ``state_dict`` ``ae/drl.py`` loads (tensors renamed, copied to CPU)."""
    state = model.actor.state_dict()
    missing = sorted(set(ACTOR_KEYS) - set(state))
    if missing:
        raise BracketryError(f"the SAC actor lacks tensors {missing[:3]} (stable-baselines3 layout changed?)")
    return {ACTOR_KEYS[k]: state[k].detach().cpu().clone() for k in ACTOR_KEYS}


def save_actor(model: Any, path: str | Path) -> Path:
    """Write the actor's weights (``--drl-weights`` format) to ``path`` atomically. Returns the path."""
    import torch

    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    torch.save(actor_state_dict(model), tmp)
    tmp.replace(p)
    return p


def checkpoint_dir(weights: str | Path) -> Path:
    """Where the checkpoints of a run writing ``weights`` live: ``<weights>.ckpt/``."""
    p = Path(weights)
    return p.with_name(p.name + ".ckpt")


@dataclass
class TrainResult:
    """What a training run did: steps done (total, this run), wall time (s), steps per second, the episodes'
    returns (step at the episode's end, return) and the paths written."""

    steps: int
    new_steps: int
    wall_s: float
    steps_per_s: float
    curve: list[tuple[int, float]]
    weights: Path
    checkpoint: Path


def train_drl(datasets: list[Any], weights: str | Path, cfg: TrainConfig, *, resume: bool = False,
              quiet: bool = False, log_every: int = 1000) -> TrainResult:
    """Train (or resume) the DRL actor for ``cfg.steps`` environment steps in all; write ``weights`` and, every
    ``cfg.checkpoint_every`` steps and at the end, the checkpoint (``<weights>.ckpt/``: learner, replay buffer,
    curve, config). ``resume``: continue the checkpoint's learner (its step count counts towards ``cfg.steps``).
    Deterministic for a seed on one machine (torch on one thread).
    """
    import torch

    sb3 = _sb3()
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)
    ckpt = checkpoint_dir(weights)
    venv = make_train_env(datasets, cfg)
    curve: list[tuple[int, float]] = []
    if resume:
        if not (ckpt / "model.zip").is_file():
            raise BracketryError(f"nothing to resume: no checkpoint {ckpt}/model.zip")
        model = sb3.SAC.load(ckpt / "model.zip", env=venv, device="cpu")
        if (ckpt / "replay.pkl").is_file():
            model.load_replay_buffer(ckpt / "replay.pkl")
        state = json.loads((ckpt / "state.json").read_text()) if (ckpt / "state.json").is_file() else {}
        curve = [(int(s), float(r)) for s, r in state.get("curve", [])]
    else:
        model = new_model(venv, cfg)
    # a logger with no output: SB3's default makes an empty folder in the system temp dir at every learn() (no
    # progress of ours goes through it: the bar below reports)
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))
    done0 = int(model.num_timesteps)
    todo = max(0, cfg.steps - done0)
    returns = np.zeros(venv.num_envs)

    def save_checkpoint() -> None:
        ckpt.mkdir(parents=True, exist_ok=True)
        model.save(ckpt / "model.zip")
        model.save_replay_buffer(ckpt / "replay.pkl")
        state = {"steps": int(model.num_timesteps), "curve": curve, "config": asdict(cfg)}
        (ckpt / "state.json").write_text(json.dumps(state, indent=1))
        save_actor(model, weights)

    with Progress("train drl", total=cfg.steps, unit="step", enabled=not quiet) as bar:
        bar.set(done0)

        class _Callback(BaseCallback):  # type: ignore[misc]
            def _on_step(self) -> bool:
                nonlocal returns
                returns += np.asarray(self.locals["rewards"], dtype=np.float64)
                for i, end in enumerate(self.locals["dones"]):
                    if end:
                        curve.append((int(self.num_timesteps), float(returns[i])))
                        returns[i] = 0.0
                bar.set(int(self.num_timesteps))
                if curve:
                    last = [r for _, r in curve[-10:]]
                    bar.set_postfix(f"return (last {len(last)} episodes) {np.mean(last):.2f}")
                if cfg.checkpoint_every and self.num_timesteps % cfg.checkpoint_every < venv.num_envs:
                    save_checkpoint()
                return True

        t0 = time.perf_counter()
        if todo:
            model.learn(total_timesteps=todo, callback=_Callback(), reset_num_timesteps=False,
                        log_interval=None)
        wall = time.perf_counter() - t0
        save_checkpoint()
    new = int(model.num_timesteps) - done0
    venv.close()
    return TrainResult(int(model.num_timesteps), new, wall, new / wall if wall > 0 else float("nan"), curve,
                       Path(weights), ckpt)


def evaluate_actor(actor: Any, env: ExposureEnv, episodes: int = 1, seed: int = 0) -> float:
    """Mean return of the deterministic ``actor`` (``ae/drl.py``'s module: (B, 4, 84, 84) -> (B, 1)) on ``env``
    (frames observation, continuous action) over ``episodes`` episodes seeded ``seed, seed + 1, ...``. Frames are
    quantised to uint8 as in training."""
    import torch

    total = 0.0
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        done = False
        while not done:
            x = np.rint(obs * 255.0).astype(np.float32) / 255.0
            with torch.no_grad():
                a = actor(torch.from_numpy(x)[None]).numpy().reshape(1)
            obs, r, term, trunc, _ = env.step(a.astype(np.float32))
            total += r
            done = term or trunc
    return total / episodes


def random_return(env: ExposureEnv, episodes: int = 1, seed: int = 0) -> float:
    """Mean return of uniformly random actions (the action space seeded ``seed``) over ``episodes`` episodes."""
    env.action_space.seed(seed)
    total = 0.0
    for e in range(episodes):
        env.reset(seed=seed + e)
        done = False
        while not done:
            _, r, term, trunc, _ = env.step(env.action_space.sample())
            total += r
            done = term or trunc
    return total / episodes
