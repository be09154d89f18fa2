"""Control rows: the 'controls' keyword, the best and worst constant of a grid, their marks in the report."""

from __future__ import annotations

import math

import pytest

from bracketry_base.errors import BracketryError
from bracketry_emulator.ae.registry import resolve_methods
from bracketry_emulator.report.tables import controls_table, method_labels, relabel
from bracketry_emulator.stats.controls import (
    BEST_CONSTANT,
    CONSTANT,
    NON_CAUSAL,
    WORST_CONSTANT,
    constant_ms,
    control_methods,
    control_roles,
)


def _row(method: str, traj: str, success: bool, tbf_s: float, rte_pct: float) -> dict:
    return {"method": method, "trajectory": traj, "subset": "all", "success": success, "time_before_failure_s": tbf_s,
            "rte_pct": rte_pct}


RESULTS = [
    *(_row("ae50", t, True, 10.0, 1.0) for t in "abc"),
    *(_row("constant-0.0625", t, False, 0.0, math.nan) for t in "abc"),  # never tracks
    _row("constant-4", "a", True, 10.0, 1.5), _row("constant-4", "b", True, 10.0, 0.9),
    _row("constant-4", "c", False, 6.0, 2.0),
    _row("constant-64", "a", True, 10.0, 3.0), _row("constant-64", "b", False, 2.0, 4.0),
    _row("constant-64", "c", False, 1.0, math.nan),
    *(_row("oracle", t, True, 10.0, 0.8) for t in "abc"),
]
METHODS = ["ae50", "constant-0.0625", "constant-4", "constant-64", "oracle"]


def test_controls_keyword_expands_to_the_oracle_and_the_constant_grid() -> None:
    names = [s.name for s in resolve_methods(["ae50", "controls"])]
    assert names == ["ae50", *control_methods()]
    assert names[1] == "oracle" and [constant_ms(n) for n in names[2:]] == [0.0625, 0.25, 1.0, 4.0, 16.0, 64.0]
    assert [s.name for s in resolve_methods(["constant-4", "controls"])].count("constant-4") == 1


def test_a_plugin_cannot_take_the_keyword_as_its_name() -> None:
    with pytest.raises(BracketryError, match="controls"):
        from bracketry_emulator.ae.registry import check_method_name

        check_method_name("controls", "pkg:Controls")


def test_best_and_worst_constant_by_success_then_failure_time_then_rte() -> None:
    roles = control_roles(RESULTS, METHODS)
    assert roles == {"oracle": NON_CAUSAL, "constant-4": BEST_CONSTANT, "constant-0.0625": WORST_CONSTANT,
                     "constant-64": CONSTANT}
    # a tie on success is broken by the median time before failure, then by the median RTE
    tie = [_row("constant-1", "a", True, 10.0, 2.0), _row("constant-2", "a", True, 10.0, 1.0),
           _row("constant-8", "a", True, 5.0, 0.5)]
    assert control_roles(tie, ["constant-1", "constant-2", "constant-8"]) == {
        "constant-2": BEST_CONSTANT, "constant-8": WORST_CONSTANT, "constant-1": CONSTANT}
    assert control_roles(RESULTS, ["ae50", "constant-4"]) == {"constant-4": CONSTANT}  # one constant: no ranking


def test_report_marks_control_rows() -> None:
    labels = method_labels(RESULTS, METHODS)
    assert labels["ae50"] == "ae50" and labels["oracle"] == "oracle (non-causal)"
    assert labels["constant-4"] == "constant-4 (best constant)"
    assert labels["constant-0.0625"] == "constant-0.0625 (worst constant)"
    rows = controls_table(RESULTS, METHODS)
    assert [r[0] for r in rows[1:]] == ["constant-0.0625", "constant-4", "constant-64", "oracle"]
    assert rows[2][1:] == [BEST_CONSTANT, "4", "2/3", "10.0", "1.50"]
    assert relabel([["metric", "ae50", "oracle"], ["RTE", "≡", "▲"]], labels, header=True)[0] == [
        "metric", "ae50", "oracle (non-causal)"]
