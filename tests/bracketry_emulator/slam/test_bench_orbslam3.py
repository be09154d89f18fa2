"""ORB-SLAM3 backend: vocabulary builder, settings, tracking with repeats, losses and new maps, failed runs.

Lean on purpose (320x240 toy corridor, a vocabulary of k=8, L=4 trained on another corridor, unpaced feed); every
ORB-SLAM3 run is a real child process of pyorbslam3.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry.cli import main as cli_main
from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
from bracketry_emulator.benchmark.slam import SlamOptions, combine_repeats, slam_options
from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.slam import settings as slam_settings
from bracketry_emulator.slam.orbslam3 import OrbSlam3Options, SlamRunError, map_states, run_orbslam3
from bracketry_emulator.slam.settings import (
    MIN_FIELD_FEATURES,
    PAPER_ORB,
    OrbSlamCamera,
    camera_fps,
    field_orb_settings,
    pyramid_levels,
    settings_yaml,
    slam_orb_settings,
)
from bracketry_emulator.slam.vocabulary import build_vocabulary, parse_vocabulary_text, vocabulary_text
from bracketry_emulator.trajectory_io import read_frames_csv

pytestmark = pytest.mark.orbslam3

N_FRAMES = 24
WORLD = ToyWorld(width_px=320, height_px=240, fx_px=240.0)
#: the same corridor walk, twice the frame rate (0.16 m a frame instead of 0.33 m), for the every-frame-tracked test
DENSE = ToyWorld(width_px=320, height_px=240, fx_px=240.0, fps=2 * WORLD.fps)


@pytest.fixture(scope="module")
def toy(tmp_path_factory) -> Path:
    """A toy trajectory (good exposure, and one with 5 black frames) plus training images of another corridor, and
    ``dense/``: the same walk at twice the frame rate (its own trajectory: calibration, ground truth, ae50)."""
    d = tmp_path_factory.mktemp("orbslam3_toy")
    WORLD.write_calibration(d)
    times = WORLD.write_run(d, "ae50", N_FRAMES)
    WORLD.write_groundtruth(d / "groundtruth.txt", times)
    DENSE.write_calibration(d / "dense")
    DENSE.write_groundtruth(d / "dense" / "groundtruth.txt", DENSE.write_run(d / "dense", "ae50", 2 * N_FRAMES))
    gains = [1.0] * 10 + [0.0] * 5 + [1.0] * (N_FRAMES - 15)
    WORLD.write_run(d, "dark", N_FRAMES, gain=gains)
    ToyWorld(width_px=320, height_px=240, fx_px=240.0, seed=99).write_run(d / "train", "x", 6, t0_ns=90 * 10**9)
    return d


def toy_dataset(toy: Path, ds: Path) -> Path:
    """A dataset folder ``ds`` with the toy's calibration, ground truth and its ae50 run (symlinks)."""
    ds.mkdir()
    for name in ("calibration", "groundtruth.txt", "ae50"):
        (ds / name).symlink_to(toy / name)
    return ds


@pytest.fixture(scope="module")
def vocabulary(toy: Path) -> Path:
    out = toy / "voc.txt"
    images = sorted(str(p) for p in (toy / "train" / "x" / "images_left").glob("*.png"))
    assert cli_main(["slam", "vocabulary", *images, "--out", str(out), "--k", "8", "--levels", "4",
                     "--seed", "3"]) == 0
    return out


