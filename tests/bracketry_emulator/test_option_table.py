"""The settings table (bracketry_emulator/option_table.py): a setting declared once reaches the commands' options,
the closed loop's JSON form, the cache key and the worker; the records' defaults are the table's; the cache keys
are the ones the code gave before the table existed (literals)."""

from __future__ import annotations

import dataclasses
import importlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import click
import pytest
from click.testing import CliRunner

from bracketry_base.options import Number
from bracketry_emulator import option_table
from bracketry_emulator.ae import scheduler
from bracketry_emulator.ae.registry import MethodSpec
from bracketry_emulator.ae.runner import LoopConfig
from bracketry_emulator.benchmark.slam import SlamOptions
from bracketry_emulator.benchmark.tasks import make_task
from bracketry_emulator.metrics.manifest import TrajectorySpec
from bracketry_emulator.option_table import BENCHMARK, EMULATE, SETTINGS, Setting, rows

#: two rows no command has: one filling a field of the emulator's settings, one with no field anywhere (it travels
#: in LoopConfig.extra)
SAT = Setting("test_sat_alpha", "loop", "--test-sat-alpha", "HigherNoSat's saturated fraction (a test's row).", 0.01,
              type=Number(0.0, 1.0), key="changed", field="emulator.alpha")
GAMMA = Setting("test_gamma", "loop", "--test-gamma", "A setting no code reads yet (a test's row).", 1.0,
                type=Number(0.0, 10.0), key="changed")


def _options(command: click.Command) -> set[str]:
    return {o for p in command.params for o in (*p.opts, *p.secondary_opts)}


@pytest.fixture
def declared(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Any, Any]]:
    """The table with the two test rows, and the emulate and benchmark commands declared again from it."""
    monkeypatch.setattr(option_table, "SETTINGS", (*SETTINGS, SAT, GAMMA))
    from bracketry_emulator.cli import benchmark, emulate

    try:
        yield importlib.reload(emulate).command, importlib.reload(benchmark).command
    finally:
        monkeypatch.undo()
        importlib.reload(emulate)
        importlib.reload(benchmark)


def _tiny_tree(root: Path) -> Path:
    import sys

    sys.path.insert(0, str(Path(__file__).parent / "ae"))
    from test_ae_runner import tiny_tree  # the closed-loop runner's own tiny synthetic tree

    return tiny_tree(root, n_seq=2)


