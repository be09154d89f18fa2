"""The CLI skeleton: --version, --help, doctor, one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

import bracketry
from bracketry.cli import COMMANDS, HIDDEN_ALIASES, main
from bracketry_base.errors import BracketryError


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bracketry", *args], capture_output=True, text=True, timeout=120)


def test_version_prints_package_version() -> None:
    out = run_cli("--version")
    assert out.returncode == 0
    assert bracketry.__version__ in out.stdout


def test_help_lists_doctor_and_only_existing_commands() -> None:
    out = run_cli("--help")
    assert out.returncode == 0
    assert "doctor" in out.stdout
    import importlib.util

    names = [line.split()[0] for line in out.stdout.split("Commands:")[1].splitlines() if line.startswith("  ")
             and not line.startswith("   ")]
    for name, (module, *_rest) in COMMANDS.items():
        listed = name in names
        assert listed == (importlib.util.find_spec(module) is not None and name not in HIDDEN_ALIASES), name
    assert "calibrate-crf" not in out.stdout and "calibrate" in names  # the old spelling runs, unlisted
    assert run_cli("calibrate-crf", "--help").returncode == 0


def test_unknown_command_is_a_usage_error_without_traceback() -> None:
    out = run_cli("no-such-command")
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    assert "No such command" in out.stderr


def test_doctor_json_reports_every_component(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["doctor", "--json"])
    checks = json.loads(capsys.readouterr().out)
    names = {c["name"] for c in checks}
    assert {"Aravis typelib 0.8", "arm-none-eabi-gcc", "qemu-system-arm netduinoplus2", "socat",
            "MicroPython WebAssembly", "PyGObject", "BorealHDR sample data"} <= names
    for c in checks:
        assert c["ok"] or c["fix"], c
    assert rc == (0 if all(c["ok"] for c in checks) else 1)


def test_doctor_fails_with_fix_when_sample_missing(monkeypatch: pytest.MonkeyPatch, tmp_path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from bracketry_base import paths

    monkeypatch.setattr(paths, "repo_root", lambda: tmp_path / "nowhere" / "repo")
    monkeypatch.setenv(paths.SAMPLE_ENV, str(tmp_path / "empty"))
    monkeypatch.setenv(paths.MPY_ENV, str(tmp_path / "no-mpy"))
    rc = main(["doctor"])
    out = capsys.readouterr().out
    assert rc == 1
    assert "MISSING  BorealHDR sample data" in out
    assert "MISSING  MicroPython WebAssembly" in out


def test_bracketry_error_becomes_one_line(monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    import click

    from bracketry import cli as cli_mod

    @click.command("boom")
    def boom() -> None:
        raise BracketryError("the thing is wrong", exit_code=3)

    monkeypatch.setitem(cli_mod.COMMANDS, "boom", ("bracketry.cli.doctor", "command", "x", None))
    monkeypatch.setattr(cli_mod.LazyGroup, "get_command", lambda self, ctx, name: boom)
    rc = main(["boom"])
    err = capsys.readouterr().err
    assert rc == 3
    assert err.strip() == "error: the thing is wrong"
