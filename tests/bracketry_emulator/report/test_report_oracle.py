"""The report says which run the oracle row took per trajectory (results.csv ``oracle_source``, the control text)."""

from __future__ import annotations

import csv
from pathlib import Path

from report_results import synthetic_results

from bracketry_emulator.report import write_report


def test_report_names_the_runs_the_oracle_took(tmp_path: Path) -> None:
    methods = ["ae50", "constant-16", "oracle"]
    results = synthetic_results(tmp_path, n_traj=3, methods=methods, repeats=1)
    for r, src in zip([r for r in results if r["method"] == "oracle"], ["oracle", "ae50", "constant-16"],
                      strict=True):
        r["oracle_source"] = src
    write_report(results, tmp_path, "ae50", methods, localisation="test")
    with open(tmp_path / "report" / "results.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["oracle_source"] for r in rows if r["method"] == "oracle"] == ["oracle", "ae50", "constant-16"]
    assert {r["oracle_source"] for r in rows if r["method"] != "oracle"} == {""}
    md = (tmp_path / "report" / "report.md").read_text()
    assert "the oracle is NON-CAUSAL, the best exposure sequence found" in md
    assert "runs taken (results.csv oracle_source): ae50 1, constant-16 1, oracle 1;" in md