def test_a_setting_declared_once_reaches_both_commands_json_key_and_worker(
        declared: tuple[Any, Any], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    emulate, benchmark = declared
    for command in (emulate, benchmark):
        assert {"--test-sat-alpha", "--test-gamma"} <= _options(command)
        assert {"--test-sat-alpha", "--test-gamma"} <= {s.option for s in option_table.settings_for(command.name)}

    # the benchmark's command line -> its closed-loop record, JSON form and cache key
    seen: dict[str, Any] = {}

    def capture(config: Any, **_: Any) -> Any:
        seen["config"] = config
        raise click.exceptions.Exit(0)

    monkeypatch.setattr("bracketry_emulator.benchmark.run_benchmark", capture)
    ds = _tiny_tree(tmp_path)
    res = CliRunner().invoke(benchmark, [str(ds), "--out", str(tmp_path / "bench"), "--methods", "ae50",
                                         "--slam", "builtin", "--test-sat-alpha", "0.05", "--test-gamma", "2.5"])
    assert res.exit_code == 0, res.output
    loop: LoopConfig = seen["config"].loop
    assert loop.emulator.alpha == 0.05 and loop.value("test_gamma") == 2.5
    assert loop.to_json()["alpha"] == 0.05 and loop.to_json()["test_gamma"] == 2.5
    assert "alpha" not in LoopConfig().to_json() and "test_gamma" not in LoopConfig().to_json()  # keys unchanged
    assert LoopConfig.from_json(loop.to_json()) == loop and loop.round_trips()
    spec = TrajectorySpec("t1", Path("/nonexistent/t1"))
    keys = {make_task(spec, "ae50", Path("/out"), loop=lp).key
            for lp in (LoopConfig(), loop, dataclasses.replace(loop, extra=(("test_gamma", 1.0),)))}
    assert len(keys) == 3
    assert make_task(spec, "ae50", Path("/out"), loop=LoopConfig()).key == KEYS["default", "ae50", None, 0]

    # the emulate command line -> what the closed-loop worker receives
    workers: list[scheduler.LoopSettings] = []

    class Spy(scheduler.Worker):
        def __init__(self, specs: Any, settings: scheduler.LoopSettings, *args: Any, **kw: Any) -> None:
            workers.append(settings)
            super().__init__(specs, settings, *args, **kw)

    monkeypatch.setattr(scheduler, "Worker", Spy)
    res = CliRunner().invoke(emulate, [str(ds), "--out", str(tmp_path / "emu"), "-m", "ae50", "-j", "1", "-q",
                                       "--no-images", "--test-sat-alpha", "0.05", "--test-gamma", "2.5"])
    assert res.exit_code == 0, res.output
    assert [w.loop.emulator.alpha for w in workers] == [0.05]
    assert workers[0].loop.value("test_gamma") == 2.5 and workers[0].loop.value("emulator.alpha") == 0.05
    summary = json.loads((tmp_path / "emu" / "summary.json").read_text())
    assert summary["emulator"]["alpha"] == 0.05


def test_records_take_their_defaults_from_the_table() -> None:
    loop = LoopConfig()
    for s in rows("loop"):
        assert loop.value(s.target) == s.default_value, s.name
    slam = SlamOptions()
    for s in rows("slam"):
        assert getattr(slam, s.target) == s.default_value, s.name
    assert LoopConfig.from_values({}) == LoopConfig()


def test_every_row_is_taken_by_a_command_and_named_once() -> None:
    names = [s.name for s in SETTINGS]
    assert len(names) == len(set(names))
    options = [o for s in SETTINGS for o in (s.option, *s.aliases)]
    assert len(options) == len(set(options))
    assert all(s.commands and s.help for s in SETTINGS)
    assert {s.name for s in option_table.settings_for(EMULATE)} & {s.name for s in option_table.settings_for(BENCHMARK)}


#: task -> its cache key (captured with CACHE_VERSION 9, the ORB sizing and the settings format 2 in ORB-SLAM3's keys):
#: the keys of every cached run stay valid; a change of what a key holds, made on purpose, updates this table with it
KEYS = {
    ("default", "ae50", None, 0): "56cc5a47b49b9fa8", ("default", "ae50", "orbslam3", 1): "5b51b58c4011ab90",
    ("default", "drl", None, 0): "b70d8051f6011a4c", ("default", "drl", "orbslam3", 1): "178133c12238aa2e",
    ("default", "half", None, 0): "627f3d086b215baa", ("default", "half", "orbslam3", 1): "023a921528aa53b7",
    ("many", "ae50", None, 0): "da043efb36f224ac", ("many", "ae50", "orbslam3", 1): "634e427258853132",
    ("many", "drl", None, 0): "6fd4fb42679334f4", ("many", "drl", "orbslam3", 1): "ca4848a470f8cf4b",
    ("many", "half", None, 0): "cb0b7012af108100", ("many", "half", "orbslam3", 1): "77bd53ff72e2f331",
    ("upstream", "ae50", None, 0): "f3ea16250c8f38f0", ("upstream", "ae50", "orbslam3", 1): "acc74ea2b489f990",
    ("upstream", "drl", None, 0): "be5d3b932c18121e", ("upstream", "drl", "orbslam3", 1): "b342ab3a7d6ae512",
    ("upstream", "half", None, 0): "0a15b3c1042b182b", ("upstream", "half", "orbslam3", 1): "6b3ecf8acadfd682",
    ("default", "ae50", "lockstep", 1): "c1dc51f82150afe9",
}
LOOPS = {
    "default": {},
    "many": {"selection": "fusion", "seed": 7, "ae_camera": "right", "init_exposure_us": 8000.0, "blur": True,
             "images": "truth", "warmup_steps": 3, "min_exposure_us": 50.0},
    "upstream": {"parity": "upstream"},
}
#: closedloop_options.json of those loops, as the code wrote it before the table
LOOP_JSON = {
    "default": '{"ae_camera": "left", "crf": "srgb", "init_exposure_us": 4000.0, "parity": "default", "seed": 0, '
               '"selection": "highernosat"}',
    "many": '{"ae_camera": "right", "blur": true, "crf": "srgb", "images": "truth", "init_exposure_us": 8000.0, '
            '"min_exposure_us": 50.0, "parity": "default", "seed": 7, "selection": "fusion", "warmup_steps": 3}',
    "upstream": '{"ae_camera": "left", "crf": "srgb", "init_exposure_us": 4000.0, "parity": "upstream", "seed": 0, '
                '"selection": "upstream"}',
}


def test_cache_keys_and_loop_json_are_the_ones_before_the_table() -> None:
    spec = TrajectorySpec("t1", Path("/nonexistent/t1"))
    orb = SlamOptions("orbslam3", "/v/voc.txt", "voc.txt:0123456789ab", "realtime", True, 2)
    half = MethodSpec("half", "ae_plugin_demo:HalfAE", (("target", 0.3),))
    drl = MethodSpec("drl", "drl", (("drl_weights", "/w/actor.pth"),))  # --drl-weights /w/actor.pth
    for name, doc in LOOPS.items():
        loop = LoopConfig.from_json(doc)
        assert json.dumps(loop.to_json(), sort_keys=True) == LOOP_JSON[name]
        for method in ("ae50", drl, half):
            for slam, repeat in ((None, 0), (orb, 1)):
                task = make_task(spec, method, Path("/out"), loop=loop, slam=slam, repeat=repeat)
                assert type(task).from_json(task.to_json()) == task
                label = method if isinstance(method, str) else method.name
                assert task.key == KEYS[(name, label, slam and slam.backend, repeat)], (name, label, repeat)
    lockstep = dataclasses.replace(orb, pace="lockstep")
    assert make_task(spec, "ae50", Path("/out"), slam=lockstep, repeat=1).key == KEYS["default", "ae50", "lockstep", 1]


def test_the_commands_agree_on_methods_pace_and_durations() -> None:
    from bracketry.cli import demo
    from bracketry.demo.pipeline import DemoPlan, plan
    from bracketry_emulator.ae.registry import parse_methods
    from bracketry_emulator.cli import benchmark, emulate

    for command in (emulate.command, benchmark.command, demo.command):
        opt = next(p for p in command.params if "--methods" in p.opts)
        assert {"--methods", "-m", "--method"} <= set(opt.opts), command.name  # --method: the old spelling
        help_text = " ".join((opt.help or "").split())
        assert all(w in help_text for w in ("'paper'", "'controls'", "oracle", "seven")), command.name
    paper = ["fix", "ae30", "ae50", "ae70", "shim", "wang", "kim"]
    assert parse_methods("paper", has_drl_weights=False) == parse_methods("ALL", has_drl_weights=False) == paper
    assert parse_methods("ae50,controls,oracle")[:2] == ["ae50", "oracle"]  # the group's oracle named once
    pace = option_table.setting("slam_pace")
    assert pace.spec(BENCHMARK)["default"] == pace.spec(option_table.DEMO)["default"] == "lockstep"
    assert DemoPlan(Path("x"), 1.0, (2, 2)).slam_pace == plan(Path("x"), None, True).slam_pace == "lockstep"
    duration = next(p for p in demo.command.params if "--duration-s" in p.opts)
    assert duration.type.convert("1m", duration, None) == 60.0  # units, as every --duration-s