def test_bench_vocabulary_format_and_determinism(toy: Path, vocabulary: Path, tmp_path: Path) -> None:
    text = vocabulary.read_text()
    assert text.split("\n", 1)[0] == "8 4 0 0" and not text.endswith("\n")
    voc = parse_vocabulary_text(text)
    depth = voc.depth()
    assert np.all(voc.parent[1:] < np.arange(1, len(voc.parent)))  # breadth-first: parents first
    assert np.all(np.diff(depth) >= 0)
    assert set(depth[voc.is_leaf]) == {4} and not voc.is_leaf[depth < 4].any()  # every branch padded to L
    assert np.bincount(voc.parent[1:]).max() <= 8 and voc.n_words > 1000
    assert np.all(voc.weights[voc.is_leaf] >= 0) and np.all(voc.weights[~voc.is_leaf] == 0)
    images = sorted(str(p) for p in (toy / "train" / "x" / "images_left").glob("*.png"))
    again = tmp_path / "again.txt"
    assert cli_main(["slam", "vocabulary", *images, "--out", str(again), "--k", "8", "--levels", "4",
                     "--seed", "3"]) == 0
    assert again.read_bytes() == vocabulary.read_bytes()
    assert cli_main(["slam", "vocabulary", *images, "--out", str(again), "--k", "8", "--levels", "4"]) != 0  # exists
    other = tmp_path / "other.txt"
    assert cli_main(["slam", "vocabulary", *images, "--out", str(other), "--k", "8", "--levels", "4",
                     "--seed", "4"]) == 0
    assert other.read_bytes() != vocabulary.read_bytes()


def test_bench_vocabulary_pads_small_clusters() -> None:
    rng = np.random.default_rng(0)
    few = rng.integers(0, 256, (3, 32), dtype=np.uint8)
    voc = build_vocabulary([few, few[:1]], k=4, levels=3, seed=0)
    depth = voc.depth()
    assert voc.n_words == 3 and set(depth[voc.is_leaf]) == {3}
    assert len(voc.parent) == 1 + 3 * 3  # three branches, each a chain of single children
    leaf_desc = {bytes(d) for d in voc.descriptors[voc.is_leaf]}
    assert leaf_desc == {bytes(d) for d in few}
    w = dict(zip((bytes(d) for d in voc.descriptors[voc.is_leaf]), voc.weights[voc.is_leaf]))
    assert w[bytes(few[0])] == pytest.approx(0.0) and w[bytes(few[1])] == pytest.approx(np.log(2))
    assert parse_vocabulary_text(vocabulary_text(voc)).n_words == 3


