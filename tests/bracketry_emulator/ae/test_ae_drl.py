"""DRL actor (seeded random weights saved to tmp): architecture, bounds, determinism, weight errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ae_scenes import irradiance, render

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae import get_method
from bracketry_emulator.ae.classical import ClassicalAE
from bracketry_testkit import STRICT

try:
    import torch
except ImportError:  # the drl extra; CI installs it (strict mode fails here instead of skipping)
    if STRICT:
        raise
    pytest.skip("torch is not installed (pip install -e '.[drl]')", allow_module_level=True)

from bracketry_emulator.ae import drl


@pytest.fixture(scope="module")
def weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return drl.save_random_actor(tmp_path_factory.mktemp("drl") / "actor.pth", seed=7)


def test_actor_architecture_and_output_shape(weights: Path) -> None:
    actor = drl.load_actor(weights)
    n_params = sum(p.numel() for p in actor.parameters())
    assert n_params == 1_947_810  # the published actor's size (mean + log_std heads)
    out = actor(torch.zeros(3, 4, 84, 84))
    assert tuple(out.shape) == (3, 1)
    assert torch.all(out.abs() < 1)


def test_drl_warmup_bounds_and_determinism(weights: Path) -> None:
    scene = irradiance()
    runs = []
    for _ in range(2):
        m = get_method("drl", drl_weights=str(weights))
        m.reset(4000.0)
        t, traj, acts = 4000.0, [], []
        for k in range(8):
            img = render(scene, t)
            nxt = m.next_exposure_us(img, t, {"step": k})
            if k < 4:  # warm-up: the classical-50 step
                assert nxt == pytest.approx(ClassicalAE(50).next_exposure_us(img, t, {}))
            else:
                a = m.last_action
                assert a is not None and -1 < a < 1
                assert nxt == pytest.approx(float(np.clip(t * 2 ** (2 * a), 50, 2e6)))
                assert t / 4 - 1e-6 <= nxt <= t * 4 + 1e-6
                acts.append(a)
            traj.append(nxt)
            t = nxt
        runs.append((traj, acts))
    assert runs[0] == runs[1]


def test_drl_frame_state_shape_and_range() -> None:
    st = drl.frame_state(np.full((1200, 1920), 4094, np.uint16))
    assert st.shape == (84, 84) and st.dtype == np.float32
    assert 0.99 < float(st.max()) < 1.0


def test_drl_weights_errors(tmp_path: Path) -> None:
    with pytest.raises(BracketryError, match="needs its weights"):
        drl.load_actor(None)
    with pytest.raises(BracketryError, match="not found"):
        drl.load_actor(tmp_path / "missing.pth")
    bad = tmp_path / "bad.pth"
    bad.write_bytes(b"not a torch file")
    with pytest.raises(BracketryError, match="cannot read"):
        drl.load_actor(bad)
    wrong = tmp_path / "wrong.pth"
    torch.save({"cnn.conv1.weight": torch.zeros(1)}, wrong)
    with pytest.raises(BracketryError, match="do not match"):
        drl.load_actor(wrong)
    state = drl.build_actor().state_dict()
    state["l1.weight"] = torch.zeros(512, 100)
    torch.save(state, tmp_path / "shape.pth")
    with pytest.raises(BracketryError, match=r"l1\.weight has shape"):
        drl.load_actor(tmp_path / "shape.pth")
