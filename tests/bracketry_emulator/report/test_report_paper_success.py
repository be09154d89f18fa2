"""Our successful trajectories beside the paper's table (report/tables.py ``success_beside_paper``), in the report."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from report_results import synthetic_results

from bracketry_emulator.report import write_report
from bracketry_emulator.report.tables import PAPER_SUCCESS, success_beside_paper


def _rows(successes: dict[str, int], n: int = 4) -> list[dict]:
    return [{"trajectory": f"t{k}", "subset": "forest", "method": m, "success": k < ok}
            for m, ok in successes.items() for k in range(n)]


def test_counts_shares_and_tau_over_the_papers_methods() -> None:
    results = _rows({"ae50": 4, "fix": 3, "kim": 1, "wang": 0, "oracle": 4})
    rows, tau = success_beside_paper(results, ["ae50", "fix", "kim", "wang", "oracle"])
    assert rows[0][0] == "method" and [r[0] for r in rows[1:]] == ["ae50", "fix", "kim", "wang"]  # no oracle
    assert rows[2] == ["fix", "3/4", "75", "40", "68"]
    # ours ae50 > fix > kim > wang; the paper's fix 40 > ae50 31 > kim 19 > wang 12: 5 pairs agree, 1 does not
    assert math.isclose(tau, (5 - 1) / 6)


def test_no_tau_without_three_methods_or_a_spread() -> None:
    assert math.isnan(success_beside_paper(_rows({"ae50": 4, "fix": 3}), ["ae50", "fix"])[1])
    assert math.isnan(success_beside_paper(_rows({"ae50": 4, "fix": 4, "kim": 4}), ["ae50", "fix", "kim"])[1])
    rows, tau = success_beside_paper(_rows({"oracle": 4, "mine": 2}), ["oracle", "mine"])
    assert rows == [rows[0]] and math.isnan(tau)


def test_report_writes_it_beside_the_success_table(tmp_path: Path) -> None:
    methods = ["ae50", "fix", "shim", "kim"]
    write_report(synthetic_results(tmp_path, n_traj=6, methods=methods, repeats=1), tmp_path, "ae50", methods,
                 localisation="test")
    with open(tmp_path / "report" / "success_paper.csv", newline="") as fh:
        table = list(csv.reader(fh))
    assert [r[0] for r in table[1:]] == methods and [int(r[3]) for r in table[1:]] == [PAPER_SUCCESS[m]
                                                                                        for m in methods]
    md = (tmp_path / "report" / "report.md").read_text()
    assert "## Successful trajectories beside the paper's (ORB-SLAM2, 59 trajectories; Kendall's tau" in md
