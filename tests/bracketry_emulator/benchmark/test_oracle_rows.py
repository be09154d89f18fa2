"""The oracle row is the best whole run of its (trajectory, repeat) among its step search's and every other row's
(benchmark/oracle_rows.py), carried through repeats (the report's side: report/test_report_oracle.py)."""

from __future__ import annotations

import copy
import math

import numpy as np

from bracketry_emulator.benchmark.oracle_rows import oracle_best_runs, run_rank_key
from bracketry_emulator.benchmark.orchestrate import group_repeats

NAN = float("nan")


def _run(method: str, traj: str = "a", repeat: int = 0, success: bool = True, tbf_s: float = 10.0,
         dist: float = 1.0, rte_pct: float = 2.0, error: str | None = None) -> dict:
    """One run's result in the per-run JSON form (RunResult.to_json) with the fields the ranking reads."""
    r = {"trajectory": traj, "subset": "forest", "method": method, "repeat": repeat, "key": f"k-{method}-{repeat}",
         "run_dir": f"runs/{traj}/{method}.r{repeat}", "vo_dir": f"vo/{traj}/{method}.r{repeat}",
         "success": success, "time_before_failure_s": tbf_s, "duration_s": 10.0,
         "tracked_distance_fraction": dist, "rte_pct": rte_pct, "failure_cause": None if success else "blur",
         "slam": "orbslam3", "s_per_frame": 0.05, "stages": {"slam": {"wall_s": 1.0}}, "cached": False}
    if error is not None:
        r.update(error=error, success=False, time_before_failure_s=NAN, tracked_distance_fraction=NAN, rte_pct=NAN,
                 failure_cause=None)
    return r


def _oracle(rows: list[dict], traj: str = "a", repeat: int = 0) -> dict:
    return next(r for r in rows if r["method"] == "oracle" and r["trajectory"] == traj and r["repeat"] == repeat)


def test_a_lost_step_search_takes_the_best_other_run_keeping_its_own_identity() -> None:
    runs = [_run("ae50", success=False, tbf_s=6.0), _run("constant-16", rte_pct=3.0),
            _run("oracle", success=False, tbf_s=0.8)]
    before = copy.deepcopy(runs)
    out = oracle_best_runs(runs)
    assert runs == before  # the input is not modified
    assert out[:2] == runs[:2]  # other rows unchanged, in their order
    o = out[2]
    assert o["oracle_source"] == "constant-16" and o["success"] and o["rte_pct"] == 3.0
    assert o["failure_cause"] is None and o["run_dir"] == "runs/a/constant-16.r0"  # the run it took
    assert (o["method"], o["key"], o["stages"], o["repeat"]) == ("oracle", "k-oracle-0", runs[2]["stages"], 0)


def test_ranking_success_then_time_before_failure_then_distance_then_rte() -> None:
    assert run_rank_key(_run("x", tbf_s=10.0)) > run_rank_key(_run("y", success=False, tbf_s=9.9, dist=1.0))
    assert run_rank_key(_run("x", success=False, tbf_s=5.0, dist=0.2)) > run_rank_key(
        _run("y", success=False, tbf_s=4.0, dist=0.9))
    assert run_rank_key(_run("x", dist=0.9, rte_pct=9.0)) > run_rank_key(_run("y", dist=0.8, rte_pct=1.0))
    assert run_rank_key(_run("x", rte_pct=1.0)) > run_rank_key(_run("y", rte_pct=1.5))
    assert run_rank_key(_run("x", rte_pct=NAN)) < run_rank_key(_run("y", rte_pct=50.0))  # no RTE ranks last
    # a run that never tracked still ranks above one whose SLAM run failed (no result at all)
    assert run_rank_key(_run("x", success=False, tbf_s=0.0, dist=0.0, rte_pct=NAN)) > run_rank_key(
        _run("y", error="orbslam3 child died"))


def test_ties_keep_the_own_run_then_the_first_row() -> None:
    same = [_run("ae50"), _run("fix"), _run("oracle")]
    assert oracle_best_runs(same)[2]["oracle_source"] == "oracle"
    worse_own = [_run("ae50", rte_pct=1.0), _run("fix", rte_pct=1.0), _run("oracle", rte_pct=1.5)]
    assert oracle_best_runs(worse_own)[2]["oracle_source"] == "ae50"
    swapped = [worse_own[1], worse_own[0], worse_own[2]]
    assert oracle_best_runs(swapped)[2]["oracle_source"] == "fix"


