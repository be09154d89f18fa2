"""Accuracy protocols: static stack (synthetic, noise-free truth) and neighbours (real sample), CLI outputs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bracketry.cli import main
from bracketry_emulator.accuracy import noise_corrected, noise_floor_dn, open_static_stack, rmse_dn, run_static
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.synth import CameraModel
from emu_synthetic import radiance_map, write_tree


def linear_camera() -> CameraModel:
    """The camera of ``bracketry synth static``: the default one without blooming. The protocol measures the
    emulation of a linear sensor; with the default's blooming (0.3) the truth frames hold charge no bracket has
    (forest-winter seed 12 at 160x100: HigherNoSat's in-range median 24.0 DN instead of 14.4, fusion 14 % worse
    than HigherNoSat instead of 71 % better)."""
    return CameraModel(blooming=0.0)


@pytest.fixture(scope="module")
def synth_stack(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small static stack written by the synthetic world (bracketry synth static's writer, its camera without
    blooming: see :func:`linear_camera`)."""
    from bracketry_emulator.synth.world import World
    from bracketry_emulator.synth.writer import write_static

    out = tmp_path_factory.mktemp("static")
    write_static(World(seed=3, resolution=(128, 80), camera=linear_camera()), out, n_exposures=48, repeats=6,
                 repeat_exposures_ms=(0.1, 1.0, 8.0, 32.0))
    return out


def test_emu_metrics() -> None:
    a = np.zeros((4, 4), np.uint16)
    b = np.full((4, 4), 3, np.uint16)
    assert rmse_dn(a, b) == 3.0
    assert noise_corrected(5.0, 3.0) == 4.0 and noise_corrected(2.0, 3.0) == 0.0
    rng = np.random.default_rng(0)
    frames = [(1000 + rng.normal(0, 4, (200, 200))).astype(np.uint16) for _ in range(6)]
    assert noise_floor_dn(frames) == pytest.approx(4 * np.sqrt(2), rel=0.05)


def test_emu_static_protocol_on_synthetic_stack(synth_stack: Path) -> None:
    stack = open_static_stack(synth_stack)
    assert sorted(stack.brackets) == [1000, 2000, 4000, 8000, 16000, 32000]
    assert len(stack.sweep) == 48 and all(s.truth_path is not None for s in stack.sweep)
    res = run_static(stack)
    assert res["n_targets"] == 48
    s = res["summary"]
    # this tiny view has a sun saturated even at 1 ms, so targets far below the bracket range cannot be exact, and
    # > 1 % saturation pushes HigherNoSat to the lower bracket (noise x2); the goal run at full size is reported
    assert s["highernosat"]["corrected"]["in_bracket_range"]["median"] <= 20.0
    assert s["highernosat"]["corrected"]["all"]["max"] <= 73.0
    # fusion: lower error against the noise-free truth inside the bracket range, never worse
    h = s["highernosat"]["truth"]["in_bracket_range"]["median"]
    f = s["fusion"]["truth"]["in_bracket_range"]["median"]
    assert f < 0.65 * h  # the goal: 35 % lower
    assert res["goals"]["fusion_median_reduction_truth"]["met"]
    assert res["goals"]["fusion_not_worse_any_target_raw"]["met"]
    assert res["goals"]["fusion_not_worse_any_target_truth"]["met"]
    row = res["targets"][-1]
    assert set(row["brackets"]) == {"1000", "2000", "4000", "8000", "16000", "32000"}
    json.dumps(res)


def test_emu_accuracy_static_command(synth_stack: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "acc"
    rc = main(["accuracy", "static", str(synth_stack), "--out", str(out), "--max-targets", "12"])
    assert rc in (0, 1)  # 1 = a HigherNoSat goal missed
    res = json.loads((out / "accuracy_static.json").read_text())
    assert res["n_targets"] == 12
    assert (out / "accuracy_static.png").stat().st_size > 10_000
    text = capsys.readouterr().out
    assert "highernosat" in text and "goal highernosat_max_le_73dn: met" in text
    assert main(["accuracy", "static", str(tmp_path / "missing")]) == 2


def test_emu_accuracy_static_on_plain_tree(tmp_path: Path) -> None:
    root = write_tree(tmp_path / "tree", 0.05 * radiance_map(40, 60), n_sequences=3, sides=("left",))
    stack = open_static_stack(root)
    assert len(stack.sweep) == 18 and len(stack.repeats) == 6
    res = run_static(stack, modes=("highernosat", "fusion"))
    assert res["summary"]["fusion"]["raw"]["all"]["median"] <= res["summary"]["highernosat"]["raw"]["all"]["median"]


@pytest.mark.realdata
def test_emu_neighbours_on_sample(borealhdr_sample: Path) -> None:
    from bracketry_emulator.accuracy import run_neighbours

    ds = open_dataset(borealhdr_sample)
    res = run_neighbours(ds, sides=("left",), max_sequences=1, crop=(600, 960))
    assert res["n_pairs"] == 4  # targets 2, 4, 8, 16 ms
    summ = res["summary"]
    for al in ("none", "homography"):
        assert summ[al]["fusion"]["rmse_dn"]["median"] < summ[al]["highernosat"]["rmse_dn"]["median"]
        assert abs(summ[al]["fusion"]["bias_dn"]["median"]) < 40  # photometry right to ~2% of the mean level
    assert summ["homography"]["from-lower"]["rmse_dn"]["median"] < summ["none"]["from-lower"]["rmse_dn"]["median"]


@pytest.mark.realdata
def test_emu_accuracy_neighbours_command(borealhdr_sequence: Path, tmp_path: Path) -> None:
    out = tmp_path / "nb"
    rc = main(["accuracy", "neighbours", str(borealhdr_sequence), "--out", str(out), "--camera", "right",
               "--max-sequences", "1", "--alignment", "translation"])
    assert rc == 0
    res = json.loads((out / "accuracy_neighbours.json").read_text())
    assert res["sides"] == ["right"] and set(res["summary"]) == {"none", "translation"}
    assert (out / "accuracy_neighbours.png").is_file()


@pytest.mark.parametrize("preset,seed", [("campus-summer", 11), ("forest-winter", 12)])
def test_emu_fusion_goal_on_static_stacks_of_other_worlds(preset: str, seed: int, tmp_path: Path) -> None:
    """Fusion (default bracket set: the pair around the target and every longer bracket) is >= 35 % below
    HigherNoSat against the noise-free truth inside the bracket range (median), and not worse at any target."""
    from bracketry_emulator.synth.world import World
    from bracketry_emulator.synth.writer import write_static

    write_static(World(preset=preset, seed=seed, resolution=(160, 100), camera=linear_camera()), tmp_path,
                 n_exposures=30, repeats=2, repeat_exposures_ms=(1.0, 8.0))
    res = run_static(open_static_stack(tmp_path), modes=("highernosat", "fusion"))
    g = res["goals"]
    assert g["fusion_median_reduction_truth"]["value"] >= 0.35, g
    assert g["fusion_not_worse_any_target_truth"]["met"] and g["fusion_not_worse_any_target_raw"]["met"], g
