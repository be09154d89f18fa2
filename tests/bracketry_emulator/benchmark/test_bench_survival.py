"""Exposure decides survival on a demo-size suite walk: a far-too-dark constant (0.0625 ms) loses track where the
oracle keeps it (real renderer, closed loop, built-in VO, failure causes); the oracle row is the best run of the
benchmark's rows on the walk."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from bracketry.cli import main as cli_main
from bracketry_emulator.ae import LoopConfig
from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
from bracketry_emulator.benchmark.oracle_rows import run_rank_key
from bracketry_emulator.synth.suite import WARMUP_STEPS, entries, entry_scenario_doc

pytestmark = pytest.mark.slow

#: the suite seed and walk: seed 0's forest dusk walk (dark: a constant 16 ms loses it, 64 ms keeps it)
SUITE_SEED = 0
WALK = "forest_dusk_a"


@pytest.fixture(scope="module")
def walk(tmp_path_factory) -> Path:
    """The demo-size suite's walk, rendered from its scenario document as ``bracketry synth suite`` renders it."""
    root = tmp_path_factory.mktemp("survival")
    entry = next(e for e in entries("demo") if e.name == WALK)
    scenario = root / "scenario.yaml"
    scenario.write_text(yaml.safe_dump(entry_scenario_doc(entry, "demo", SUITE_SEED), sort_keys=False))
    out = root / WALK
    assert cli_main(["synth", "trajectory", "--scenario", str(scenario), "--out", str(out), "-q"]) == 0
    return out


def test_far_too_dark_constant_loses_track_where_the_oracle_keeps_it(walk: Path, tmp_path: Path) -> None:
    res = run_benchmark(BenchmarkConfig([walk], ["ae50", "oracle", "constant-0.0625"], tmp_path / "bench",
                                        reference="ae50", loop=LoopConfig(warmup_steps=WARMUP_STEPS)))
    by = {r["method"]: r for r in res.results}
    assert by["oracle"]["success"], by["oracle"]["time_before_failure_s"]
    # the oracle row is the best whole run among its step search's and the other rows' (benchmark/oracle_rows.py)
    source = by["oracle"]["oracle_source"]
    assert source in by and all(run_rank_key(by[source]) >= run_rank_key(r) for r in res.results), source
    assert by["oracle"]["rte_pct"] == by[source]["rte_pct"] and by["oracle"]["run_dir"] == by[source]["run_dir"]
    assert not by["constant-0.0625"]["success"]
    assert by["constant-0.0625"]["failure_cause"] == "underexposure"
    rows = (tmp_path / "bench" / "report" / "failure_causes.csv").read_text().splitlines()
    assert rows[0] == "trajectory,method,repeat,time_s,cause"
    assert f"{walk.name},constant-0.0625,0,0.00,underexposure" in rows