def test_a_failed_step_search_run_is_beaten_by_a_constant_that_lost_track() -> None:
    runs = [_run("oracle", error="orbslam3 child died (signal 11)"),
            _run("constant-0.0625", success=False, tbf_s=0.3, dist=0.01, rte_pct=NAN)]
    o = oracle_best_runs(runs)[0]
    assert o["oracle_source"] == "constant-0.0625" and "error" not in o and o["time_before_failure_s"] == 0.3
    alone = oracle_best_runs([runs[0]])[0]  # nothing better: its own failed run, error kept
    assert alone["oracle_source"] == "oracle" and alone["error"].startswith("orbslam3")


def test_candidates_are_runs_of_the_same_trajectory_and_repeat() -> None:
    runs = [_run("ae50", "a", 0, success=False, tbf_s=2.0), _run("ae50", "a", 1),
            _run("ae50", "b", 0), _run("oracle", "a", 0, success=False, tbf_s=1.0),
            _run("oracle", "a", 1, success=False, tbf_s=1.0), _run("oracle", "b", 0, success=False, tbf_s=1.0)]
    out = oracle_best_runs(runs)
    assert _oracle(out, "a", 0)["time_before_failure_s"] == 2.0 and not _oracle(out, "a", 0)["success"]
    assert _oracle(out, "a", 1)["success"] and _oracle(out, "b", 0)["success"]
    assert [_oracle(out, t, r)["oracle_source"] for t, r in (("a", 0), ("a", 1), ("b", 0))] == ["ae50"] * 3
    # combined over repeats, the row names each repeat's candidate in repeat order (repeat 2: the oracle alone)
    grouped = {(r["trajectory"], r["method"]): r
               for r in group_repeats(oracle_best_runs([*runs, _run("oracle", "a", 2)]))}
    assert grouped[("a", "oracle")]["oracle_source"] == "ae50/ae50/oracle"
    assert "oracle_source" not in grouped[("a", "ae50")] and grouped[("b", "oracle")]["oracle_source"] == "ae50"


def test_oracle_alone_is_its_own_run() -> None:
    runs = [_run("oracle", "a", success=False, tbf_s=0.8), _run("oracle", "b")]
    out = oracle_best_runs(runs)
    assert [r["oracle_source"] for r in out] == ["oracle", "oracle"]
    assert [{k: v for k, v in r.items() if k != "oracle_source"} for r in out] == runs


def test_the_oracle_keeps_at_least_as_many_trajectories_as_any_row_on_random_benchmarks() -> None:
    methods = ["ae50", "fix", "shim", "constant-0.0625", "oracle"]
    for seed in range(20):
        rng = np.random.default_rng(seed)
        runs = []
        for t in range(8):
            for m in methods:
                for rep in range(3):
                    if rng.random() < 0.05:
                        runs.append(_run(m, f"t{t}", rep, error="crash"))
                        continue
                    ok = bool(rng.random() < 0.6)
                    runs.append(_run(m, f"t{t}", rep, success=ok, tbf_s=10.0 if ok else float(rng.uniform(0, 10)),
                                     dist=float(rng.uniform(0, 1)), rte_pct=float(rng.gamma(2.0, 1.0))))
        out = oracle_best_runs(runs)
        for t in range(8):
            for rep in range(3):
                here = [r for r in out if r["trajectory"] == f"t{t}" and r["repeat"] == rep]
                best = max(run_rank_key(r) for r in here)
                assert run_rank_key(_oracle(out, f"t{t}", rep)) == best, (seed, t, rep)
        successes = {m: sum(bool(r["success"]) for r in out if r["method"] == m) for m in methods}
        assert successes["oracle"] == max(successes.values()), (seed, successes)
        fails = {m: [r["time_before_failure_s"] for r in out if r["method"] == m and not r["success"]]
                 for m in methods}
        assert all(math.isfinite(v) for v in fails["oracle"]), seed  # a real run wherever one exists
