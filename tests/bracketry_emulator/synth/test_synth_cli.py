"""`bracketry synth trajectory|static`: the written trees, their files and error handling."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry.cli import main


def test_synth_trajectory_writes_borealhdr_tree(tmp_path: Path) -> None:
    out = tmp_path / "walk"
    rc = main(["synth", "trajectory", "--out", str(out), "--resolution", "64x40", "--seconds", "0.3", "-q"])
    assert rc == 0
    for side in ("left", "right"):
        folders = sorted(p.name for p in (out / f"camera_{side}").iterdir())
        assert folders == sorted(["1.0", "2.0", "4.0", "8.0", "16.0", "32.0"])
        pngs = sorted((out / f"camera_{side}" / "8.0").glob("*.png"))
        assert len(pngs) == 1
        img = cv2.imread(str(pngs[0]), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint16 and img.shape == (40, 64) and img.max() <= 4094
    gt = [ln for ln in (out / "groundtruth.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(gt) == 6 and all(len(ln.split()) == 8 for ln in gt)
    stamps = sorted(int(p.stem) for p in (out / "camera_left").glob("*/*.png"))
    assert [int(ln.split()[0].replace(".", "")) for ln in gt] == stamps
    for name in ("left.yaml", "right.yaml", "pcalib.txt", "calib_kitti.txt"):
        assert (out / "calibration" / name).is_file()
    assert len(np.loadtxt(out / "calibration" / "pcalib.txt")) == 256
    model = json.loads((out / "camera_model.json").read_text())
    assert model["response"] == "srgb" and model["world"]["baseline_m"] == 0.18


def test_synth_static_writes_protocol(tmp_path: Path) -> None:
    out = tmp_path / "static"
    rc = main(["synth", "static", "--out", str(out), "--resolution", "32x20", "--n-exposures", "5", "--repeats", "3",
               "--repeat-ms", "1,8", "--brackets-ms", "1,4", "-q"])
    assert rc == 0
    index = json.loads((out / "static.json").read_text())
    assert index["sweep"]["n"] == 5 and len(list((out / "sweep").glob("*.png"))) == 5
    assert len(list((out / "truth" / "sweep").glob("*.png"))) == 5
    assert len(index["repeats"]["files"]["8000"]) == 3
    assert sorted(p.name for p in (out / "camera_left").iterdir()) == ["1.0", "4.0"]
    rate = np.load(out / "truth" / "rate_e_per_us.npy")
    assert rate.shape == (20, 32) and rate.dtype == np.float32


@pytest.mark.parametrize("args, message", [
    (["--resolution", "33x20"], "even"),
    (["--brackets-ms", "1,x"], "milliseconds"),
    (["--brackets-ms", "1,50"], "frame period"),
    (["--response", "/nonexistent/pcalib.txt"], "pcalib"),
])
def test_synth_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture, args: list[str],
                                     message: str) -> None:
    rc = main(["synth", "trajectory", "--out", str(tmp_path / "x"), "--seconds", "0.3", "-q", *args])
    err = capsys.readouterr().err
    assert rc != 0 and message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_synth_refuses_non_empty_out(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "keep.txt").write_text("x")
    rc = main(["synth", "trajectory", "--out", str(tmp_path), "--seconds", "0.3", "--resolution", "32x20", "-q"])
    assert rc == 2 and "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "keep.txt").read_text() == "x"


@pytest.mark.realdata
def test_synth_default_intrinsics_are_the_real_calibration(borealhdr_sample: Path, tmp_path: Path) -> None:
    from bracketry_emulator.synth.calibration import default_calibration, load_calibration

    real = load_calibration(borealhdr_sample / "calibration", 1920, 1200)
    embedded = default_calibration()
    for side in ("left", "right"):
        assert np.allclose(real.side(side).K, embedded.side(side).K)
        assert np.allclose(real.side(side).D, embedded.side(side).D)
    # --calibration and a pcalib response through the CLI
    out = tmp_path / "w"
    rc = main(["synth", "trajectory", "--out", str(out), "--resolution", "96x60", "--seconds", "0.3", "-q",
               "--calibration", str(borealhdr_sample / "calibration"),
               "--response", str(borealhdr_sample / "calibration" / "pcalib_inside1.txt")])
    assert rc == 0
    model = json.loads((out / "camera_model.json").read_text())
    assert model["response"] == "pcalib" and len(model["pcalib"]) == 256
    assert np.allclose(np.loadtxt(out / "calibration" / "pcalib.txt"), model["pcalib"])
    left = (out / "calibration" / "left.yaml").read_text()
    assert "image_width: 96" in left


def test_synth_groundtruth_reads_with_evo(tmp_path: Path) -> None:
    from evo.tools import file_interface

    out = tmp_path / "walk"
    assert main(["synth", "trajectory", "--out", str(out), "--resolution", "32x20", "--seconds", "1.1", "-q"]) == 0
    traj = file_interface.read_tum_trajectory_file(str(out / "groundtruth.txt"))
    assert traj.num_poses == 24
    # 2 km/h walk, plus the backpack's gait sway (2.5 cm per stride: 7 % more path over 1 s)
    assert traj.path_length / (traj.timestamps[-1] - traj.timestamps[0]) == pytest.approx(2.0 / 3.6, rel=0.1)
