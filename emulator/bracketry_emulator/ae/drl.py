"""DRL: the deep-reinforcement-learning exposure agent of Zhang et al. 2024 (id drl; needs the ``drl`` extra, torch).

Paper: S. Zhang, J. He, Y. Zhu, J. Wu, J. Yuan, "Efficient camera exposure control for visual odometry via deep
reinforcement learning", arXiv 2408.17005 (code and weights: ShuyangUni/drl_exposure_ctrl, MIT). The benchmark uses
their published actor trained with the feature reward (``actor_drl_feat_10000.pth``), not fine-tuned.

Actor (SAC policy, inference only): input 4 stacked frames 84x84 in [0, 1]; conv 32@8x8/4, 64@4x4/2, 64@3x3/1 (ReLU)
-> 3136 -> FC 512 -> FC 512 (ReLU) -> mean (and log_std, unused at inference); deterministic action a = tanh(mean)
in (-1, 1); exposure t <- t * 2^(2a) (at most +-2 stops per frame), clamped to [50 us, 2 s]. Parameter names match
the published ``state_dict`` (cnn.conv1..3, l1, l2, mean_layer, log_std_layer) so the public ``.pth`` loads as is.

As the benchmark authors: the state is the last 4 emulated mosaics area-resized to 84x84 and divided by 4096
(oldest first); the first 4 calls use the classical-50 step while the stack fills.

Deliberate deviations:
- Unit quirk FIXED: the authors' class returns the agent's exposure in microseconds to a caller that works in ms
  (unverified whether converted); our interface is in us end to end.
- torch runs on one thread per process (the runner parallelises over processes).
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bracketry_base.errors import BracketryError, MissingComponentError

from .base import check_input
from .classical import ClassicalAE

FRAME_SIZE = 84
N_FRAMES = 4
MIN_EXPOSURE_US = 50.0
MAX_EXPOSURE_US = 2_000_000.0


def _torch() -> Any:
    try:
        import torch
    except ImportError as exc:
        raise MissingComponentError(
            "the drl method needs PyTorch: pip install -e '.[drl]' (torch==2.13.0 CPU)") from exc
    return torch


def build_actor(hidden: int = 512, n_frames: int = N_FRAMES) -> Any:
    """A fresh (randomly initialised) actor ``torch.nn.Module``; ``forward(x: float32 (B, 4, 84, 84)) -> a (B, 1)``
    in (-1, 1) (deterministic: tanh of the mean head)."""
    torch = _torch()
    nn = torch.nn

    class _Encoder(nn.Module):  # type: ignore[name-defined,misc]
        def __init__(self) -> None:
            super().__init__()
            self.conv1 = nn.Conv2d(n_frames, 32, kernel_size=8, stride=4)
            self.conv2 = nn.Conv2d(32, 64, kernel_size=4, stride=2)
            self.conv3 = nn.Conv2d(64, 64, kernel_size=3, stride=1)

        def forward(self, x: Any) -> Any:
            x = torch.relu(self.conv1(x))
            x = torch.relu(self.conv2(x))
            x = torch.relu(self.conv3(x))
            return torch.flatten(x, 1)

    class _Actor(nn.Module):  # type: ignore[name-defined,misc]
        def __init__(self) -> None:
            super().__init__()
            self.cnn = _Encoder()
            self.l1 = nn.Linear(3136, hidden)
            self.l2 = nn.Linear(hidden, hidden)
            self.mean_layer = nn.Linear(hidden, 1)
            self.log_std_layer = nn.Linear(hidden, 1)

        def forward(self, x: Any) -> Any:
            h = torch.relu(self.l1(self.cnn(x)))
            h = torch.relu(self.l2(h))
            return torch.tanh(self.mean_layer(h))

    return _Actor()


def save_random_actor(path: str | Path, seed: int = 0) -> Path:
    """Write the ``state_dict`` of a seeded, randomly initialised actor to ``path`` (tests, demos). Returns the path."""
    torch = _torch()
    torch.manual_seed(seed)
    actor = build_actor()
    p = Path(path)
    torch.save(actor.state_dict(), p)
    return p


def check_weights_path(weights: str | Path | None) -> Path:
    """The weights path, or BracketryError (one line) when none is given or the file does not exist."""
    if weights is None or str(weights) == "":
        raise BracketryError("the drl method needs its weights: pass --drl-weights PATH/actor_drl_feat_10000.pth "
                             "(ShuyangUni/drl_exposure_ctrl, model/)")
    path = Path(weights)
    if not path.is_file():
        raise BracketryError(f"DRL weights not found: {path}")
    return path


def load_actor(weights: str | Path | None) -> Any:
    """The actor with the weights of a ``.pth`` state_dict (the public ``actor_drl_feat_10000.pth``), in eval mode.

    Raises BracketryError with one clear line when no file is given, the file is missing or unreadable, or its
    tensors do not match the architecture.
    """
    path = check_weights_path(weights)
    torch = _torch()
    try:
        state = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:
        first = (str(exc).strip().splitlines() or [""])[0][:200]  # torch adds paragraphs of advice
        raise BracketryError(f"cannot read DRL weights {path} (not a PyTorch state_dict .pth?): "
                             f"{type(exc).__name__}: {first}") from exc
    if isinstance(state, dict) and "actor" in state and isinstance(state["actor"], dict):
        state = state["actor"]
    if not isinstance(state, dict):
        raise BracketryError(f"DRL weights {path} are not a state_dict (got {type(state).__name__})")
    actor = build_actor()
    expected = actor.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        raise BracketryError(f"DRL weights {path} do not match the actor: missing {missing[:3]}, "
                             f"unexpected {unexpected[:3]}")
    for key, tensor in expected.items():
        if tuple(state[key].shape) != tuple(tensor.shape):
            raise BracketryError(f"DRL weights {path} do not match the actor: {key} has shape "
                                 f"{tuple(state[key].shape)}, expected {tuple(tensor.shape)}")
    actor.load_state_dict(state)
    actor.eval()
    return actor


def frame_state(image: np.ndarray) -> np.ndarray:
    """One state frame: the mosaic area-resized to 84x84, divided by 4096 -> float32 (84, 84) in [0, 1)."""
    small = cv2.resize(image.astype(np.float32), (FRAME_SIZE, FRAME_SIZE), interpolation=cv2.INTER_AREA)
    return small / 4096.0


class DrlAE:
    """The DRL agent in closed loop (see the module docstring). ``weights``: path of the actor's ``.pth``."""

    #: relative cost of one step, for balancing worker processes (see registry.MethodTraits)
    step_cost = 3
    #: its first steps are the classical-50 steps (see registry.MethodTraits)
    step_group = "classical-50-default"
    #: creating it starts torch's threads: worker processes create it after the fork; the parent only calls
    #: :meth:`check_options`
    created_in_worker = True

    @staticmethod
    def check_options(drl_weights: str | Path | None = None, **_: object) -> None:
        """Refuse missing weights (one line) without creating the actor."""
        check_weights_path(drl_weights)

    def __init__(self, weights: str | Path | None = None, warmup_steps: int = N_FRAMES, name: str = "drl") -> None:
        self.actor = load_actor(weights)
        self.warmup_steps = warmup_steps
        self.name = name
        self._classical = ClassicalAE(50.0)
        torch = _torch()
        torch.set_num_threads(1)
        self.reset(0.0)

    def reset(self, init_exposure_us: float) -> None:
        self._frames: deque[np.ndarray] = deque(maxlen=N_FRAMES)
        self._calls = 0
        self.last_action: float | None = None

    def action(self, frames: np.ndarray) -> float:
        """The deterministic action a in (-1, 1) for a float32 (4, 84, 84) state."""
        torch = _torch()
        with torch.no_grad():
            out = self.actor(torch.from_numpy(np.ascontiguousarray(frames, dtype=np.float32))[None])
        return float(out.reshape(-1)[0])

    def next_exposure_us(self, image: np.ndarray, exposure_us: float, meta: dict[str, Any]) -> float:
        check_input(image, exposure_us)
        self._frames.append(frame_state(image))
        calls = self._calls
        self._calls += 1
        if calls < self.warmup_steps or len(self._frames) < N_FRAMES:
            return self._classical.next_exposure_us(image, exposure_us, meta)
        a = self.action(np.stack(list(self._frames)))
        self.last_action = a
        return float(np.clip(exposure_us * 2.0 ** (2.0 * a), MIN_EXPOSURE_US, MAX_EXPOSURE_US))
