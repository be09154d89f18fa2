"""The AE plugin API: a method by import path, by entry point, and the PLUGINS.md example end to end."""

from __future__ import annotations

import csv
import json
import re
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from test_ae_runner import tiny_tree

from bracketry_base import paths
from bracketry_base.errors import BracketryError
from bracketry_emulator.ae import get_method

PLUGIN_SOURCE = textwrap.dedent('''
    class HalfAE:
        """Halves the exposure whenever the mean code is above 2048, else doubles it."""

        name = "half"

        def reset(self, init_exposure_us):
            self.calls = 0

        def next_exposure_us(self, image, exposure_us, meta):
            self.calls += 1
            return exposure_us / 2 if image.mean() > 2048 else exposure_us * 2


    class NoName:
        def reset(self, init_exposure_us):
            pass

        def next_exposure_us(self, image, exposure_us, meta):
            return exposure_us


    class Broken:
        name = "broken"
''')


@pytest.fixture()
def plugin_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "ae_plugin_demo.py").write_text(PLUGIN_SOURCE)
    dist = tmp_path / "ae_plugin_demo-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ae-plugin-demo\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[bracketry.ae_methods]\nhalf-ep = ae_plugin_demo:HalfAE\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("ae_plugin_demo", None)


def test_plugin_by_import_path(plugin_dir: Path) -> None:
    m = get_method("ae_plugin_demo:HalfAE")
    m.reset(1000.0)
    assert m.name == "half"
    assert m.next_exposure_us(np.full((4, 4), 4000, np.uint16), 1000.0, {}) == 500.0
    assert get_method("ae_plugin_demo:NoName").name == "NoName"
    with pytest.raises(BracketryError, match="no method reset"):
        get_method("ae_plugin_demo:Broken")


def test_plugin_by_entry_point(plugin_dir: Path) -> None:
    m = get_method("half-ep")
    m.reset(1000.0)
    assert m.next_exposure_us(np.zeros((4, 4), np.uint16), 1000.0, {}) == 2000.0


def test_the_documented_example_plugin_runs_in_closed_loop(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The TargetMedian example of PLUGINS.md, copied from the doc, run by ``bracketry emulate`` as documented."""
    from bracketry.cli import main

    doc = (paths.repo_root() / "emulator" / "bracketry_emulator" / "ae" / "PLUGINS.md").read_text()
    source = re.search(r"`my_ae/bright.py`:\s*```python\n(.*?)```", doc, re.S)
    assert source is not None, "the example is no longer in PLUGINS.md"
    pkg = tmp_path / "plugins" / "my_ae"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "bright.py").write_text(source.group(1))
    monkeypatch.syspath_prepend(str(tmp_path / "plugins"))
    rec = tiny_tree(tmp_path, 3)
    out = tmp_path / "runs"
    assert main(["emulate", str(rec), "--method", "ae50,my_ae.bright:TargetMedian", "--out", str(out), "-j", "1",
                 "-q"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["methods"]) == {"ae50", "median40"}  # the class's name names its outputs
    assert summary["plugins"] == {"median40": {"source": "my_ae.bright:TargetMedian", "options": {}}}
    assert len(list((out / "median40" / "images_left").glob("*.png"))) == 3
    assert (out / "exposures.csv").read_text().splitlines()[0] == "step,timestamp_ns,ae50_ms,median40_ms"
    # the option PLUGINS.md's "Options" passes (--method-option median40.target=0.3) is one the class takes
    options = re.search(r"--method-option median40\.(\w+)=([\d.]+)", doc)
    assert options is not None
    from my_ae.bright import TargetMedian
    assert TargetMedian(**{options.group(1): float(options.group(2))}).target == 0.3
    sys.modules.pop("my_ae.bright", None)
    sys.modules.pop("my_ae", None)


GAIN_PLUGIN = textwrap.dedent('''
    from bracketry_emulator.ae import CameraSetting


    class QuarterAndGain:
        """1 ms at 12 dB every frame (the exposure-equivalent 3.98 ms); records what it was told."""

        name = "quarter-gain"

        def reset(self, init_exposure_us):
            self.seen = []

        def next_exposure_us(self, image, exposure_us, meta):
            self.seen.append((exposure_us, meta["gain_db"], meta["camera_exposure_us"]))
            return CameraSetting(1000.0, 12.0)
''')


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_plugin_that_sets_the_gain_runs_in_closed_loop(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          workers: str) -> None:
    """Through ``bracketry emulate`` (in-process and forked workers): after the first frame (4 ms), every step is
    1 ms at 12 dB, emulated from the 1 ms bracket, recorded in ae.csv and steps.csv; the other method (ae50) in the
    same run is unchanged by it."""
    from bracketry.cli import main

    (tmp_path / "gain_plugin_demo.py").write_text(GAIN_PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    rec = tiny_tree(tmp_path, 3)
    out = tmp_path / "runs"
    assert main(["emulate", str(rec), "--method", "ae50,gain_plugin_demo:QuarterAndGain", "--out", str(out),
                 "-j", workers, "-q"]) == 0
    with open(out / "quarter-gain" / "ae.csv") as f:
        rows = list(csv.DictReader(f))
    target_ms = 10 ** (12 / 20)  # 1 ms x 12 dB
    assert [float(r["exposure_ms"]) for r in rows] == pytest.approx([4.0, target_ms, target_ms], rel=1e-5)
    assert [float(r["gain_db"]) for r in rows] == pytest.approx([0.0, 12.0, 12.0])
    assert [float(r["source_exposure_ms"]) for r in rows] == [4.0, 1.0, 1.0]
    with open(out / "quarter-gain" / "steps.csv") as f:
        steps = list(csv.DictReader(f))
    assert [float(r["exposure_ms"]) for r in steps] == pytest.approx([4.0, 1.0, 1.0])
    assert [float(r["gain_db"]) for r in steps] == pytest.approx([0.0, 12.0, 12.0])
    with open(out / "ae50" / "ae.csv") as f:
        assert all(float(r["gain_db"]) == 0.0 for r in csv.DictReader(f))
    sys.modules.pop("gain_plugin_demo", None)
