"""Inputs that would make results lie: a bad vocabulary, a broken set-up (swapped cameras, wrong focal length).

A header-only, truncated, garbage or compressed vocabulary is one line, exit 2, through ``bracketry benchmark``
before any run; the ORB-SLAM3 set-up check (middle bracket, no AE) refuses swapped cameras and a focal length 3x
off, and passes a good set-up. Lean: a 3 s synthetic 320x240 trajectory and a k=8, L=4 vocabulary trained on a
toy corridor (as tests/bracketry_emulator/slam/test_bench_orbslam3.py); every ORB-SLAM3 run is a real child.
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import pytest
import yaml

from bracketry.cli import main as cli_main
from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.slam.setup_check import SetupCheckError, Trajectory, check_setup
from bracketry_emulator.slam.vocabulary_check import VocabularyError, check_vocabulary

pytestmark = pytest.mark.orbslam3


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A bracketed trajectory, its twin with the cameras swapped, a twin with the focal length 3x, a vocabulary."""
    root = tmp_path_factory.mktemp("setup_check")
    walk = root / "walk"
    assert cli_main(["synth", "trajectory", "--out", str(walk), "--seconds", "3", "--resolution", "320x240",
                     "-q"]) == 0
    ToyWorld(width_px=320, height_px=240, fx_px=240.0, seed=99).write_run(root / "train", "x", 6, t0_ns=90 * 10**9)
    voc = root / "voc.txt"
    images = sorted(str(p) for p in (root / "train" / "x" / "images_left").glob("*.png"))
    assert cli_main(["slam", "vocabulary", *images, "--out", str(voc), "--k", "8", "--levels", "4",
                     "--seed", "3"]) == 0
    swapped = root / "swapped"  # the cameras plugged the wrong way round
    swapped.mkdir()
    (swapped / "camera_left").symlink_to(walk / "camera_right")
    (swapped / "camera_right").symlink_to(walk / "camera_left")
    for name in ("calibration", "groundtruth.txt", "camera_model.json"):
        (swapped / name).symlink_to(walk / name)
    focal = root / "focal"  # a calibration whose focal length is 3x the real one
    focal.mkdir()
    for name in ("camera_left", "camera_right", "groundtruth.txt", "camera_model.json"):
        (focal / name).symlink_to(walk / name)
    shutil.copytree(walk / "calibration", focal / "calibration")
    for side in ("left", "right"):
        p = focal / "calibration" / f"{side}.yaml"
        doc = yaml.safe_load(p.read_text())
        for key, idx in (("camera_matrix", (0, 4)), ("projection_matrix", (0, 3, 5))):
            for i in idx:
                doc[key]["data"][i] *= 3.0
        p.write_text(yaml.safe_dump(doc))
    return {"root": root, "walk": walk, "swapped": swapped, "focal": focal, "voc": voc}


def _bad_vocabularies(voc: Path, folder: Path) -> dict[str, tuple[Path, str]]:
    text = voc.read_text()
    head, nodes = text.split("\n", 1)
    out = {"header_only": ("10 5 0 0", "only its header"),
           "truncated": (text[: int(len(text) * 0.6)], "truncated"),
           "cut_at_line": (text[: text.rfind("\n", 0, int(len(text) * 0.6))], "truncated"),
           "garbage": ("this is not a vocabulary\n" * 3, "not a DBoW2 text vocabulary"),
           "too_many_fields": (f"{head}\n" + nodes.replace("\n", " 7\n", 3), "numbers where")}
    files = {}
    for name, (content, words) in out.items():
        p = folder / f"{name}.txt"
        p.write_text(content)
        files[name] = (p, words)
    gz = folder / "voc.txt.gz"
    gz.write_bytes(gzip.compress(text.encode()))
    files["gzip"] = (gz, "gzip-compressed")
    return files


def test_vocabulary_check_accepts_a_good_one_and_names_each_fault(world: dict[str, Path], tmp_path: Path) -> None:
    summary = check_vocabulary(world["voc"])
    assert (summary.k, summary.levels) == (8, 4) and 0 < summary.n_words < summary.n_nodes <= 8 + 64 + 512 + 4096
    for name, (path, words) in _bad_vocabularies(world["voc"], tmp_path).items():
        with pytest.raises(VocabularyError) as exc:
            check_vocabulary(path)
        msg = str(exc.value)
        assert "\n" not in msg and words in msg and str(path) in msg, (name, msg)


@pytest.mark.parametrize("name", ["header_only", "truncated", "garbage"])
def test_benchmark_refuses_a_bad_vocabulary_in_one_line(name: str, world: dict[str, Path], tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    path, words = _bad_vocabularies(world["voc"], tmp_path)[name]
    out = tmp_path / "bench"
    rc = cli_main(["benchmark", str(world["walk"]), "--out", str(out), "-m", "ae50", "--vocabulary", str(path),
                   "--slam-pace", "0", "--workers", "1", "-q"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("error: ") and "Traceback" not in err
    assert words in err
    assert not (out / "runs").exists() and not (out / "vo").exists()  # refused before any run


def test_setup_check_passes_a_good_setup(world: dict[str, Path], tmp_path: Path) -> None:
    walk = world["walk"]
    res = check_setup([Trajectory("walk", walk, walk / "calibration", None, walk / "groundtruth.txt")],
                      world["voc"], tmp_path / "check")
    assert res is not None and res.trajectory == "walk" and res.what == "middle bracket (8 ms)"
    assert res.longest_tracked >= 5 and res.cpu_s > 0
    assert (tmp_path / "check" / "walk" / "orbslam3.log").is_file()


def test_setup_check_refuses_a_focal_length_3x_off(world: dict[str, Path], tmp_path: Path) -> None:
    """ORB-SLAM3 tracks (the geometry is self-consistent) but moves 3x the reference's distance: refused."""
    focal = world["focal"]
    with pytest.raises(SetupCheckError) as exc:
        check_setup([Trajectory("focal", focal, focal / "calibration", None, focal / "groundtruth.txt")],
                    world["voc"], tmp_path / "check")
    msg = str(exc.value)
    assert "\n" not in msg and "stereo scale" in msg and "focal length" in msg


def test_benchmark_refuses_swapped_cameras_in_one_line(world: dict[str, Path], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench"
    rc = cli_main(["benchmark", str(world["swapped"]), "--out", str(out), "-m", "ae50", "--vocabulary",
                   str(world["voc"]), "--slam-pace", "0", "--workers", "1", "-q"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("error: set-up check failed") and "Traceback" not in err
    assert "calibration" in err and "swapped" in err
    assert not (out / "runs").exists()
