"""`bracketry demo` with a researcher's AE plugins: an import-path plugin (a module on PYTHONPATH, with an option
from the command line) and an entry-point plugin (a tiny package pip-installed into a test-local folder, its option
from a YAML file) run from the recording to a report whose statistics hold both, by their names."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from ae_plugin_kit import bracketry, entry_point_plugin, env_with, import_path_plugin


@pytest.mark.slow
def test_demo_runs_plugins_into_the_statistics(tmp_path: Path) -> None:
    mod_dir, mod_id = import_path_plugin(tmp_path / "mod")
    site, ep_id = entry_point_plugin(tmp_path / "ep")
    opts = tmp_path / "opts.yaml"
    opts.write_text("darker: {target: 0.2}\n")
    out = tmp_path / "demo"
    res = bracketry(["demo", "--quick", "--duration-s", "5", "--out", str(out), "--methods",
                     f"ae50,{mod_id},{ep_id}", "--method-option", "brighter.target=0.5", "--method-options",
                     str(opts), "--stats-methods", "all"], env_with(mod_dir, site), timeout=1200)
    assert res.returncode == 0, res.stderr[-3000:]
    rep = out / "benchmark" / "report"
    with open(rep / "verdicts.csv", newline="") as f:
        assert next(csv.reader(f)) == ["metric", "brighter", "darker"]
    md = (rep / "report.md").read_text()
    assert "brighter: ae_kit_mod:Brighter, target=0.5" in md and "darker: ae-kit-ep, target=0.2" in md
    runs = {p.name for p in (out / "benchmark" / "runs").glob("*/*") if p.is_dir()}
    assert runs == {"ae50", "brighter", "darker"}


def test_demo_refuses_a_bad_plugin_option_before_recording(tmp_path: Path) -> None:
    mod_dir, mod_id = import_path_plugin(tmp_path / "mod")
    out = tmp_path / "demo"
    res = bracketry(["demo", "--quick", "--out", str(out), "--methods", f"ae50,{mod_id}", "--method-option",
                     "brighter.gain=2"], env_with(mod_dir), timeout=120)
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert "cannot be created with options gain=2" in res.stderr
    assert not out.exists() or not any(out.iterdir())
