"""The cause analysis of emulated-vs-truth disagreement (``bracketry accuracy truth-causes``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from result_rows import metric_rows

from bracketry_base.errors import BracketryError
from bracketry_emulator.benchmark.truth_causes import truth_causes, variant_dataset, write_truth_causes
from bracketry_emulator.metrics.manifest import load_manifest

_rows = metric_rows


def test_the_effect_whose_removal_brings_the_truth_to_the_emulation_drives_it() -> None:
    methods = ["ref", "a", "b"]
    emulated = _rows({"ref": [0.5] * 4, "a": [0.8] * 4, "b": [0.2] * 4})
    truth = _rows({"ref": [0.5] * 4, "a": [0.3] * 4, "b": [0.6] * 4})
    half = _rows({"ref": [0.5] * 4, "a": [0.55] * 4, "b": [0.4] * 4})
    doc = truth_causes(emulated, truth, {"blur": emulated, "noise": truth, "instant": half}, methods)
    cov = doc["metrics"]["coverage_mean"]
    assert cov["effects"]["blur"]["gap_closed"] == pytest.approx(1.0)
    assert cov["effects"]["noise"]["gap_closed"] == pytest.approx(0.0)
    assert cov["effects"]["instant"]["gap_closed"] == pytest.approx(0.5)
    assert cov["driver"] == "blur"
    assert cov["effects"]["blur"]["kendall_tau_emulated"] == pytest.approx(1.0)
    assert cov["effects"]["noise"]["kendall_tau_truth"] == pytest.approx(1.0)
    assert cov["kendall_tau_emulated_truth"] < 0
    # a variant farther from the emulation than the truth drives nothing
    alone = truth_causes(emulated, truth, {"noise": _rows({"ref": [0.5] * 4, "a": [0.1] * 4, "b": [0.9] * 4})},
                         methods)
    assert alone["metrics"]["coverage_mean"]["effects"]["noise"]["gap_closed"] < 0
    assert alone["metrics"]["coverage_mean"]["driver"] is None


def test_truth_causes_files_and_section_of_the_agreement_report(tmp_path: Path) -> None:
    rows = _rows({"ref": [0.5] * 3, "a": [0.9] * 3})
    other = _rows({"ref": [0.5] * 3, "a": [0.7] * 3})
    rep = tmp_path / "report"
    rep.mkdir()
    (rep / "truth_agreement.md").write_text("# Emulated vs truth images\n")
    doc = truth_causes(rows, other, {"noise": rows}, ["ref", "a"])
    for _ in range(2):  # written twice: one section
        jpath, mpath = write_truth_causes(doc, rep)
    assert json.loads(jpath.read_text())["metrics"]["coverage_mean"]["driver"] == "noise"
    text = (rep / "truth_agreement.md").read_text()
    assert text.startswith("# Emulated vs truth images") and text.count("## Which effect drives") == 1
    assert "| noise |" in mpath.read_text()


def test_variant_dataset_links_the_data_and_switches_one_effect_off(tmp_path: Path) -> None:
    suite = tmp_path / "suite"
    traj = suite / "forest" / "walk_a"
    (traj / "images").mkdir(parents=True)
    (traj / "images" / "f.png").write_bytes(b"png")
    (traj / "groundtruth.txt").write_text("0 0 0 0 0 0 0 1\n")
    (traj / "camera_model.json").write_text(json.dumps({"world": {"seed": 1}, "recording": {"t0_ns": 0}}))
    (suite / "manifest.yaml").write_text(yaml.safe_dump(
        {"warmup_steps": 3, "trajectories": [{"path": "forest/walk_a", "subset": "forest", "name": "walk_a"}]}))
    man = variant_dataset(suite / "manifest.yaml", "blur", tmp_path / "v")
    specs = load_manifest(man)
    assert [s.name for s in specs] == ["walk_a"] and specs[0].path == (tmp_path / "v" / "forest" / "walk_a")
    assert (specs[0].path / "groundtruth.txt").is_symlink()
    assert (specs[0].path / "images" / "f.png").read_bytes() == b"png"
    info = json.loads((specs[0].path / "camera_model.json").read_text())
    assert info["truth_effects"] == {"blur": False} and info["world"] == {"seed": 1}
    assert yaml.safe_load(man.read_text())["warmup_steps"] == 3
    assert "truth_effects" not in json.loads((traj / "camera_model.json").read_text())  # the original untouched
    with pytest.raises(BracketryError, match="unknown effect"):
        variant_dataset(suite / "manifest.yaml", "gain", tmp_path / "w")


@pytest.mark.slow
def test_truth_causes_command_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two short synthetic walks, two methods, the noise switched off: the benchmark both ways, then the variant."""
    from bracketry.cli import main
    from bracketry_emulator.synth import LoopTrajectory, World, write_trajectory

    suite = tmp_path / "suite"
    for k in range(2):
        write_trajectory(World("forest-winter", 10 + k, (320, 200), trajectory=LoopTrajectory(speed_kmh=3.0)),
                         suite / "walks" / f"w{k}", seconds=1.0)
    # the manifest's windows (the 1 s walks are 0.8 m long) are the default, as for bracketry benchmark
    (suite / "manifest.yaml").write_text(yaml.safe_dump({"windows_m": [0.2, 0.3, 0.4], "trajectories": [
        {"path": f"walks/w{k}", "subset": "walks", "name": f"w{k}"} for k in range(2)]}))
    out = tmp_path / "out"
    rc = main(["accuracy", "truth-causes", str(suite / "manifest.yaml"), "--out", str(out), "-m", "ae50,ae30",
               "--effects", "noise"])
    assert rc == 0, capsys.readouterr()
    for part in ("both", "both/truth", "variants/noise/bench"):
        rows = json.loads((out / part / "report" / "results.json").read_text())
        assert rows and all([w["window_m"] for w in r["windows"]] == [0.2, 0.3, 0.4] for r in rows), part
    doc = json.loads((out / "both" / "report" / "truth_causes.json").read_text())
    assert doc["methods"] == ["ae50", "ae30"] and list(doc["effects"]) == ["noise"]
    assert set(doc["metrics"]) >= {"coverage_mean", "matches_mean"}
    assert (out / "variants" / "noise" / "data" / "walks" / "w0" / "camera_model.json").is_file()
    assert "## Which effect drives" in (out / "both" / "report" / "truth_agreement.md").read_text()
    assert main(["accuracy", "truth-causes", str(suite / "manifest.yaml"), "--out", str(out), "--effects",
                 "gain"]) == 2  # an unknown effect: one line, exit 2
