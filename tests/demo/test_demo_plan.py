"""The demo's plans: the default one benchmarks the demo-size suite beside the recording, quick (CI) does not."""

from __future__ import annotations

import time
from pathlib import Path

from bracketry.demo.pipeline import DEMO_SUITE, plan, suite


def test_default_plan_adds_the_demo_suite_quick_does_not(tmp_path: Path) -> None:
    default = plan(tmp_path, None, quick=False)
    assert default.suite == DEMO_SUITE == "demo" and default.suite_seed == 0
    assert plan(tmp_path, None, quick=True).suite is None
    assert plan(tmp_path, None, quick=False, suite=False).suite is None
    assert plan(tmp_path, None, quick=True, suite=True).suite == DEMO_SUITE


def test_no_suite_renders_nothing(tmp_path: Path) -> None:
    said: list[str] = []
    assert suite(plan(tmp_path / "out", None, quick=True), said.append) is None
    assert said == [] and not (tmp_path / "out").exists()


def test_the_suite_renders_in_the_background_at_the_lowest_priority_and_stops(tmp_path: Path,
                                                                             monkeypatch) -> None:
    """The default plan starts the suite's render beside the recording (niced, its own log); a demo that fails before
    step 3 ends it. (The render itself, and that the suite is the same bytes however made: tests/.../synth.)"""
    from bracketry.demo.pipeline import BACKGROUND_NICE, start_suite, stop_suite

    assert start_suite(plan(tmp_path / "quick", None, quick=True)) is None
    monkeypatch.setenv("BRACKETRY_CACHE", str(tmp_path / "cache"))  # nothing cached: it has to render
    p = plan(tmp_path / "out", None, quick=False)
    proc = start_suite(p)
    assert proc is not None and proc.poll() is None
    try:
        nice, deadline = None, time.monotonic() + 10.0
        while nice != BACKGROUND_NICE and time.monotonic() < deadline:  # `nice` sets it, then runs bracketry
            nice = int(Path(f"/proc/{proc.pid}/stat").read_text().rsplit(") ", 1)[1].split()[16])
            time.sleep(0.01)
        assert nice == BACKGROUND_NICE
    finally:
        stop_suite(proc)
    assert proc.returncode is not None and proc.returncode != 0
    assert (tmp_path / "out" / "suite.log").is_file() and not (tmp_path / "out" / "suite" / "manifest.yaml").exists()
