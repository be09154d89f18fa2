"""The CLI's one place for checking input before any work: exit codes, number types, output paths, shared options.

Every subcommand of ``bracketry`` (both packages) declares its options with these types, so that

- numbers are range-checked by click while parsing (finite, positive where they must be), never deep in the work;
- output paths are checked before any work: an existing file (or a non-empty folder) is refused unless
  ``--overwrite`` is given, a missing parent folder is an error (never created), an unwritable place is an error, a
  file where a folder is expected (and the reverse) is an error;
- the exit codes are the ones below, and internal errors never share a code with results.

A failed check is a click usage error: one line on stderr (``error: ...``) and exit code 2 (see ``bracketry.cli.main``).
CONTRIBUTING.md ("CLI") documents the rule and the option vocabulary.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from bracketry_base.errors import BracketryError
from bracketry_base.ipv4 import unicast_ipv4
from bracketry_base.outputs import Existing, Kind, check_output

#: Exit codes of every command (documented once, in CONTRIBUTING.md and ``bracketry --help``).
EXIT_OK = 0  #: success
EXIT_PROBLEMS = 1  #: the command ran and found problems / goals not met (verify, accuracy static, doctor, ...)
EXIT_USAGE = 2  #: usage or input error: bad option value, unreadable input, refused output path
EXIT_INTERNAL = 3  #: internal error (a bug): never a result
EXIT_INTERRUPTED = 130  #: Ctrl-C

F = TypeVar("F", bound=Callable[..., Any])


class Number(click.FloatRange):
    """A finite float within [min, max] (either bound optional, each open or closed); nan and inf are refused.

    A click FloatRange (so ``--help`` shows the range) that also refuses non-finite values, which FloatRange accepts
    (``nan`` compares false with every bound, ``inf`` passes an open upper bound).
    """

    name = "number"

    def __init__(self, min: float | None = None, max: float | None = None, *, min_open: bool = False,
                 max_open: bool = False) -> None:
        super().__init__(min, max, min_open=min_open, max_open=max_open)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            v = float(value)
        else:
            try:
                v = float(str(value).strip())
            except ValueError:
                self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return super().convert(v, param, ctx)

    def __repr__(self) -> str:
        return f"Number({self._describe_range()})"


class Integer(click.IntRange):
    """An integer within [min, max] (click's IntRange; a float such as 1e308 or a word is refused)."""

    name = "integer"


def positive(max: float | None = None) -> Number:
    """A finite number > 0 (and <= ``max``)."""
    return Number(0.0, max, min_open=True)


def non_negative(max: float | None = None) -> Number:
    """A finite number >= 0 (and <= ``max``)."""
    return Number(0.0, max)


def finite(min: float | None = None, max: float | None = None) -> Number:
    """Any finite number (within the optional bounds)."""
    return Number(min, max)


def count(min: int = 1, max: int | None = None) -> Integer:
    """An integer >= ``min`` (default 1)."""
    return Integer(min, max)


#: ``--workers N``: parallel workers, 0 = one per CPU, 1 = in this process.
WORKERS = Integer(0, 256)
#: Seeds of random generators.
SEED = Integer(0, 2**32 - 1)

_DURATION = re.compile(r"(\d+(?:\.\d*)?|\.\d+)([hms]?)")
#: The longest duration any command accepts (a week): beyond it a value is a typo, not a plan.
MAX_DURATION_S = 7 * 24 * 3600.0


class Duration(click.ParamType):
    """Seconds: ``30``, ``2.5``, ``30s``, ``2m``, ``1h`` or ``1m30s`` -> float seconds, > 0, >= ``min_s`` and
    <= ``max_s``."""

    name = "duration"

    def __init__(self, max_s: float = MAX_DURATION_S, min_s: float = 0.0) -> None:
        self.max_s = max_s
        self.min_s = min_s

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            total = float(value)
        else:
            text = str(value).strip()
            total, pos = 0.0, 0
            for m in _DURATION.finditer(text):
                if m.start() != pos:
                    break
                total += float(m.group(1)) * {"h": 3600, "m": 60, "s": 1, "": 1}[m.group(2)]
                pos = m.end()
            if pos != len(text) or not text:
                self.fail(f"{value!r}: expected seconds or e.g. 30s, 2m, 1h, 1m30s", param, ctx)
        if not math.isfinite(total) or total <= 0:
            self.fail(f"{value!r}: must be more than 0 s", param, ctx)
        if total < self.min_s:
            self.fail(f"{value!r}: at least {self.min_s:g} s", param, ctx)
        if total > self.max_s:
            self.fail(f"{value!r}: at most {self.max_s:g} s", param, ctx)
        return total


#: the camera resolutions any command or scenario takes, per side, in pixels
MIN_RESOLUTION_PX, MAX_RESOLUTION_PX = 16, 8192


def parse_resolution(text: str, what: str = "--resolution") -> tuple[int, int]:
    """``WIDTHxHEIGHT`` (e.g. ``640x400``) -> (width, height) in pixels, both even and within
    :data:`MIN_RESOLUTION_PX`..:data:`MAX_RESOLUTION_PX`; anything else: one-line BracketryError naming ``what``."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError:
        raise BracketryError(f"{what} {text!r}: expected WIDTHxHEIGHT, e.g. 640x400") from None
    lo, hi = MIN_RESOLUTION_PX, MAX_RESOLUTION_PX
    if not (lo <= w <= hi and lo <= h <= hi) or w % 2 or h % 2:
        raise BracketryError(f"{what} {text!r}: width and height must be even and within {lo}..{hi}")
    return w, h


_MEMORY = re.compile(r"(\d+(?:\.\d*)?)\s*([KMGT]i?B)", re.IGNORECASE)


class MemorySize(click.ParamType):
    """A memory size with its unit: ``500MB``, ``8GB``, ``16GiB`` (K/M/G/T, B or iB) -> the text as given, stripped
    (the form dask and Slurm read), > 0."""

    name = "size"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        text = str(value).strip()
        m = _MEMORY.fullmatch(text)
        if m is None:
            self.fail(f"{value!r}: expected a size with its unit, e.g. 500MB, 8GB, 16GiB", param, ctx)
        if float(m.group(1)) <= 0:
            self.fail(f"{value!r}: must be more than 0", param, ctx)
        return text


class IPv4(click.ParamType):
    """A dotted IPv4 address (cameras are opened by IP only: a name would be resolved by discovery broadcast)."""

    name = "ipv4"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        try:
            return str(unicast_ipv4(str(value)))
        except BracketryError as exc:
            self.fail(str(exc), param, ctx)


class OutputPath(click.ParamType):
    """An output file or folder, checked with :func:`check_output` while parsing, before the command runs.

    ``--overwrite`` (declared with :func:`overwrite_option`, which is eager) is read from the context, so the order of
    the options on the command line does not matter. ``dash_stdout``: ``-`` means standard output (no check).
    ``resumable``: a non-empty folder is also fine with ``--resume`` (:func:`resume_option`, eager too).
    """

    name = "path"

    def __init__(self, kind: Kind = "file", *, existing: Existing = "refuse", suffixes: tuple[str, ...] = (),
                 dash_stdout: bool = False, resumable: bool = False) -> None:
        self.kind, self.existing, self.suffixes, self.dash_stdout = kind, existing, suffixes, dash_stdout
        self.resumable = resumable

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Path:
        if isinstance(value, Path):
            path = value
        else:
            path = Path(os.fsdecode(value)) if isinstance(value, bytes) else Path(str(value))
        if self.dash_stdout and str(path) == "-":
            return path
        overwrite = bool(ctx is not None and ctx.params.get("overwrite"))
        resume = self.resumable and bool(ctx is not None and ctx.params.get("resume"))
        if resume and overwrite:
            self.fail("--resume and --overwrite exclude each other (continue what the folder holds, or replace it)",
                      param, ctx)
        what = param.opts[0] if param is not None and param.opts else "output"
        try:
            return check_output(path, self.kind, overwrite=overwrite, existing="resume" if resume else self.existing,
                                suffixes=self.suffixes, what=what)
        except BracketryError as exc:
            message = str(exc).removeprefix(f"{what} ")
            if self.resumable:
                message = message.replace("(add --overwrite to write into it)",
                                          "(add --resume to continue what it holds, or --overwrite to replace it)")
            self.fail(message, param, ctx)


def output_file(*, existing: Existing = "refuse", suffixes: tuple[str, ...] = (),
                dash_stdout: bool = False) -> OutputPath:
    """The type of an option that names a file to write."""
    return OutputPath("file", existing=existing, suffixes=suffixes, dash_stdout=dash_stdout)


def output_dir(*, existing: Existing = "refuse", resumable: bool = False) -> OutputPath:
    """The type of an option that names a folder to write into (``resumable``: a non-empty one with ``--resume``)."""
    return OutputPath("dir", existing=existing, resumable=resumable)


def input_file() -> click.Path:
    """An existing, readable file."""
    return click.Path(exists=True, dir_okay=False, readable=True, path_type=Path)


def input_dir() -> click.Path:
    """An existing folder."""
    return click.Path(exists=True, file_okay=False, path_type=Path)


def input_path() -> click.Path:
    """An existing file or folder."""
    return click.Path(exists=True, path_type=Path)


class AliasedOption(click.Option):
    """A click option whose old spellings (``aliases``) still work but are not shown in ``--help``."""

    def __init__(self, *args: Any, aliases: tuple[str, ...] = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.aliases = set(aliases)

    def get_help_record(self, ctx: click.Context) -> tuple[str, str] | None:
        saved = self.opts
        self.opts = [o for o in saved if o not in self.aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = saved

    def get_error_hint(self, ctx: click.Context | None) -> str:
        return " / ".join(f"'{o}'" for o in self.opts if o not in self.aliases)


def option(*decls: str, aliases: tuple[str, ...] = (), **kwargs: Any) -> Callable[[F], F]:
    """``click.option`` with hidden old spellings: ``option("--timeout-s", "timeout_s", aliases=("--timeout",))``."""
    return click.option(*decls, *aliases, cls=AliasedOption, aliases=aliases, **kwargs)


def overwrite_option(help: str = "Replace existing output files (and write into a non-empty output folder).",
                     ) -> Callable[[F], F]:
    """``--overwrite`` (eager, so the output types see it whatever the order; old spelling ``--force`` hidden)."""
    return option("--overwrite", "overwrite", aliases=("--force",), is_flag=True, is_eager=True, help=help)


def resume_option(help: str = "Continue in a non-empty output folder, reusing what it holds.") -> Callable[[F], F]:
    """``--resume`` (eager, so the output types see it whatever the order; see ``output_dir(resumable=True)``)."""
    return click.option("--resume", "resume", is_flag=True, is_eager=True, help=help)


def quiet_option(help: str = "No progress bar.") -> Callable[[F], F]:
    """``--quiet/-q`` (old spelling ``--no-progress`` hidden)."""
    return option("--quiet", "-q", "quiet", aliases=("--no-progress",), is_flag=True, help=help)


def method_options_options() -> Callable[[F], F]:
    """``--method-option NAME.key=value`` (repeatable; the value a YAML scalar) and ``--method-options FILE`` (YAML
    ``{name: {key: value}}``): keyword arguments of AE plugins' constructors, for every command that takes methods
    (parsed by ``bracketry_emulator.ae.parse_method_options``, checked before any work)."""
    def decorate(f: F) -> F:
        f = click.option("--method-options", "method_options", type=input_file(), default=None,
                         help="YAML file of AE plugins' options: {name: {key: value}} (a method's name or its id as "
                              "given in --methods); --method-option wins over it.")(f)
        return click.option("--method-option", "method_option", multiple=True, metavar="NAME.KEY=VALUE",
                            help="An AE plugin's constructor argument (repeatable), the value read as YAML "
                                 "(0.3, true, text), e.g. median40.target=0.3. Part of the cache key; printed "
                                 "in the report.")(f)
    return decorate
