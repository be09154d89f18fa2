"""The benchmark feeds SLAM raw frames, spooled by the closed loops: the images that reach SLAM are the PNG route's,
bit for bit; the results are the same; PNGs only when asked; the report ends with the stage table; the SLAM runs go
as many at a time as the workers."""

from __future__ import annotations

import itertools
import json
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from bracketry.cli import main as cli_main
from bracketry_emulator.ae import run_methods
from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
from bracketry_emulator.slam.frame_stream import FrameFeed, read_stream
from bracketry_emulator.vo import run_vo
from bracketry_emulator.vo.runner import list_side_images, read_gray8

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def world(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bench_stream") / "walk"
    assert cli_main(["synth", "trajectory", "--out", str(d), "--seconds", "3", "--resolution", "320x200",
                     "-q"]) == 0
    return d


@pytest.mark.parametrize("workers", [1, 2])  # in this process, and forked workers that open the FIFOs themselves
def test_streamed_images_equal_the_written_pngs(world: Path, tmp_path: Path, workers: int) -> None:
    methods = ["ae50", "shim"]
    received: dict[str, list] = {m: [] for m in methods}
    feeds, readers = {}, []
    for m in methods:
        fifo = FrameFeed.make_fifo(tmp_path / f"{m}.fifo")
        t = threading.Thread(target=lambda f=fifo, m=m: received[m].extend(read_stream(f)))
        t.start()
        readers.append(t)
        feeds[m] = [FrameFeed(fifo)]
    run_methods(world, methods, tmp_path / "runs", workers=workers, progress=False, feeds=feeds)
    for t in readers:
        t.join(timeout=60)
    for m in methods:
        left = list_side_images(tmp_path / "runs" / m, "left")
        right = list_side_images(tmp_path / "runs" / m, "right")
        assert len(received[m]) == len(left) == len(right) > 5
        for (t_ns, sl, sr), (tl, pl), (_tr, pr) in zip(received[m], left, right, strict=True):
            assert t_ns == tl
            for streamed, png in ((sl, pl), (sr, pr)):
                decoded = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
                assert streamed.dtype == decoded.dtype == np.uint16 and np.array_equal(streamed, decoded), png


def test_streamed_slam_results_equal_the_png_route(world: Path, tmp_path: Path) -> None:
    """The built-in VO (deterministic) fed spooled frames gives the same per-frame log and trajectory as run on the PNG
    files of the same closed loop; the report ends with the stage table; without --write-images no PNG is written."""
    res = run_benchmark(BenchmarkConfig([world], ["ae50"], tmp_path / "b", reference="ae50", windows_m=(1.0,),
                                        write_images=True))
    (r,) = res.results
    assert r["slam_input"] == "stream" and not r.get("error")
    vo = run_vo(r["run_dir"], world / "calibration", tmp_path / "png_route")
    streamed_dir = Path(r["vo_dir"])
    assert (streamed_dir / "frames.csv").read_text() == (vo.out_dir / "frames.csv").read_text()
    tums = sorted(p.name for p in vo.out_dir.glob("CameraTrajectory*.txt"))
    assert tums and tums == sorted(p.name for p in streamed_dir.glob("CameraTrajectory*.txt"))
    for name in tums:
        assert (streamed_dir / name).read_text() == (vo.out_dir / name).read_text()
    assert not (streamed_dir / "frames.stream").exists()
    left = list_side_images(r["run_dir"], "left")  # the kept middle frame (qualitative figure) is the PNG route's
    preview = cv2.imread(str(streamed_dir / "preview_left.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(preview, read_gray8(left[len(left) // 2][1]))
    timing = json.loads((res.out_dir / "report" / "stages.json").read_text())
    assert {"decode", "emulation", "ae:ae50", "png_write", "slam", "metrics", "report"} <= set(timing["stages"])
    assert timing["stages"]["slam"]["count"] == 1 and timing["stages"]["slam"]["cpu_s"] > 0
    assert timing["trajectory_s"] == pytest.approx(r["duration_s"], abs=1e-3) and timing["machine"]["cpus"] >= 1
    md = (res.out_dir / "report" / "report.md").read_text()
    assert md.rstrip().splitlines()[-1].startswith("| benchmark (wall clock) |")  # the report ends with it
    assert "## Where the time went" in md and "s per trajectory-minute" in md and "logical CPUs" in md
    # the default: no PNG at all, the same results, the steps still recorded
    res2 = run_benchmark(BenchmarkConfig([world], ["ae50"], tmp_path / "c", reference="ae50", windows_m=(1.0,)))
    run_dir = Path(res2.results[0]["run_dir"])
    assert not list(run_dir.rglob("*.png")) and len((run_dir / "steps.csv").read_text().splitlines()) > 5
    assert (res2.out_dir / "report" / "qualitative.png").stat().st_size > 1000
    assert (Path(res2.results[0]["vo_dir"]) / "frames.csv").read_text() == (vo.out_dir / "frames.csv").read_text()
    assert "png_write" not in json.loads((res2.out_dir / "report" / "stages.json").read_text())["stages"]
    # cached on a second call: no work now, said in the table's legend
    again = run_benchmark(BenchmarkConfig([world], ["ae50"], tmp_path / "c", reference="ae50", windows_m=(1.0,)))
    assert again.results[0]["cached"] and "came from the cache" in (again.out_dir / "report" / "report.md"
                                                                    ).read_text()


@pytest.mark.parametrize("workers", [1, 2])
def test_slam_runs_go_one_more_at_a_time_than_workers(world: Path, tmp_path: Path, workers: int) -> None:
    """The closed loops spool every run's frames; the SLAM children then go at most ``workers`` + 1 at a time (a run's
    life: from its request.json, written as it starts, to its slam.json, written as it ends), each reads its whole
    spool, and no spool is left."""
    methods = ["ae50", "shim", "fix", "ae30", "ae70"]
    res = run_benchmark(BenchmarkConfig([world], methods, tmp_path / "b", reference="ae50", windows_m=(1.0,),
                                        workers=workers))
    lives = []
    for r in res.results:
        assert not r.get("error") and r["slam_input"] == "stream"
        vo = Path(r["vo_dir"])
        assert not (vo / "frames.stream").exists() and not (vo / "frames.fifo").exists()
        steps = len((Path(r["run_dir"]) / "steps.csv").read_text().splitlines()) - 1
        assert json.loads((vo / "slam.json").read_text())["n_frames"] == steps > 5
        lives.append(((vo / "request.json").stat().st_mtime_ns, (vo / "slam.json").stat().st_mtime_ns))
    assert len(lives) == len(methods)
    for start, _end in lives:  # runs alive when this one started (itself included)
        assert sum(1 for s, e in lives if s <= start < e) <= workers + 1


def test_a_trajectory_spools_once_every_earlier_run_has_started(world: Path, tmp_path: Path) -> None:
    """The closed loops run far faster than SLAM: a trajectory's pass (which writes its runs' spools) waits until
    every SLAM run of the trajectories before it has started, so the spools on disk are the running runs' and one
    trajectory's more, not the whole suite's (a full-size walk's seven spools are about 2 GB). Three trajectories of
    three methods each, one worker: two runs at a time, so each trajectory's third run waits for one to end."""
    walks = [world]
    for seed in (1, 2):
        walks.append(tmp_path / f"walk_{seed + 1}")
        assert cli_main(["synth", "trajectory", "--out", str(walks[-1]), "--seconds", "3", "--resolution", "320x200",
                         "--seed", str(seed), "-q"]) == 0
    res = run_benchmark(BenchmarkConfig(walks, ["ae50", "fix", "shim"], tmp_path / "b", reference="ae50",
                                        windows_m=(1.0,), workers=1))
    started: dict[str, list[int]] = {}
    for r in res.results:
        assert not r.get("error")
        started.setdefault(r["trajectory"], []).append((Path(r["vo_dir"]) / "request.json").stat().st_mtime_ns)
    names = ["walk", "walk_2", "walk_3"]
    assert sorted(started) == names and all(len(v) == 3 for v in started.values())
    for earlier, later in itertools.pairwise(names):
        pass_written = [(tmp_path / "b" / "runs" / later / m / "ae.csv").stat().st_mtime_ns
                        for m in ("ae50", "fix", "shim")]
        assert min(pass_written) >= max(started[earlier]), (earlier, later)
