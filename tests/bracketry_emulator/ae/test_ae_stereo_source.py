"""One source bracket per stereo step: both cameras' images of a step come from the same capture."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from ae_scenes import irradiance, render
from test_ae_runner import tiny_tree

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae import run_methods
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation import Emulator, EmulatorConfig, RunWriter


def brackets(gain: float) -> dict[int, np.ndarray]:
    irr = irradiance(48, 64, seed=3)
    return {ms * 1000: render(irr * gain, ms * 1000.0) for ms in (1, 2, 4, 8, 16, 32)}


def test_the_decision_uses_the_more_saturated_camera() -> None:
    left, right = brackets(0.3), brackets(0.5)
    emu = Emulator(EmulatorConfig())
    sat = {e: float(np.mean(img >= 4094)) for e, img in right.items()}
    assert sat[16000] > 0.01 and float(np.mean(left[16000] >= 4094)) <= 0.01  # the cameras disagree at 16 ms
    assert emu.select(left, 12000.0) == 16000 and emu.select(right, 12000.0) == 8000
    assert emu.select_stereo({"left": left, "right": right}, 12000.0) == 8000
    assert emu.select_stereo({"left": left, "right": right}, 12000.0, decide=("left",)) == 16000
    for sel in ("highernosat", "upstream", "fusion"):
        e = Emulator(EmulatorConfig(selection=sel))  # type: ignore[arg-type]
        src = e.select_stereo({"left": left, "right": right}, 12000.0)
        outs = [e.emulate(b, 12000.0, src) for b in (left, right)]
        assert outs[0].source_exposure_us == outs[1].source_exposure_us == src
    with pytest.raises(BracketryError):
        emu.emulate(left, 12000.0, 3000)


@pytest.mark.parametrize("selection", ["highernosat", "fusion"])
def test_closed_loop_left_and_right_share_bracket_name_and_timestamp(tmp_path: Path, selection: str) -> None:
    from bracketry_emulator.ae import LoopConfig

    rec = tiny_tree(tmp_path, n_seq=4)  # right camera 1.5x brighter: its saturation differs from the left's
    cfg = LoopConfig(emulator=EmulatorConfig(selection=selection), init_exposure_us=6000.0)  # type: ignore[arg-type]
    run_methods(rec, ["ae70", "constant-6", "constant-3"], tmp_path / "out", workers=1, config=cfg,
                progress=False)
    ds = open_dataset(rec)
    seqs = ds.sequences()
    emu = Emulator(EmulatorConfig(selection=selection))  # type: ignore[arg-type]
    own = {side: emu.select(seqs[0].load(side), 6000.0) for side in ("left", "right")}
    assert own["left"] != own["right"]  # each camera alone would take another bracket at 6 ms
    for m in ("ae70", "constant-6", "constant-3"):
        d = tmp_path / "out" / m
        names = {side: sorted(p.name for p in (d / f"images_{side}").iterdir()) for side in ("left", "right")}
        assert names["left"] == names["right"] and len(names["left"]) == 4
        times = {side: (d / f"times_images_{side}.txt").read_text() for side in ("left", "right")}
        assert times["left"] == times["right"]
        rows = list(csv.DictReader((d / "steps.csv").open()))
        assert all(r["mode"] == "default" for r in rows)
        for r, seq in zip(rows, seqs, strict=True):
            src = round(float(r["source_exposure_ms"]) * 1000)
            assert int(r["timestamp_ns"]) == seq.timestamps_ns["left"][src]


def test_writer_refuses_images_from_different_brackets(tmp_path: Path) -> None:
    rec = tiny_tree(tmp_path, n_seq=1)
    seq = open_dataset(rec).sequences()[0]
    emu = Emulator(EmulatorConfig())
    imgs = {side: emu.emulate(seq.load(side), 6000.0) for side in ("left", "right")}
    assert imgs["left"].source_exposure_us != imgs["right"].source_exposure_us
    with RunWriter(tmp_path / "w", "m", ("left", "right")) as w, pytest.raises(BracketryError, match="one source"):
        w.write_step(0, seq, imgs, 6000.0)
