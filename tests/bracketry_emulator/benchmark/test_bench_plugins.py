"""AE plugins through every command that takes methods, as a researcher runs them: an import-path plugin (a module on
PYTHONPATH) and an entry-point plugin (a tiny package pip-installed into a test-local folder), each named by its
``name`` in folders, CSV rows, statistics and the report; their options from the command line and a YAML file, in
the cache key; bad names and options refused in one line before any work."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from ae_plugin_kit import bracketry, entry_point_plugin, env_with, import_path_plugin
from bracketry.cli import main as cli_main
from bracketry_base.errors import BracketryError
from bracketry_emulator.ae.registry import MethodSpec, parse_method_options, resolve_methods
from bracketry_emulator.benchmark import make_task
from bracketry_emulator.metrics.manifest import expand_datasets


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("plugin_world") / "walk"
    assert cli_main(["synth", "trajectory", "--out", str(d), "--seconds", "4", "--resolution", "320x200", "-q"]) == 0
    return d


@pytest.fixture(scope="module")
def plugins(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    root = tmp_path_factory.mktemp("plugins")
    mod_dir, mod_id = import_path_plugin(root / "mod")
    site, ep_id = entry_point_plugin(root / "ep")
    return {"env": env_with(mod_dir, site), "mod": mod_id, "ep": ep_id, "paths": (mod_dir, site)}


@pytest.fixture()
def on_path(plugins: dict, monkeypatch: pytest.MonkeyPatch):
    import sys

    for p in plugins["paths"]:
        monkeypatch.syspath_prepend(str(p))
    yield plugins
    for name in ("ae_kit_mod", "ae_kit_ep"):
        sys.modules.pop(name, None)


def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# -- names and options, in-process ----------------------------------------------------------------------------------

def test_names_options_and_keys(on_path: dict, world: Path) -> None:
    specs = resolve_methods(["ae50", "constant-8", on_path["mod"], on_path["ep"]],
                            {"brighter": {"target": 0.3}, on_path["ep"]: {"target": 0.2}})
    assert [s.name for s in specs] == ["ae50", "constant-8", "brighter", "darker"]
    assert specs[2] == MethodSpec("brighter", "ae_kit_mod:Brighter", (("target", 0.3),))
    assert specs[3].source == "ae-kit-ep" and specs[3].kwargs == {"target": 0.2}
    assert specs[0].plain and not specs[2].plain
    # the YAML file, then NAME.key=value on top, values parsed as YAML scalars
    yml = world.parent / "opts.yaml"
    yml.write_text("brighter: {target: 0.3, label: x}\n")
    assert parse_method_options(["brighter.target=0.5", "constant-0.5.flag=true"], yml) == {
        "brighter": {"target": 0.5, "label": "x"}, "constant-0.5": {"flag": True}}
    # built-ins keep their key (and so their cache files); a plugin's source and options are in its key
    spec = expand_datasets([world])[0]
    builtin = make_task(spec, "ae50", world.parent / "b")
    assert "plugin" not in builtin.to_json_keyed() and builtin.method_spec.plain
    assert make_task(spec, MethodSpec("ae50", "ae50"), world.parent / "b").key == builtin.key
    k3 = make_task(spec, specs[2], world.parent / "b")
    k5 = make_task(spec, MethodSpec("brighter", "ae_kit_mod:Brighter", (("target", 0.5),)), world.parent / "b")
    assert k3.key != k5.key and k3.to_json_keyed()["plugin"] == {"source": "ae_kit_mod:Brighter",
                                                                 "options": {"target": 0.3}}
    assert type(k3).from_json(k3.to_json()) == k3


@pytest.mark.parametrize(("methods", "options", "words"), [
    ("ae50,ae_kit_mod:Brighter,ae_kit_ep:Brighter", {}, "two AE methods are named 'brighter'"),
    ("ae50,ae_kit_mod:Brighter", {"nope": {"x": 1}}, "not run: nope"),
    ("ae50,ae_kit_mod:Brighter", {"brighter": {"gain": 1}}, "cannot be created with options gain=1"),
    ("ae50", {"ae50": {"x": 1}}, "built-in method ae50"),
])
def test_bad_names_and_options_are_refused(on_path: dict, methods: str, options: dict, words: str) -> None:
    with pytest.raises(BracketryError, match=words):
        resolve_methods(methods.split(","), options)


def test_unsafe_and_builtin_names_are_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "ae_kit_bad.py").write_text(
        "class Slash:\n    name = 'a/b'\n    def reset(self, e): pass\n"
        "    def next_exposure_us(self, i, e, m): return e\n"
        "class Colon(Slash):\n    name = 'x:y'\nclass Shadow(Slash):\n    name = 'ae50'\nclass Rep(Slash):\n"
        "    name = 'mine.r2'\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for cls, words in (("Slash", "safe|folder"), ("Colon", "folder"), ("Shadow", "built-in"), ("Rep", "r<n>")):
        with pytest.raises(BracketryError, match=words):
            resolve_methods([f"ae_kit_bad:{cls}"])


@pytest.mark.parametrize("command", ["emulate", "benchmark"])
@pytest.mark.parametrize(("extra", "words"), [
    (["--methods", "ae50,ae_kit_mod:Brighter,ae_kit_ep:Brighter"], "two AE methods are named 'brighter'"),
    (["--methods", "ae50,ae_kit_mod:Brighter", "--method-option", "nope.x=1"], "not run: nope"),
    (["--methods", "ae50,ae_kit_mod:Brighter", "--method-option", "brighter.gain=2"], "rejects|cannot be created"),
    (["--methods", "ae50", "--method-option", "ae50x=1"], "bad --method-option"),
])
def test_cli_refuses_bad_plugin_input_before_any_work(on_path: dict, world: Path, tmp_path: Path, capsys,
                                                      command: str, extra: list[str], words: str) -> None:
    out = tmp_path / "out"
    argv = [command, str(world), "--out", str(out), *extra]
    assert cli_main([*argv, "--slam", "builtin"] if command == "benchmark" else argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error:"), err
    import re

    assert re.search(words, err), err
    assert not out.exists() or not any(out.iterdir())


# -- end to end, in child processes as a user runs them ---------------------------------------------------------------

def test_emulate_names_plugin_outputs(plugins: dict, world: Path, tmp_path: Path) -> None:
    opts = tmp_path / "opts.yaml"
    opts.write_text("darker: {target: 0.2}\n")
    res = bracketry(["emulate", str(world), "-m", f"ae50,{plugins['mod']},{plugins['ep']}", "--method-option",
                     "brighter.target=0.5", "--method-options", str(opts), "-o", str(tmp_path / "e"), "-q",
                     "--no-images", "--max-sequences", "4", "-j", "1"], plugins["env"])
    assert res.returncode == 0, res.stderr
    e = tmp_path / "e"
    summary = json.loads((e / "summary.json").read_text())
    assert list(summary["methods"]) == ["ae50", "brighter", "darker"]
    assert summary["plugins"] == {"brighter": {"source": "ae_kit_mod:Brighter", "options": {"target": 0.5}},
                                  "darker": {"source": "ae-kit-ep", "options": {"target": 0.2}}}
    assert (e / "exposures.csv").read_text().splitlines()[0] == "step,timestamp_ns,ae50_ms,brighter_ms,darker_ms"
    assert all((e / m / "ae.csv").is_file() for m in ("ae50", "brighter", "darker"))
    assert "plugin brighter: ae_kit_mod:Brighter, target=0.5" in res.stdout


@pytest.mark.slow
def test_benchmark_plugins_to_statistics_and_cache(plugins: dict, world: Path, tmp_path: Path) -> None:
    out = tmp_path / "b"
    argv = ["benchmark", str(world), "--methods", f"ae50,{plugins['mod']},{plugins['ep']}", "--slam", "builtin",
            "--stats-methods", "all", "--windows", "1,2", "--workers", "1", "-q", "--out", str(out),
            "--method-option", "brighter.target=0.5"]
    res = bracketry(argv, plugins["env"])
    assert res.returncode == 0, res.stderr
    rep = out / "report"
    verdicts = _csv(rep / "verdicts.csv")
    assert list(verdicts[0]) == ["metric", "brighter", "darker"]
    assert {r["method"] for r in _csv(rep / "results.csv")} == {"ae50", "brighter", "darker"}
    md = (rep / "report.md").read_text()
    assert "brighter: ae_kit_mod:Brighter, target=0.5" in md and "darker: ae-kit-ep" in md
    assert "Reported but not in the statistics" not in md
    assert sorted(p.name for p in (out / "runs" / "walk").iterdir() if p.is_dir()) == ["ae50", "brighter", "darker"]
    assert sorted(p.name for p in (out / "cache" / "walk").iterdir()) == ["ae50.json", "brighter.json",
                                                                           "darker.json"]
    # unchanged: every run from the cache (a full --out is continued only when asked)
    assert bracketry(argv, plugins["env"]).returncode == 2
    argv.append("--resume")
    again = bracketry(argv, plugins["env"])
    assert again.returncode == 0, again.stderr
    assert sorted(line.split()[0] for line in again.stdout.splitlines() if " / " in line) == ["cached"] * 3
    # a changed option reruns that method only
    changed = bracketry([*argv[:-2], "brighter.target=0.3", "--resume"], plugins["env"])
    assert changed.returncode == 0, changed.stderr
    states = {line.split()[3].rstrip(":"): line.split()[0] for line in changed.stdout.splitlines() if " / " in line}
    assert states == {"ae50": "cached", "brighter": "done", "darker": "cached"}, changed.stdout
    assert "brighter: ae_kit_mod:Brighter, target=0.3" in (rep / "report.md").read_text()
