"""Benchmark orchestration: report files, cache/resume after an interruption, Dask LocalCluster == local run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bracketry.cli import main as cli_main
from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark import BenchmarkConfig, RunResult, make_task, run_benchmark
from bracketry_emulator.benchmark.tasks import load_cached
from bracketry_emulator.benchmark.toyworld import ToyWorld
from bracketry_emulator.metrics import expand_datasets
from bracketry_emulator.metrics.failure_causes import CAUSES

N_FRAMES = 6
WINDOWS = (1.0,)
METHODS = ["ae50", "dim", "burst"]
_GAINS = {"ae50": [1.0] * N_FRAMES, "dim": [0.7] * N_FRAMES, "burst": [1.0] * 3 + [14.0] * 2 + [1.0]}
_KEYS = ("trajectory", "method", "success", "time_before_failure_s", "coverage", "matches", "rte_pct",
         "rre_deg_per_m", "windows", "n_segments")


@pytest.fixture(scope="module")
def datasets(tmp_path_factory) -> list[Path]:
    """Two toy trajectories, each holding already emulated runs of three 'methods' (different gains)."""
    root = tmp_path_factory.mktemp("bench_ds")
    out = []
    for seed in (1, 2):
        d = root / f"traj{seed}"
        w = ToyWorld(width_px=256, height_px=192, fx_px=200.0, seed=seed)
        w.write_calibration(d)
        for m in METHODS:
            times = w.write_run(d, m, N_FRAMES, gain=_GAINS[m])
        w.write_groundtruth(d / "groundtruth.txt", times)
        out.append(d)
    manifest = root / "manifest.yaml"
    manifest.write_text("trajectories:\n  - {path: traj1, subset: Forest}\n  - {path: traj2, subset: Campus}\n")
    return [manifest]


def _essential(results: list[dict]) -> str:
    """The compared fields as canonical JSON (NaN-safe: NaN != NaN in a plain dict comparison)."""
    return json.dumps([{k: r[k] for k in _KEYS} for r in results], sort_keys=True)


@pytest.fixture(scope="module")
def local_run(datasets, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench_local")
    return run_benchmark(BenchmarkConfig(datasets, METHODS, out, reference="ae50", windows_m=WINDOWS))


def test_bench_local_run_and_report(local_run) -> None:
    res = local_run.results
    assert [(r["trajectory"], r["method"]) for r in res] == [(t, m) for t in ("traj1", "traj2") for m in METHODS]
    by = {(r["trajectory"], r["method"]): r for r in res}
    assert by[("traj1", "ae50")]["success"] and by[("traj2", "dim")]["success"]
    assert not by[("traj1", "burst")]["success"]
    assert by[("traj1", "burst")]["time_before_failure_s"] == pytest.approx(3 / ToyWorld().fps, abs=1e-3)
    assert by[("traj1", "burst")]["n_segments"] == 2
    rep = local_run.out_dir / "report"
    for name in ("results.csv", "windows.csv", "summary.csv", "success.csv", "stats.csv", "verdicts.csv",
                 "report.md", "report.html", "wilcoxon.csv", "friedman.csv",
                 "coverage.png", "matches.png", "failure.png", "qualitative.png",
                 "exposure_traj1.png"):
        assert (rep / name).is_file() and (rep / name).stat().st_size > 0, name
    success = (rep / "success.csv").read_text().splitlines()
    assert success[0] == "subset,ae50,dim,burst"
    assert "Campus (1),1,1,0" in success and "Forest (1),1,1,0" in success and "Total (2),2,2,0" in success
    md = (rep / "report.md").read_text()
    assert "Statistical difference with ae50" in md and "RTE" in md and "![" in md
    assert "Paired: Wilcoxon signed-rank against ae50" in md and "Kendall W" in md
    wil = (rep / "wilcoxon.csv").read_text().splitlines()
    assert len(wil) == 1 + 5 * 2 and wil[1].startswith("Coverage,dim,2,")  # 5 metrics x 2 methods, paired on 2
    assert "<table>" in (rep / "report.html").read_text()


def test_bench_report_says_why_runs_lost_track(local_run) -> None:
    """failure_causes.csv: its header, one row per run that lost track (burst on both walks), a known cause; the
    cause x method table in the Markdown, HTML and LaTeX report."""
    rep = local_run.out_dir / "report"
    lines = (rep / "failure_causes.csv").read_text().splitlines()
    assert lines[0] == "trajectory,method,repeat,time_s,cause"
    lost = [r for r in local_run.results if not r["success"]]
    assert lost and len(lines) == 1 + len(lost)
    rows = [line.split(",") for line in lines[1:]]
    assert {(r[0], r[1]) for r in rows} == {(r["trajectory"], r["method"]) for r in lost}
    assert all(r[4] in CAUSES and r[2] == "0" for r in rows)
    burst = next(r for r in rows if r[:2] == ["traj1", "burst"])
    assert float(burst[3]) == pytest.approx(3 / ToyWorld().fps, abs=0.01)
    md = (rep / "report.md").read_text()
    assert "Why runs lost track" in md and "exposure_jump" in md and "the paper's reading" in md
    assert "Why runs lost track" in (rep / "report.html").read_text()
    assert "exposure jump" in (rep / "latex" / "causes.tex").read_text()


def test_bench_interrupted_run_resumes(datasets, local_run, tmp_path: Path) -> None:
    seen: list[str] = []

    def stop_after_two(r: RunResult) -> None:
        seen.append(r.method)
        if len(seen) == 2:
            raise KeyboardInterrupt  # as a Ctrl-C in the middle of the benchmark

    with pytest.raises(KeyboardInterrupt):
        run_benchmark(BenchmarkConfig(datasets, METHODS, tmp_path, windows_m=WINDOWS), on_done=stop_after_two)
    cached = sorted(p.name for p in (tmp_path / "cache").rglob("*.json"))
    assert len(cached) == 2
    resumed = run_benchmark(BenchmarkConfig(datasets, METHODS, tmp_path, windows_m=WINDOWS))
    assert [r["cached"] for r in resumed.results] == [True, True, False, False, False, False]
    assert _essential(resumed.results) == _essential(local_run.results)
    # a cache entry made with other settings is not reused
    spec = expand_datasets(datasets)[0]
    assert load_cached(make_task(spec, "ae50", tmp_path, WINDOWS)) is not None
    assert load_cached(make_task(spec, "ae50", tmp_path, (1.0, 2.0))) is None
    assert load_cached(make_task(spec, "ae50", tmp_path, WINDOWS, max_frames=3)) is None


def test_bench_dask_localcluster_matches_local(datasets, local_run, tmp_path: Path) -> None:
    import distributed  # dask[distributed], a dependency of the emulator extra
    # dashboard off (no Bokeh); the scheduler's small HTTP server goes to a free loopback port
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0", scheduler_kwargs={"dashboard": False}) as cluster:
        res = run_benchmark(BenchmarkConfig(datasets, METHODS, tmp_path, windows_m=WINDOWS,
                                            scheduler=cluster.scheduler_address))
    assert not any(r["cached"] for r in res.results)
    assert _essential(res.results) == _essential(local_run.results)
    assert json.loads((tmp_path / "report" / "results.json").read_text())[0]["trajectory"] == "traj1"


def test_bench_cli(datasets, local_run, tmp_path: Path, capsys) -> None:
    # same settings as the library run in the same folder: every task comes from the cache
    args = ["benchmark", str(datasets[0]), "--methods", ",".join(METHODS), "--out", str(local_run.out_dir),
            "--windows", "1", "--slam", "builtin"]
    assert cli_main(args) == 2  # a full folder: refused without --resume (or --overwrite)
    assert "--resume" in capsys.readouterr().err
    rc = cli_main([*args, "--resume"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "cached traj1 / burst: failed at 0.8 s" in out and "report:" in out
    assert cli_main(["benchmark", str(datasets[0]), "--methods", "dim", "--out", str(tmp_path)]) == 2
    assert "reference method 'ae50'" in capsys.readouterr().err  # before any vocabulary is resolved or built
    assert cli_main(["benchmark", str(datasets[0]), "--methods", "ae50", "--out", str(tmp_path),
                     "--vocabulary", str(tmp_path / "missing.txt")]) == 2
    assert "--vocabulary" in capsys.readouterr().err
    assert cli_main(["benchmark", str(datasets[0]), "--methods", "ae50", "--out", str(tmp_path),
                     "--slam-pace", "fast"]) == 2
    assert cli_main(["benchmark", str(datasets[0]), "--methods", "ae50", "--out", str(tmp_path),
                     "--windows", "x"]) == 2


def test_methods_all_leaves_drl_out_without_weights_and_names_the_option() -> None:
    from bracketry_emulator.ae.registry import parse_methods

    assert "drl" not in parse_methods("all", has_drl_weights=False)
    # 'all' = the paper's eight (drl with its weights); zhang by name
    assert parse_methods("all", has_drl_weights=True) == ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl"]
    assert parse_methods("all,zhang", has_drl_weights=True)[-1] == "zhang"
    assert parse_methods("ae50,fix,ae50") == ["ae50", "fix"]
    with pytest.raises(BracketryError, match="--drl-weights"):
        parse_methods("ae50,drl", has_drl_weights=False)


def test_methods_paper_and_stats_methods() -> None:
    from bracketry_emulator.ae.registry import parse_methods
    from bracketry_emulator.benchmark.orchestrate import select_stats_methods

    paper = parse_methods("paper", has_drl_weights=False)
    assert paper == ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim"]
    methods = [*paper, "zhang", "myrun"]
    assert select_stats_methods("paper", methods, "ae50") == [*paper, "myrun"]  # zhang reported, not tested
    assert select_stats_methods("all", methods, "ae50") == methods
    assert select_stats_methods("ae30,zhang", methods, "ae50") == ["ae30", "ae50", "zhang"]
    with pytest.raises(BracketryError, match="not benchmarked: nope"):
        select_stats_methods("ae30,nope", methods, "ae50")
