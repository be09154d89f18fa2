"""The ``bracketry`` command line: one entry point, subcommand groups loaded lazily.

Each subcommand lives in its own module and exposes a click object named ``command``. The table below is the only
place that lists them; a module that is not (yet) in the tree is simply not offered. Loading is lazy so that
``bracketry --help`` stays fast and a rig without the ``emulator`` extra still runs its own commands.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from typing import Any

import click

from bracketry import __version__
from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_USAGE

#: name -> (module path, attribute, one-line help, extra needed)
COMMANDS: dict[str, tuple[str, str, str, str | None]] = {
    "doctor": ("bracketry.cli.doctor", "command", "Check the components the rig and tests need.", None),
    "wire": ("bracketry.cli.wire", "command", "Encode and decode frames of the serial wire protocol.", None),
    "trigger": ("bracketry.cli.trigger", "command", "STM32 trigger: talk to it, run it in QEMU, or simulate it.", None),
    "panel": ("bracketry.cli.panel", "command", "ESP32 status panel: simulate it or deploy its firmware.", None),
    "cameras": ("bracketry.cli.cameras", "command", "GigE cameras through Aravis: probe, configure, grab.", "host"),
    "record": ("bracketry.cli.record", "command", "Record for a fixed duration (no buttons).", "host"),
    "verify": ("bracketry.cli.verify", "command", "Check recordings: drops, pairing, bracket order, repair.", None),
    "export": ("bracketry.cli.export", "command", "Export a recording as a BorealHDR tree or a ROS 1 bag.", None),
    "daemon": ("bracketry.cli.daemon", "command", "Run the rig daemon (buttons, panel, cameras, recording).", "host"),
    "status": ("bracketry.cli.status", "command", "Ask the running daemon for its state.", None),
    "simulate": ("bracketry.cli.simulate", "command", "Run the whole rig here on simulated devices.", "host"),
    "devices": ("bracketry.cli.devices", "command", "List the rig's USB serial devices and write udev rules.", "host"),
    "hw": ("bracketry.cli.hw", "command", "Hardware calculators: power budget and GigE bandwidth.", None),
    "synth": ("bracketry_emulator.cli.synth", "command", "Render synthetic bracketed HDR stereo data.", "emulator"),
    "calibrate": ("bracketry.cli.calibrate", "command", "Calibrate the rig: stereo geometry (solve, capture), "
                  "response (crf).", None),
    "calibrate-crf": ("bracketry_emulator.cli.crf", "command", "Calibrate the camera response from a static stack "
                      "(hidden: the old spelling of 'calibrate crf').", "emulator"),
    "emulate": ("bracketry_emulator.cli.emulate", "command", "Emulate images at chosen exposures, run AE methods.",
                "emulator"),
    "accuracy": ("bracketry_emulator.cli.accuracy", "command", "Measure the emulator's accuracy.", "emulator"),
    "benchmark": ("bracketry_emulator.cli.benchmark", "command", "Benchmark AE methods: VO, metrics, statistics.",
                  "emulator"),
    "train": ("bracketry_emulator.cli.train", "command", "Train learned AE methods on emulated exposures (DRL).",
              "learn"),
    "slam": ("bracketry_emulator.cli.slam", "command", "SLAM backend tools: build an ORB-SLAM3 vocabulary.",
             "emulator"),
    "demo": ("bracketry.cli.demo", "command", "Run the whole pipeline on the embedded default.", None),
}


def _available(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


#: old names that still run but are not listed (``calibrate-crf`` is ``calibrate crf``)
HIDDEN_ALIASES = frozenset({"calibrate-crf"})


class LazyGroup(click.Group):
    """A click group whose subcommands are imported only when used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return [name for name, (mod, *_rest) in COMMANDS.items() if _available(mod) and name not in HIDDEN_ALIASES]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        entry = COMMANDS.get(cmd_name)
        if entry is None or not _available(entry[0]):
            return None
        mod_name, attr, help_text, extra = entry
        try:
            module = importlib.import_module(mod_name)
        except ImportError as exc:
            hint = f" (install the extra: pip install -e '.[{extra}]')" if extra else ""
            missing = getattr(exc, "name", None) or str(exc)
            return _broken_command(cmd_name, help_text, f"'{cmd_name}' needs the Python module {missing}{hint}")
        cmd = getattr(module, attr)
        return cmd

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][2]) for name in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def _broken_command(name: str, help_text: str, message: str) -> click.Command:
    def run(**_kwargs: Any) -> None:
        raise BracketryError(message)

    return click.Command(name, callback=run, help=help_text + "\n\nUnavailable: " + message,
                         context_settings={"ignore_unknown_options": True, "allow_extra_args": True})


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", "-V", prog_name="bracketry")
def cli() -> None:
    """bracketry: record exposure-bracketed stereo images and benchmark auto-exposure methods on them.

    The rig side (firmware, host daemon) records; the offline side emulates any exposure from the brackets and
    compares AE methods in closed loop. Run `bracketry doctor` to check this machine.

    \b
    Exit codes of every command:
      0  ok
      1  the command ran and found problems / goals not met
      2  usage or input error (one line on stderr; nothing written)
      3  internal error (a bug)
    """


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning BracketryError (and any other failure) into one line on stderr."""
    debug = os.environ.get("BRACKETRY_DEBUG") == "1"
    # bad input is reported by us in one line: keep OpenCV's own log lines (e.g. a broken PNG header) quiet
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT" if not debug else "INFO")
    try:
        rv = cli.main(args=argv, prog_name="bracketry", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return EXIT_INTERRUPTED
    except click.UsageError as exc:  # bad option value, refused output path, unknown command: one line
        hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
        message = " ".join(exc.format_message().split())
        click.echo(f"error: {message}{hint}", err=True)
        return EXIT_USAGE
    except click.ClickException as exc:
        click.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return int(exc.exit_code or 0)
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return EXIT_INTERRUPTED
    except BracketryError as exc:
        if debug:
            raise
        click.echo(f"error: {' '.join(str(exc).split()) or type(exc).__name__}", err=True)
        return exc.exit_code
    except BrokenPipeError:
        return 0
    except Exception as exc:  # last resort: one line, never a traceback unless BRACKETRY_DEBUG=1
        if debug:
            raise
        detail = " ".join(str(exc).split())[:300]
        click.echo(f"error: internal error: {type(exc).__name__}: {detail} (a bug; BRACKETRY_DEBUG=1 shows the "
                   "traceback)", err=True)
        return EXIT_INTERNAL
    # A command may return an int exit code (EXIT_PROBLEMS when it ran and found problems).
    return rv if isinstance(rv, int) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
