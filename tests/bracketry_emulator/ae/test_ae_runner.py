"""The closed-loop runner on a tiny synthetic BorealHDR tree: layout, links, overwrite, sides, bounds, plugins."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from ae_scenes import irradiance, render

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae import run_methods

EXPOSURES_MS = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0)


def tiny_tree(root: Path, n_seq: int = 3) -> Path:
    """A BorealHDR tree of ``n_seq`` complete sequences of 48x64 frames (right camera 1.5x brighter)."""
    rec = root / "rec"
    irr = irradiance(48, 64, seed=2)
    t_ns = 1_700_000_000_000_000_000
    for _ in range(n_seq):
        for ms in EXPOSURES_MS:
            for side, gain in (("left", 1.0), ("right", 1.5)):
                d = rec / f"camera_{side}" / f"{ms:.1f}"
                d.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(d / f"{t_ns}.png"), render(irr * gain, ms * 1000))
            t_ns += 46_000_000
    return rec


PLUGIN = ("class Doubler:\n    name = 'doubler'\n    def reset(self, t):\n        pass\n"
          "    def next_exposure_us(self, image, t, meta):\n        return 2 * t\n")


def test_layout_links_and_plot(tmp_path: Path) -> None:
    rec = tiny_tree(tmp_path)
    s = run_methods(rec, ["fix", "ae50", "ae70", "constant-3"], tmp_path / "out", workers=1, progress=False)
    assert s.n_sequences == 3 and s.sides == ("left", "right")
    for m in ("fix", "ae50", "ae70", "constant-3"):
        d = tmp_path / "out" / m
        assert len(list((d / "images_left").glob("*.png"))) == 3
        assert len(list((d / "images_right").glob("*.png"))) == 3
        assert len((d / "times_images_left.txt").read_text().splitlines()) == 3
        assert len((d / "ae.csv").read_text().splitlines()) == 4
    # identical images (same sequence, side and target) are hard links: step 0 is 4 ms for every method
    a = sorted((tmp_path / "out" / "fix" / "images_left").glob("*.png"))
    b = sorted((tmp_path / "out" / "ae50" / "images_left").glob("*.png"))
    assert [p.name for p in a] == [p.name for p in b]
    assert a[0].stat().st_ino == b[0].stat().st_ino
    c = sorted((tmp_path / "out" / "ae70" / "images_left").glob("*.png"))
    assert c[0].stat().st_ino == a[0].stat().st_ino  # step 0: every method at 4 ms
    assert c[1].stat().st_ino != a[1].stat().st_ino
    assert s.runs["constant-3"].exposures_ms == [3.0, 3.0, 3.0]
    assert (tmp_path / "out" / "exposure_times.png").stat().st_size > 1000
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert doc["init_exposure_ms"] == 4.0 and list(doc["methods"]) == ["fix", "ae50", "ae70", "constant-3"]


def test_overwrite_does_not_write_through_links(tmp_path: Path) -> None:
    rec = tiny_tree(tmp_path, 2)
    out = tmp_path / "out"
    run_methods(rec, ["fix", "ae50"], out, workers=1, progress=False)
    fix_first = sorted((out / "fix" / "images_left").glob("*.png"))[0]
    before = cv2.imread(str(fix_first), cv2.IMREAD_UNCHANGED)
    with pytest.raises(BracketryError, match="already holds a run"):
        run_methods(rec, ["ae50"], out, workers=1, progress=False)
    run_methods(rec, ["ae50"], out, workers=1, progress=False, overwrite=True, init_exposure_us=1000.0)
    assert np.array_equal(cv2.imread(str(fix_first), cv2.IMREAD_UNCHANGED), before)


def test_right_camera_drives_and_bounds_clamp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rec = tiny_tree(tmp_path, 3)
    (tmp_path / "ae_runner_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    left = run_methods(rec, ["ae50"], tmp_path / "l", workers=1, progress=False, write_images=False)
    right = run_methods(rec, ["ae50", "ae_runner_plugin:Doubler"], tmp_path / "r", workers=2, progress=False,
                        camera="right", ae_camera="right", max_exposure_us=10_000.0)
    assert right.sides == ("right",)
    assert not (tmp_path / "r" / "ae50" / "images_left").exists()
    # the right camera is brighter, so AE50 driven by it chooses a shorter exposure
    assert right.runs["ae50"].exposures_ms[1] < left.runs["ae50"].exposures_ms[1]
    assert right.runs["doubler"].exposures_ms == [4.0, 8.0, 10.0]
    assert (tmp_path / "r" / "doubler" / "steps.csv").is_file()


def test_bad_settings(tmp_path: Path) -> None:
    rec = tiny_tree(tmp_path, 1)
    with pytest.raises(BracketryError, match="outside the bounds"):
        run_methods(rec, ["ae50"], tmp_path / "o", progress=False, init_exposure_us=100_000.0)
    with pytest.raises(BracketryError, match="camera"):
        run_methods(rec, ["ae50"], tmp_path / "o", progress=False, camera="middle")
    with pytest.raises(BracketryError, match="unknown AE method"):
        run_methods(rec, ["nope"], tmp_path / "o", progress=False)


@pytest.mark.parametrize("workers", ["1", "2"])
def test_emulate_reports_a_corrupt_png_and_an_incomplete_sequence_in_one_line(
        tmp_path: Path, workers: str, capsys: pytest.CaptureFixture[str]) -> None:
    from bracketry.cli import main

    rec = tiny_tree(tmp_path, 3)
    lost = sorted((rec / "camera_left" / "8.0").glob("*.png"))[-1]
    lost.unlink()  # the last sequence is incomplete: skipped and reported, not fatal
    assert main(["emulate", str(rec), "-m", "ae50,fix", "-o", str(tmp_path / "ok"), "-j", workers, "-q"]) == 0
    err = capsys.readouterr().err
    assert "warning: dataset:" in err and "incomplete" in err, err
    doc = json.loads((tmp_path / "ok" / "summary.json").read_text())
    assert doc["sequences"] == 2 and doc["dataset_problems"]

    bad = sorted((rec / "camera_left" / "4.0").glob("*.png"))[1]  # read once the run is under way
    data = bytearray(bad.read_bytes())
    data[8:40] = bytes(32)  # a broken header (no IHDR chunk first)
    bad.write_bytes(bytes(data))
    code = main(["emulate", str(rec), "-m", "ae50,fix", "-o", str(tmp_path / "bad"), "-j", workers, "-q"])
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err, err
    assert bad.name in err and "BufferError" not in err, err


def test_emulate_fusion_options_and_noise_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from bracketry.cli import main
    from bracketry_emulator.emulation import NoiseModel

    rec = tiny_tree(tmp_path, 2)
    noise = tmp_path / "noise.json"
    NoiseModel(read_dn=2.5, dn_per_e=0.125).to_json(noise)
    args = ["emulate", str(rec), "-m", "ae50", "-j", "1", "-q", "--selection", "fusion", "--fusion-brackets", "all",
            "--motion", "translation", "--deghost-sigma", "4"]
    assert main([*args, "-o", str(tmp_path / "a"), "--noise", str(noise)]) == 0
    emu = json.loads((tmp_path / "a" / "summary.json").read_text())["emulator"]
    assert emu["fusion_brackets"] == "all" and emu["motion"] == "translation" and emu["deghost_sigma"] == 4
    assert emu["noise"] == {"read_dn": 2.5, "dn_per_e": 0.125}
    # a synthetic world's camera_model.json at the dataset root is the default model
    (rec / "camera_model.json").write_text(json.dumps({"read_noise_e": 3.0, "gain_e_per_dn": 6.0}))
    assert main([*args, "-o", str(tmp_path / "b")]) == 0
    emu = json.loads((tmp_path / "b" / "summary.json").read_text())["emulator"]
    assert emu["noise"] == {"read_dn": 0.5, "dn_per_e": pytest.approx(1 / 6)}
    capsys.readouterr()
    assert main(["emulate", str(rec), "-m", "ae50", "-o", str(tmp_path / "c"), "--motion", "homography"]) == 2
    assert "need --selection fusion" in capsys.readouterr().err
    noise.write_text("{}")
    assert main([*args, "-o", str(tmp_path / "d"), "--noise", str(noise)]) == 2
    assert "not a noise model" in capsys.readouterr().err


def test_warmup_steps_run_on_the_first_sequence_and_write_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                                  ) -> None:
    """The scheduler's warm-up (in-process and in worker processes): the doubler takes 3 steps on the first view
    before the run (4 -> 32 ms), then one step per sequence; only the run's steps are written."""
    rec = tiny_tree(tmp_path, 3)
    (tmp_path / "ae_runner_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        res = run_methods(rec, ["ae50", "ae_runner_plugin:Doubler"], out, workers=workers, progress=False,
                          warmup_steps=3, max_exposure_us=1_000_000.0)
        assert res.runs["doubler"].exposures_ms == [32.0, 64.0, 128.0]
        assert len(res.runs["ae50"].steps) == 3
        assert len((out / "doubler" / "steps.csv").read_text().splitlines()) == 1 + 3
        assert len(list((out / "doubler" / "images_left").iterdir())) == 3
        cold = run_methods(rec, ["ae50"], tmp_path / f"c{workers}", workers=workers, progress=False,
                           write_images=False)
        # AE50 warmed on the first view starts nearer its settled exposure than from the 4 ms first target
        settled = cold.runs["ae50"].exposures_ms[-1]
        assert abs(res.runs["ae50"].exposures_ms[0] - settled) < abs(cold.runs["ae50"].exposures_ms[0] - settled)
