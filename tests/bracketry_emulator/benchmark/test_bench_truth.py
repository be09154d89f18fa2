"""Benchmarks on emulated and on truth images (``bracketry benchmark --images``) and their comparison."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from result_rows import metric_rows

from bracketry.cli import main
from bracketry_emulator.benchmark.truth_agreement import kendall_tau, truth_agreement, write_truth_agreement
from emu_synthetic import radiance_map, write_tree

_rows = metric_rows


def test_kendall_tau_and_verdict_flips() -> None:
    assert kendall_tau([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert kendall_tau([1, 2, 3, 4], [40, 30, 20, 10]) == pytest.approx(-1.0)
    n = 8
    emulated = _rows({"ref": [0.5] * n, "a": [0.9] * n, "b": [0.1] * n, "c": [0.5 + 0.01 * k for k in range(n)]})
    same = truth_agreement(emulated, emulated, ["ref", "a", "b", "c"], "ref", 0.05)
    assert same["kendall_tau_median"] == pytest.approx(1.0)
    assert same["verdicts"]["agree"] == same["verdicts"]["total"] == 3 * 5 and not same["verdicts"]["flips"]
    # in truth, method a is no better than the reference: its five verdicts flip, and the ranking changes
    truth = _rows({"ref": [0.5] * n, "a": [0.3] * n, "b": [0.1] * n, "c": [0.5 + 0.01 * k for k in range(n)]})
    doc = truth_agreement(emulated, truth, ["ref", "a", "b", "c"], "ref", 0.05)
    assert doc["verdicts"]["total"] == 15 and doc["verdicts"]["agree"] == 10
    assert {(f["method"], f["emulated"], f["truth"]) for f in doc["verdicts"]["flips"]} == {("a", "better", "worse")}
    assert doc["kendall_tau_median"] < 1.0
    assert doc["metrics"]["coverage_mean"]["methods"]["a"] == {"emulated": pytest.approx(0.9),
                                                               "truth": pytest.approx(0.3)}


def test_truth_agreement_files(tmp_path: Path) -> None:
    rows = _rows({"ref": [0.5] * 4, "a": [0.9] * 4})
    jpath, mpath = write_truth_agreement(truth_agreement(rows, rows, ["ref", "a"], "ref", 0.05), tmp_path / "r")
    assert json.loads(jpath.read_text())["verdicts"]["total"] == 5
    assert "| Coverage | a | 0.9 | 0.9 |" in mpath.read_text()


def test_benchmark_refuses_truth_images_of_a_real_dataset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = write_tree(tmp_path / "tree", radiance_map(seed=2) * 0.02, n_sequences=2)
    for images in ("truth", "both"):
        rc = main(["benchmark", str(data), "--out", str(tmp_path / f"out-{images}"), "-m", "ae50", "--slam",
                   "builtin", "--images", images, "-q"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and "synthetic trajectory" in err[0], err
        assert not (tmp_path / f"out-{images}" / "runs").exists()


def test_benchmark_refuses_truth_images_of_a_suite_rendered_by_other_synth_code(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A suite rendered before the synthetic world changed: its truth images would show another world than its
    brackets (the check runs before any trajectory is read)."""
    from bracketry_emulator.synth.suite import code_digest

    data = write_tree(tmp_path / "tree", radiance_map(seed=2) * 0.02, n_sequences=2)
    for code, expected in (("0123456789ab", "rendered by synth code 0123456789ab"),
                           (code_digest(), "synthetic trajectory")):
        manifest = tmp_path / f"manifest-{code}.yaml"
        manifest.write_text(f"suite: {{version: '1', size: demo, seed: 3, code: '{code}'}}\n"
                            f"trajectories:\n- path: {data}\n  subset: forest\n  name: walk\n")
        for images in ("truth", "both"):
            out = tmp_path / f"out-{code}-{images}"
            rc = main(["benchmark", str(manifest), "--out", str(out), "-m", "ae50", "--slam", "builtin",
                       "--images", images, "-q"])
            err = capsys.readouterr().err.strip().splitlines()
            assert rc == 2 and len(err) == 1 and expected in err[0], err
            assert not (out / "runs").exists()
