"""The report's HTML page: the verdicts (coloured), the box plots per metric and method, the success table per subset,
the exposure traces and the qualitative strip lead; the long tables are folded; nothing is wider than the page,
checked in headless Chromium at 1280 px, where every figure loads."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import pytest
from report_results import LONG_METHODS, chromium_probe, synthetic_results

from bracketry_emulator.report import write_report

BOX_FIGURES = ["box_coverage_mean.png", "box_matches_mean.png", "box_rte_pct.png", "box_rre_deg_per_m.png",
               "box_time_before_failure_s.png", "box_tracked_distance_fraction.png"]


@pytest.fixture(scope="module")
def wide_report(tmp_path_factory) -> Path:
    """30 trajectories x 8 methods (long plug-in names), 3 repeats: the report's widest tables."""
    root = tmp_path_factory.mktemp("html_wide")
    write_report(synthetic_results(root), root, "ae50", LONG_METHODS, localisation="test")
    return root / "report" / "report.html"


def _toy_benchmark(root: Path) -> Path:
    """A real small benchmark (built-in VO): 2 toy trajectories in two subsets x 3 emulated 'methods'."""
    from bracketry_emulator.benchmark import BenchmarkConfig, run_benchmark
    from bracketry_emulator.benchmark.toyworld import ToyWorld

    gains = {"ae50": [1.0] * 6, "dim": [0.7] * 6, "burst": [1.0] * 3 + [14.0] * 2 + [1.0]}
    for seed in (1, 2):
        d = root / "data" / f"traj{seed}"
        w = ToyWorld(width_px=256, height_px=192, fx_px=200.0, seed=seed)
        w.write_calibration(d)
        for m, g in gains.items():
            times = w.write_run(d, m, 6, gain=g)
        w.write_groundtruth(d / "groundtruth.txt", times)
    manifest = root / "data" / "manifest.yaml"
    manifest.write_text("trajectories:\n  - {path: traj1, subset: Forest}\n  - {path: traj2, subset: Campus}\n")
    res = run_benchmark(BenchmarkConfig([manifest], list(gains), root / "out", reference="ae50", windows_m=(1.0,)))
    return res.report_files["report.html"]


def test_page_leads_with_the_glance_and_folds_the_long_tables(wide_report: Path) -> None:
    page = wide_report.read_text()
    order = ["<h2>Statistical difference with ae50</h2>", "<h2>Metrics per method</h2>",
             "<h2>Successful trajectories per subset</h2>", "<h2>Exposure and images</h2>", "<details>"]
    at = [page.index(s) for s in order]
    assert at == sorted(at)
    for title in ("Per trajectory", "Tests", "Paired: Wilcoxon signed-rank against ae50", "Per-frame figures"):
        assert page.index(f"<summary>{title}</summary>") > page.index("<details>")
    assert "trajectory_29" not in page[:page.index("<details>")]  # the per-trajectory rows are folded
    glance = page[:page.index("<details>")]
    for name in [*BOX_FIGURES, "exposure_trajectory_00.png", "qualitative.png"]:
        assert f"src='{name}'" in glance and (wide_report.parent / name).stat().st_size > 0
    # the verdict table: one row per compared method, ▼ cells coloured
    verdicts = glance[glance.index("<h2>Statistical difference"):glance.index("<h2>Metrics per method")]
    assert verdicts.count("<tr>") == 1 + len(LONG_METHODS) - 1
    assert "<td class='worse'>▼</td>" in verdicts and "<td class='equal'>≡</td>" in verdicts
    # every table in its own scroll box, every image at most its box's width
    assert page.count("<table>") == page.count("<div class='scroll'><table>") > 0
    assert "img{max-width:100%" in page and ".scroll{max-width:100%;overflow-x:auto" in page


def _check_in_chromium(page: Path, work: Path) -> Path:
    facts, shot = chromium_probe(page, work, width_px=1280)
    assert facts["innerWidth"] == 1280
    assert facts["scrollWidth"] <= 1280, f"the page scrolls sideways: {facts['scrollWidth']} px wide"
    srcs = set(re.findall(r"<img src='([^']+)'", page.read_text()))
    assert {i["src"] for i in facts["images"]} == srcs and srcs
    for img in facts["images"]:
        assert img["complete"] and img["naturalWidth"] > 0, img
    png = cv2.imread(str(shot))
    assert png is not None and png.shape[1] == 1280
    return shot


@pytest.mark.chromium
def test_wide_report_fits_1280_px_in_chromium(wide_report: Path, tmp_path: Path) -> None:
    _check_in_chromium(wide_report, tmp_path)


@pytest.mark.chromium
def test_small_benchmark_report_fits_1280_px_in_chromium(tmp_path: Path) -> None:
    page = _toy_benchmark(tmp_path)
    text = page.read_text()
    assert "<h2>Successful trajectories per subset</h2>" in text and "Campus (1)" in text
    assert (page.parent / "latex" / "verdicts.tex").is_file()
    _check_in_chromium(page, tmp_path)
