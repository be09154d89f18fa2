"""``--parity upstream``: the methods choose the authors' exposure at every step (committed traces of their own
script, see data/upstream_traces/README.md)."""

from __future__ import annotations

import csv
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from bracketry_emulator.ae import LoopConfig, get_method, run_methods
from bracketry_emulator.dataset import open_dataset
from bracketry_emulator.emulation import Emulator, EmulatorConfig

DATA = Path(__file__).parent / "data" / "upstream_traces"
METHODS = ("fix", "ae30", "ae50", "ae70", "shim", "kim", "zhang")


def traces() -> dict[tuple[str, str, str], list[float]]:
    """{(dataset, init_ms, method): [exposure_ms per step]} of the authors' runs."""
    out: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    with open(DATA / "traces.csv") as f:
        for row in csv.DictReader(f):
            out[(row["dataset"], row["init_ms"], row["method"])].append(float(row["exposure_ms"]))
    return out


def kim_outcomes() -> dict[int, set[float]]:
    out: dict[int, set[float]] = defaultdict(set)
    with open(DATA / "kim_gp_outcomes.csv") as f:
        for row in csv.DictReader(f):
            out[int(row["step"])].add(float(row["outcome_ms"]))
    return out


def test_vectors_cover_the_seven_methods() -> None:
    tr = traces()
    for init in ("1.5", "4", "12", "30"):
        assert all(len(tr[("sample", init, m)]) == 2 for m in METHODS)
    assert all(len(tr[("synth_seed18", "4", m)]) == 10 for m in METHODS)
    # the authors' Kim is not deterministic: their two runs of the same command differ
    assert tr[("synth_seed18", "4", "kim")] != tr[("synth_seed18_run2", "4", "kim")]


@pytest.mark.realdata
def test_first_step_equals_the_authors_on_the_sample(borealhdr_sample: Path, borealhdr_sequence: Path) -> None:
    """Every method, four initial exposures: the image of the first bracket cycle -> the authors' next exposure."""
    tr = traces()
    pcalib = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    emu = Emulator(EmulatorConfig(selection="upstream", parity="upstream", crf=str(pcalib)))
    brackets = open_dataset(borealhdr_sequence).sequences()[0].load("left")
    for init in ("1.5", "4", "12", "30"):
        img = emu.emulate(brackets, float(init) * 1000).image
        meta = {"response": emu.response, "step": 0}
        for m in METHODS:
            t0, t1 = tr[("sample", init, m)]
            assert t0 == float(init)
            method = get_method(m, parity="upstream")
            method.reset(t0 * 1000)
            assert method.next_exposure_us(img, t0 * 1000, meta) / 1000 == pytest.approx(t1, rel=1e-9), (init, m)


@pytest.fixture(scope="module")
def synth_short(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 4 bracket cycles of the synthetic trajectory of the vectors (rendering is per frame time, so they
    are the same frames as the 3 s run's)."""
    out = tmp_path_factory.mktemp("synth18") / "w"
    subprocess.run([sys.executable, "-m", "bracketry", "synth", "trajectory", "--out", str(out), "--seconds", "1.1",
                    "--resolution", "1920x1200", "--seed", "18", "-q"], check=True, capture_output=True, timeout=600)
    return out


@pytest.mark.realdata
def test_closed_loop_equals_the_authors_on_a_synthetic_trajectory(borealhdr_sample: Path, synth_short: Path,
                                                                  tmp_path: Path) -> None:
    tr = traces()
    pcalib = borealhdr_sample / "calibration" / "pcalib_inside1.txt"
    cfg = LoopConfig(emulator=EmulatorConfig(selection="upstream", parity="upstream", crf=str(pcalib)),
                     write_images=False)
    run = run_methods(synth_short, list(METHODS), tmp_path / "out", workers=1, config=cfg, progress=False)
    assert (tmp_path / "out" / "summary.json").read_text().count('"mode": "upstream"') == 1
    for m in METHODS:
        ours = run.runs[m].exposures_ms
        assert len(ours) == 4
        theirs = tr[("synth_seed18_run2" if m == "kim" else "synth_seed18", "4", m)][:4]
        assert ours == pytest.approx(theirs, rel=1e-9), m
    outcomes = kim_outcomes()
    for k, t in enumerate(run.runs["kim"].exposures_ms[1:], start=1):
        assert any(abs(t - o) < 1e-3 for o in outcomes[k]), (k, t, outcomes[k])


def test_all_is_the_papers_eight_and_the_mode_is_in_the_benchmark_key(tmp_path: Path) -> None:
    from bracketry_emulator.ae import expand_methods
    from bracketry_emulator.benchmark.emulated_runs import loop_config
    from bracketry_emulator.benchmark.tasks import make_task
    from bracketry_emulator.metrics.manifest import TrajectorySpec

    assert expand_methods("all", has_drl_weights=True) == ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim", "drl"]
    assert "drl" not in expand_methods("all", has_drl_weights=False)
    assert expand_methods("all,zhang", has_drl_weights=False)[-1] == "zhang"
    up = loop_config({"parity": "upstream"}, None)
    assert up.emulator.parity == "upstream" and up.emulator.selection == "upstream"
    spec = TrajectorySpec(name="t", path=tmp_path)
    keys = {make_task(spec, "shim", tmp_path, loop={"parity": p})["key"] for p in ("default", "upstream")}
    assert len(keys) == 2
