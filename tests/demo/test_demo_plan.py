"""The demo's plans: the default one benchmarks the demo-size suite beside the recording, quick (CI) does not."""

from __future__ import annotations

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
