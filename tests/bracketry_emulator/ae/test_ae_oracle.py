"""The oracle (non-causal control): its grid, its look-ahead through the real closed loop, in and out of process."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tests.emu_synthetic import BRACKETS_US, render

from bracketry_emulator.ae import run_methods
from bracketry_emulator.ae.oracle import OracleAE, exposure_grid_us
from bracketry_emulator.ae.registry import get_method, method_traits
from bracketry_emulator.dataset import write_png16

#: brightness of each bracket sequence: bright, then 64x darker from sequence 3 on (a canopy entered)
SCALES = (1.0, 1.0, 1.0, 1 / 64, 1 / 64, 1 / 64)


def _textured(h: int = 120, w: int = 160, seed: int = 3) -> np.ndarray:
    """float64 HxW irradiance (DN/us): 4-px blocks of random levels (good ORB corners), mid-grey at ~4 ms."""
    rng = np.random.default_rng(seed)
    blocks = rng.uniform(0.05, 0.6, size=(h // 4, w // 4))
    return np.kron(blocks, np.ones((4, 4)))


def _tree(root: Path, scales: tuple[float, ...] = SCALES) -> Path:
    irr = _textured()
    rng = np.random.default_rng(0)
    t = 1_700_000_000_000_000_000
    for k, scale in enumerate(scales):
        shifted = np.roll(irr, 2 * k, axis=1)  # the camera pans 2 px per sequence
        for e in BRACKETS_US:
            for side in ("left", "right"):
                write_png16(root / f"camera_{side}" / f"{e / 1000:.1f}" / f"{t}.png",
                            render(shifted * scale, e, rng))
            t += 45_000_000
    return root


def test_grid_half_stops_within_bounds() -> None:
    grid = exposure_grid_us(0.25, 32.0, 2, (20.0, 64_000.0))
    assert len(grid) == 15 and grid[0] == 250.0 and grid[-1] == 32_000.0
    assert np.allclose(np.diff(np.log2(grid)), 0.5)
    assert exposure_grid_us(0.25, 32.0, 2, (1000.0, 8000.0)) == [1000.0, 1414.214, 2000.0, 2828.427, 4000.0,
                                                                  5656.854, 8000.0]


def test_oracle_is_declared_non_causal_and_refuses_to_run_without_the_look_ahead() -> None:
    assert method_traits("oracle").looks_ahead and not method_traits("ae50").looks_ahead
    oracle = get_method("oracle")
    assert getattr(oracle, "non_causal", False)
    oracle.reset(4000.0)
    with pytest.raises(ValueError, match="look-ahead"):
        oracle.next_exposure_us(np.zeros((8, 8), np.uint16), 4000.0, {"step": 0})


@pytest.mark.parametrize("workers", [1, 2])
def test_oracle_reads_the_next_step_and_reacts_before_the_change(tmp_path: Path, workers: int) -> None:
    """The scene darkens 6 stops at sequence 3: the oracle's target FOR step 3 (chosen at step 2, from the look
    ahead) is already >= 2 stops longer than its bright-scene targets; the causal AE50 only reacts after seeing
    step 3. The same exposures with the oracle in this process and in a forked worker."""
    data = _tree(tmp_path / "data")
    summary = run_methods(data, ["oracle", "ae50"], tmp_path / f"out{workers}", workers=workers, progress=False)
    oracle = summary.runs["oracle"].exposures_ms
    ae50 = summary.runs["ae50"].exposures_ms
    bright = max(oracle[1:3])
    assert oracle[3] >= 4 * bright, oracle
    assert ae50[3] < 2 * ae50[2], ae50  # the causal method has not seen the change yet
    if workers == 2:
        single = run_methods(data, ["oracle", "ae50"], tmp_path / "single", workers=1, progress=False)
        assert single.runs["oracle"].exposures_ms == oracle


def test_oracle_last_step_keeps_its_exposure(tmp_path: Path) -> None:
    data = _tree(tmp_path / "data", (1.0, 1.0))
    run = run_methods(data, ["oracle"], tmp_path / "out", workers=1, progress=False).runs["oracle"]
    assert len(run.steps) == 2 and run.steps[-1].next_exposure_us == run.steps[-1].exposure_us


def test_oracle_choice_is_the_best_score_of_its_grid() -> None:
    """The answer is a grid exposure whose tracked share is within 5 % of the best one evaluated."""
    oracle = OracleAE()
    irr = _textured()
    frames = {k: np.roll(irr, 2 * k, axis=1) for k in (0, 1)}
    oracle.reset(4000.0)
    meta = {"bounds_us": (20.0, 64_000.0),
            "look_ahead": lambda e, off: render(frames[off], e)}
    out = oracle.next_exposure_us(render(frames[0], 4000.0), 4000.0, meta)
    scores = oracle.last_scores
    assert out in scores and scores[out] >= 0.95 * max(scores.values()) > 0.2
    assert scores[32_000.0] < scores[out] and scores[250.0] < scores[out]  # saturated / dark frames track less
