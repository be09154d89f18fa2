"""The benchmark tells a known-bad control from AE50: a far-too-dark constant exposure on a small synthetic suite
(real renderer, closed loops, built-in VO, metrics, statistics, report), deterministic under its seeds."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from bracketry.cli import main as cli_main
from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
from bracketry_emulator.report.tables import per_metric_values, per_trajectory_values
from bracketry_emulator.stats.mannwhitney import WORSE, verdict_table
from bracketry_emulator.stats.paired import wilcoxon_to_reference

pytestmark = pytest.mark.slow

#: the suite: snowy forest walks of 3 s at 320x200, one per seed (Mann-Whitney with 5 vs 5 reaches p = 0.008)
SEEDS = (1, 2, 3, 4, 5)
DARK = "constant-0.0625"  # 4 stops under the shortest bracket: nothing to track in a snowy forest


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("controls_suite")
    for seed in SEEDS:
        rc = cli_main(["synth", "trajectory", "--out", str(root / f"walk{seed}"), "--seed", str(seed),
                       "--duration-s", "3", "--resolution", "320x200", "-q"])
        assert rc == 0
    manifest = {"trajectories": [{"path": f"walk{s}", "subset": "forest"} for s in SEEDS]}
    (root / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    return root / "manifest.yaml"


def test_far_too_dark_constant_is_flagged_worse_than_ae50(suite: Path, tmp_path: Path) -> None:
    result = run_benchmark(BenchmarkConfig([suite], ["ae50", DARK], tmp_path / "bench", windows_m=(0.5, 1.0),
                                           stats_methods="all"))
    rows = result.results
    methods = ["ae50", DARK]
    assert sorted({r["trajectory"] for r in rows}) == [f"walk{s}" for s in SEEDS]
    ae50_ok = [r["success"] for r in rows if r["method"] == "ae50"]
    assert all(ae50_ok), [(r["trajectory"], r["time_before_failure_s"]) for r in rows if r["method"] == "ae50"]
    assert not any(r["success"] for r in rows if r["method"] == DARK)
    verdicts = verdict_table(per_metric_values(rows, methods), "ae50")
    assert verdicts["time_before_failure_s"][DARK].verdict == WORSE
    # Wilcoxon's two-sided p cannot go below 2/2^5 = 0.0625 with 5 pairs: it sees the same direction, not a verdict
    paired = wilcoxon_to_reference(per_trajectory_values(rows, methods, "time_before_failure_s"), "ae50", True)
    assert paired[DARK].effect_r == -1.0 and paired[DARK].p_two_sided == pytest.approx(0.0625)
    # the report says it too, and marks the constant as a control row
    table = (result.out_dir / "report" / "verdicts.csv").read_text().splitlines()
    assert table[0] == f"metric,{DARK}" and "Failure Time,▼" in table
    stats = (result.out_dir / "report" / "stats.csv").read_text().splitlines()  # the verdict's stability
    assert any(line.startswith(f"Failure Time,{DARK},") and line.endswith(",worse,1.00") for line in stats), stats
    assert f"{DARK} (control)" in (result.out_dir / "report" / "report.md").read_text()
