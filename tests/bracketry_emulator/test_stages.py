"""The benchmark's stage timing collector and its table (pure: made-up seconds with known results)."""

from __future__ import annotations

import time

import pytest

from bracketry_emulator.stages import StageTimes, ae_stage, machine_line, stage_rows


def test_stage_times_add_merge_and_order() -> None:
    a = StageTimes()
    a.add("slam", 30.0, 12.0)
    a.add(ae_stage("kim"), 1.5, 1.4, n=40)
    a.add("decode", 2.0)  # CPU not measured: absent, not zero
    b = StageTimes()
    b.add("slam", 10.0, 3.0)
    b.add(ae_stage("ae50"), 0.5, 0.5, n=40)
    doc = a.merge(b.as_dict()).as_dict()
    assert list(doc) == ["decode", "ae:ae50", "ae:kim", "slam"]  # the fixed table order, methods by name
    assert doc["slam"] == {"wall_s": 40.0, "cpu_s": 15.0, "count": 2}
    assert doc["ae:kim"]["count"] == 40 and "cpu_s" not in doc["decode"]
    with pytest.raises(ValueError, match="unknown stage"):
        a.add("rendering", 1.0)
    with pytest.raises(ValueError, match="unknown stage"):
        a.add("ae", 1.0)  # an AE stage names its method


def test_stage_timer_measures_wall_and_thread_cpu() -> None:
    st = StageTimes()
    with st.time("metrics"):
        time.sleep(0.05)
    d = st.as_dict()["metrics"]
    assert d["wall_s"] >= 0.05 and d["cpu_s"] < d["wall_s"]  # sleeping costs no CPU


def test_stage_rows_are_seconds_per_trajectory_minute() -> None:
    st = StageTimes()
    st.add("emulation", 9.0, 6.0)
    st.add("slam", 120.0, 30.0, n=4)
    rows = stage_rows(st.as_dict(), trajectory_s=30.0, wall_total_s=75.0)  # half a trajectory-minute
    assert rows[0] == ["stage", "runs", "seconds", "CPU seconds", "s per trajectory-minute",
                       "CPU s per trajectory-minute"]
    assert rows[1] == ["emulation", "1", "9.00", "6.00", "18.00", "12.00"]
    assert rows[2] == ["slam", "4", "120", "30.00", "240", "60.00"]
    assert rows[3][0] == "benchmark (wall clock)" and rows[3][4] == "150"
    no_minutes = stage_rows(st.as_dict(), trajectory_s=0.0)
    assert no_minutes[1][4] == "" and len(no_minutes) == 3


def test_machine_line() -> None:
    line = machine_line({"cpu": "Some CPU", "cpus": 2, "system": "Linux 6", "load_average": [1.5, 2.0, 3.0]})
    assert line == "Some CPU, 2 logical CPUs, Linux 6, load average 1.5 / 2.0 / 3.0 (1/5/15 min)"
