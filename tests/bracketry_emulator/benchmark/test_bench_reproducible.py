"""The same ``bracketry benchmark`` command (ORB-SLAM3 in lockstep, the default feed) three times on the same suite,
the third beside two busy loops: the verdict tables and the success counts are the same bytes.

Lean, as tests/bracketry_emulator/slam/test_bench_orbslam3.py: three 3 s synthetic walks at 320x240 (11 frames
each), two methods, a k=8, L=4 vocabulary trained on a toy corridor; every ORB-SLAM3 run is a real child. With
three walks every verdict is ≡ (no Wilcoxon p below 0.25): the comparison holds the success counts and the verdict
symbols (the stabilities, shares computed from the runs' values, are in stats.csv and wilcoxon.csv). The runs' own
RTE, RRE and matches (``results.csv``) still differ: ORB-SLAM3 is not byte-reproducible even in lockstep
(docs/RESULTS.md, "The lockstep feed").
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bracketry.cli import main as cli_main
from bracketry_emulator.benchmark.toyworld import ToyWorld

pytestmark = pytest.mark.orbslam3

#: the report files that must not move with the machine's load
COMPARED = ("verdicts.csv", "verdicts_paired.csv", "success.csv")
N_BUSY = 2


@pytest.fixture(scope="module")
def suite(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path | list[Path]]:
    """Three synthetic walks (seeds 1-3) and a vocabulary."""
    root = tmp_path_factory.mktemp("reproducible")
    walks = []
    for seed in (1, 2, 3):
        walk = root / f"w{seed}"
        assert cli_main(["synth", "trajectory", "--out", str(walk), "--seed", str(seed), "--duration-s", "3",
                         "--resolution", "320x240", "-q"]) == 0
        walks.append(walk)
    ToyWorld(width_px=320, height_px=240, fx_px=240.0, seed=99).write_run(root / "train", "x", 6, t0_ns=90 * 10**9)
    voc = root / "voc.txt"
    images = sorted(str(p) for p in (root / "train" / "x" / "images_left").glob("*.png"))
    assert cli_main(["slam", "vocabulary", *images, "--out", str(voc), "--k", "8", "--levels", "4",
                     "--seed", "3"]) == 0
    return {"walks": walks, "voc": voc}


def _benchmark(suite: dict, out: Path) -> dict[str, bytes]:
    walks = [str(w) for w in suite["walks"]]  # type: ignore[union-attr]
    assert cli_main(["benchmark", *walks, "--out", str(out), "-m", "ae50,fix", "--vocabulary", str(suite["voc"]),
                     "--windows", "1", "--workers", "2", "-q"]) == 0
    return {name: (out / "report" / name).read_bytes() for name in COMPARED}


def test_three_runs_one_beside_busy_loops_give_the_same_verdicts(suite: dict, tmp_path: Path) -> None:
    first = _benchmark(suite, tmp_path / "a")
    second = _benchmark(suite, tmp_path / "b")
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(N_BUSY)]
    try:
        assert all(p.poll() is None for p in busy)
        loaded = _benchmark(suite, tmp_path / "c")
        assert all(p.poll() is None for p in busy)  # they ran all along
    finally:
        for p in busy:
            p.kill()
            p.wait()
    for name in COMPARED:
        assert second[name] == first[name], name
        assert loaded[name] == first[name], name
    assert first["success.csv"].decode().splitlines()[-1] == "Total (3),3,3"  # the lockstep runs all tracked
    assert first["verdicts_paired.csv"].decode().splitlines()[0] == "metric,fix"