def test_bench_settings_reals_and_levels() -> None:
    cam = OrbSlamCamera(240.0, 240.0, 160.0, 120.0, 0.18, 320, 240)
    fs = cv2.FileStorage(settings_yaml(cam, 3.67, loop_closing=False), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    assert fs.getNode("Stereo.ThDepth").isReal() and fs.getNode("Stereo.ThDepth").real() == 35.0
    assert fs.getNode("Camera1.fx").isReal() and fs.getNode("Camera.fps").isInt()
    assert int(fs.getNode("Camera.fps").real()) == 3 and int(fs.getNode("loopClosing").real()) == 0
    assert [camera_fps(f) for f in (11 / 3, 3.9999999, 4.0, 0.5, 20.0)] == [3, 4, 4, 1, 20]
    assert np.allclose(fs.getNode("Stereo.T_c1_c2").mat()[:3, 3], [0.18, 0, 0])
    assert int(fs.getNode("ORBextractor.nLevels").real()) == pyramid_levels(320, 240, 13, 1.2) == 8
    assert pyramid_levels(960, 600, 13, 1.2) == 13
    assert int(fs.getNode("ORBextractor.nFeatures").real()) == slam_orb_settings(320, 240).n_features
    fs.release()
    field = cv2.FileStorage(settings_yaml(cam, 3.67, orb=field_orb_settings(320, 240)),
                            cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    assert int(field.getNode("ORBextractor.nFeatures").real()) == MIN_FIELD_FEATURES
    field.release()


def test_bench_field_orb_settings_follow_the_papers_view() -> None:
    """The paper's 3000 features at 1920 px; at smaller widths the share it spent at the scales those images resolve
    (level log_1.2(1920 / W) on), never below the floor; its scale factor and FAST thresholds everywhere."""
    assert field_orb_settings(1920, 1200) == PAPER_ORB
    big, mid, small = field_orb_settings(960, 600), field_orb_settings(640, 400), field_orb_settings(320, 200)
    assert (mid.n_features, mid.n_levels) == (794, 11) and (small.n_features, small.n_levels) == (750, 7)
    assert big.n_features == 1345 and big.n_levels == 13
    assert {(o.scale_factor, o.ini_th_fast, o.min_th_fast) for o in (big, mid, small)} == {(1.2, 15, 5)}


def test_bench_orb_sizing_is_field_and_in_the_cache_key(monkeypatch: pytest.MonkeyPatch) -> None:
    """``field`` by default; a result of one sizing is never reused for the other (the built-in VO's keys stay)."""
    assert slam_settings.ORB_SIZING == "field" and slam_orb_settings(320, 200) == field_orb_settings(320, 200)
    assert slam_orb_settings(320, 200, sizing="paper") == PAPER_ORB
    orb = SlamOptions(backend="orbslam3", vocabulary="voc.txt", vocabulary_id="voc.txt:0")
    field_key, builtin_key = orb.key_json(), SlamOptions.builtin().key_json()
    monkeypatch.setattr(slam_settings, "ORB_SIZING", "paper")
    assert orb.key_json() != field_key and SlamOptions.builtin().key_json() == builtin_key


def test_bench_map_states_splits_segments() -> None:
    states, segs = map_states(["OK", "OK", "RECENTLY_LOST", "RECENTLY_LOST", "OK", "NO_IMAGES_YET", "OK", "OK"])
    assert states == ["INIT", "OK", "LOST", "LOST", "INIT", "LOST", "INIT", "OK"]
    assert segs == [0, 0, -1, -1, 1, -1, 2, 2]


def test_bench_orbslam3_tracks_in_every_repeat(toy: Path, vocabulary: Path, tmp_path: Path) -> None:
    """Good exposure, 3 repeats: all frames tracked, one segment, RTE under 5 % in each repeat.

    On the dense walk (48 frames, 0.16 m apart), not the 24-frame ``ae50`` (0.33 m): there 30-40 % of ORB-SLAM3's
    tracked points leave the view every frame and it needs a keyframe every 2-3 frames. Its tracking thread races
    its local-mapping thread (fed unpaced, and also in real time once the machine is loaded: tracking then takes
    most of the 0.27 s a frame); when local mapping is late one keyframe is not made, the tracked points fall
    217 -> 140 -> 71 -> 42, a frame (18, 21 or 23) is LOST and a new map starts: 5 of 18 runs unpaced, 4 of 18 in
    real time, at load 12 on 2 cores. At 0.16 m a frame, keyframes 2-3 frames late still leave >= 55 tracked points
    (0 of 60 runs lost a frame under the same load), so every frame must still be tracked.

    The bound: over 1-4 m windows on this 7.8 m corridor walk ORB-SLAM3 measures 2.3-3.5 % a run (unpaced, a
    small vocabulary; the built-in VO 3.1 % on the 24 frames); 5 % still catches a scale, frame or timing error
    (those give tens of percent).
    """
    slam = slam_options("orbslam3", vocabulary, pace="lockstep", repeats=3)
    ds = toy_dataset(toy / "dense", tmp_path / "ds")
    seen: list[dict] = []
    res = run_benchmark(BenchmarkConfig([ds], ["ae50"], tmp_path / "out", reference="ae50",
                                        windows_m=(1.0, 2.0, 4.0), workers=2, slam=slam),
                        on_done=lambda r: seen.append(r.to_json()))
    assert len(seen) == 3 and all(not r.get("error") for r in seen), [r.get("error") for r in seen]
    for r in seen:
        assert r["slam"] == "orbslam3" and r["n_segments"] == 1 and r["tracked_fraction"] == 1.0
        assert 0 < r["rte_pct"] < 5.0, r["rte_pct"]
        assert r["tracked_distance_fraction"] == pytest.approx(1.0)
        log = Path(r["vo_dir"]) / "orbslam3.log"
        assert "ORB-SLAM3" in log.read_text()  # the C++ banner, captured at the file-descriptor level
    (r,) = res.results
    assert r["repeats"] == 3 and len(r["rte_pct_runs"]) == 3 and r["rte_pct_spread"] >= 0
    assert r["rte_pct"] == pytest.approx(float(np.median(r["rte_pct_runs"])))
    md = (res.out_dir / "report" / "report.md").read_text()
    assert "ORB-SLAM3 stereo" in md and "voc.txt" in md


def test_bench_orbslam3_black_frames_lost_then_new_segment(toy: Path, vocabulary: Path, tmp_path: Path) -> None:
    info = run_orbslam3(toy / "dark", toy / "calibration", tmp_path / "vo",
                        OrbSlam3Options(str(vocabulary), pace_s=0.0))
    frames = read_frames_csv(tmp_path / "vo" / "frames.csv")
    states = [f["state"] for f in frames]
    assert states[:10] == ["INIT"] + ["OK"] * 9
    assert all(s == "LOST" for s in states[10:15]) and all(f["reason"].startswith("ORB-SLAM3") for f in frames[10:15])
    # ORB-SLAM3's own keypoints: more than its stereo start's 500 on the first frame, none left on black ones
    assert frames[0]["n_slam_keypoints"] > 500
    assert all(f["n_slam_keypoints"] < 500 for f in frames[10:15]), [f["n_slam_keypoints"] for f in frames[10:15]]
    assert "INIT" in states[15:] and states[-1] == "OK"
    segs = sorted({f["segment"] for f in frames if f["state"] != "LOST"})
    assert segs[0] == 0 and len(segs) >= 2
    assert len(list((tmp_path / "vo").glob("CameraTrajectory*.txt"))) == len(segs)
    assert info["backend"] == "orbslam3" and info["n_frames"] == N_FRAMES


def test_bench_orbslam3_broken_vocabulary_is_one_line(toy: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.txt"
    bad.write_text("this is not a vocabulary")
    with pytest.raises(SlamRunError) as exc:
        run_orbslam3(toy / "ae50", toy / "calibration", tmp_path / "vo", OrbSlam3Options(str(bad), pace_s=0.0),
                     max_frames=3)
    msg = str(exc.value)
    assert "\n" not in msg and "ORB-SLAM3 failed" in msg and "orbslam3.log" in msg
    assert (tmp_path / "vo" / "orbslam3.log").stat().st_size > 0


def test_bench_failed_run_is_a_report_line_and_others_finish(toy: Path, vocabulary: Path, tmp_path: Path) -> None:
    ds = toy_dataset(toy, tmp_path / "ds")
    broken = ds / "broken"
    (broken / "images_left").mkdir(parents=True)
    (broken / "images_right").mkdir()
    for k in range(3):  # unreadable images: this run fails in its child, not the benchmark
        (broken / "images_left" / f"{k + 1}.png").write_bytes(b"not a png")
        (broken / "images_right" / f"{k + 1}.png").write_bytes(b"not a png")
    slam = slam_options("orbslam3", vocabulary, pace=0.0)
    res = run_benchmark(BenchmarkConfig([ds], ["ae50", "broken"], tmp_path / "out", reference="ae50",
                                        windows_m=(1.0,), workers=1, slam=slam, max_frames=6))
    by = {r["method"]: r for r in res.results}
    assert not by["ae50"].get("error") and by["ae50"]["tracked_fraction"] == 1.0
    assert "cannot read image" in by["broken"]["error"] and np.isnan(by["broken"]["rte_pct"])
    failed = (res.out_dir / "report" / "failed_runs.csv").read_text()
    assert "broken" in failed and "cannot read image" in failed
    assert "Failed SLAM runs" in (res.out_dir / "report" / "report.md").read_text()


def test_bench_combine_repeats_median_and_failures() -> None:
    base = {"trajectory": "t", "method": "m", "success": True, "coverage": [], "matches": []}
    runs = [{**base, "repeat": i, "rte_pct": v, "rre_deg_per_m": 0.1, "tracked_fraction": 1.0} for i, v in
            enumerate((1.0, 3.0, 2.0))] + [{**base, "repeat": 3, "error": "ORB-SLAM3 failed (killed by SIGSEGV)",
                                            "rte_pct": float("nan")}]
    out = combine_repeats(runs)
    assert out["rte_pct"] == 2.0 and out["rte_pct_spread"] == 2.0 and out["repeat"] == 2
    assert out["repeats"] == 4 and out["repeats_ok"] == 3 and out["errors"] == ["ORB-SLAM3 failed (killed by SIGSEGV)"]


@pytest.fixture(scope="module")
def bracketed(tmp_path_factory) -> Path:
    """A bracketed synthetic trajectory (the closed loops run on it, so SLAM reads their spooled frames)."""
    d = tmp_path_factory.mktemp("orbslam3_stream") / "walk"
    assert cli_main(["synth", "trajectory", "--out", str(d), "--seconds", "3", "--resolution", "320x240",
                     "-q"]) == 0
    return d


def test_bench_orbslam3_fed_in_memory(bracketed: Path, vocabulary: Path, tmp_path: Path) -> None:
    """ORB-SLAM3 children get the closed loops' images through their spool files (no PNG written): every frame reaches
    SLAM, the settings are those the PNG route writes (same frame rate), the child's CPU time is measured. In lockstep:
    a spooled run fed unpaced takes frames as fast as it tracks, and how much it keeps follows the machine's load."""
    slam = slam_options("orbslam3", vocabulary, pace="lockstep")
    res = run_benchmark(BenchmarkConfig([bracketed], ["ae50", "fix"], tmp_path / "out", reference="ae50",
                                        windows_m=(1.0,), workers=1, slam=slam))
    for r in res.results:
        assert not r.get("error") and r["slam_input"] == "stream", r.get("error")
        assert r["n_frames"] == 11 and r["tracked_fraction"] > 0.5
        assert not list(Path(r["run_dir"]).rglob("*.png"))
    stream_settings = (Path(res.results[0]["vo_dir"]) / "settings.yaml").read_text()
    png = run_benchmark(BenchmarkConfig([bracketed], ["ae50"], tmp_path / "png", reference="ae50",
                                        windows_m=(1.0,), workers=1, slam=slam,
                                        export_orbslam=True))  # the PNG route (the export needs the files)
    assert png.results[0]["slam_input"] == "png"
    assert (Path(png.results[0]["vo_dir"]) / "settings.yaml").read_text() == stream_settings
    stages = json.loads((res.out_dir / "report" / "stages.json").read_text())["stages"]
    assert stages["slam"]["count"] == 2 and stages["slam"]["cpu_s"] > 0


def test_bench_orbslam3_failing_children_do_not_hold_the_closed_loop(bracketed: Path, tmp_path: Path) -> None:
    """Every ORB-SLAM3 child exits on a broken vocabulary after its first frame: each run is one failed-run line,
    the closed loop (which spooled their frames) and the benchmark finish. (The vocabulary check and the set-up check
    would refuse this vocabulary before any run: both are bypassed here, a vocabulary id given and no set-up
    check, to exercise failing children.)"""
    bad = tmp_path / "bad.txt"
    bad.write_text("this is not a vocabulary")
    slam = replace(slam_options("orbslam3", bad, pace=0.0, resolve=False), vocabulary=str(bad),
                   vocabulary_id="bad.txt:0")
    res = run_benchmark(BenchmarkConfig([bracketed], ["ae50", "fix"], tmp_path / "out", reference="ae50",
                                        windows_m=(1.0,), workers=1, slam=slam, setup_check=False))
    for r in res.results:
        assert "ORB-SLAM3 failed" in r["error"] and "\n" not in r["error"] and np.isnan(r["rte_pct"])
    assert "Failed SLAM runs" in (res.out_dir / "report" / "report.md").read_text()
    assert (Path(res.results[0]["run_dir"]) / "ae.csv").is_file()  # the closed loop itself completed
