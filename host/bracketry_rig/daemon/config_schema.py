"""Declarative config tables: a frozen dataclass whose fields carry their own key spec.

Each field of a :func:`config_table` dataclass is declared once with :func:`setting` (a TOML key: its type comes
from the annotation; default, choices, range, extra check and help from the call) or :func:`table` (a nested TOML
table, or an array of tables). From that one declaration come the dataclass and its defaults, the checker
(:class:`Checker`: unknown keys, missing keys, types, choices and ranges, each a one-line problem naming the key) and
the documented example (:func:`example_toml`). Rules that span keys stay with the caller (``daemon/config.py``).
"""

from __future__ import annotations

import dataclasses
import json
import textwrap
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn, TypeVar, dataclass_transform

T = TypeVar("T")
_UnionType = type(int | None)
#: what is wrong with a value: None (nothing), the problem, or (where in the value, e.g. "[2]", the problem)
Problem = str | tuple[str, str] | None
WIDTH = 118  # the example's comment lines


@dataclass(frozen=True)
class Setting:
    """The spec of one key: what values it accepts and what it means."""

    help: str
    choices: tuple[Any, ...] = ()
    refused: str = ""  # the problem of a value outside ``choices`` ({value}); default "must be one of ..."
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    unit: str = ""  # printed after a range
    why: str = ""  # printed after a range, in parentheses
    check: Callable[[Any], Problem] | None = None  # a further rule: the problem, or None
    example: Any = None  # the example's value of a key whose value there is None (shown commented out)
    auto: str = ""  # the key's default is derived from other keys, as this says (shown commented out)

    def limits(self) -> str:
        """The range in words, e.g. ``within 2..5 Hz`` or ``> 0``; "" without one."""
        unit = f" {self.unit}" if self.unit else ""
        if self.min is not None and self.max is not None:
            return f"within {self.min:g}..{self.max:g}{unit}"
        if self.min is not None:
            return f"{'>' if self.min_open else '>='} {self.min:g}{unit}"
        if self.max is not None:
            return f"<= {self.max:g}{unit}"
        return ""

    def problem(self, value: Any) -> Problem:
        """What is wrong with a value of the right type, or None."""
        if self.choices and value not in self.choices:
            if self.refused:
                return self.refused.format(value=value)
            return f"must be one of {', '.join(map(str, self.choices))}, got {value!r}"
        low = self.min is not None and (value <= self.min if self.min_open else value < self.min)
        if low or (self.max is not None and value > self.max):
            why = f" ({self.why})" if self.why else ""
            return f"must be {self.limits()}{why}, got {value}"
        return self.check(value) if self.check else None


@dataclass(frozen=True)
class Table:
    """The spec of a nested table (``many``: an array of tables ``[[name]]``)."""

    help: str
    many: bool = False
    missing: str = ""  # the problem when absent; "" when the table is optional


def setting(*, default: Any = dataclasses.MISSING, help: str, **spec: Any) -> Any:
    """A key of the table: ``default`` (none: required) and the :class:`Setting` fields."""
    return field(default=default, metadata={"setting": Setting(help=help, **spec)})


def table(*, default: Any = dataclasses.MISSING, default_factory: Any = dataclasses.MISSING, help: str,
          many: bool = False, missing: str = "") -> Any:
    """A nested table (the field's type is its dataclass, a tuple of it when ``many``, or ``X | None``)."""
    return field(default=default, default_factory=default_factory,
                 metadata={"table": Table(help=help, many=many, missing=missing)})


@dataclass_transform(frozen_default=True, field_specifiers=(setting, table, field))
def config_table(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass whose :func:`setting` / :func:`table` fields are its TOML keys."""
    return dataclass(frozen=True)(cls)


@dataclass(frozen=True)
class Key:
    """One key of a config table, as declared."""

    name: str
    type: Any  # the annotation, ``X | None`` reduced to X
    spec: Setting | Table
    default: Any  # dataclasses.MISSING when required

    @property
    def required(self) -> bool:
        return self.default is dataclasses.MISSING

    @property
    def toml_types(self) -> tuple[type, ...]:
        """The TOML value types the key accepts."""
        origin = typing.get_origin(self.type)
        if origin is tuple or self.type is tuple:
            return (list,)
        return {float: (int, float), Path: (str,)}.get(self.type, (self.type,))

    def convert(self, value: Any) -> Any:
        """The checked TOML value as the field's type."""
        if self.type is float:
            return float(value)
        if self.type is Path:
            return Path(value).expanduser()
        if typing.get_origin(self.type) is tuple:
            item = typing.get_args(self.type)[0]
            return tuple(item(v) for v in value)
        return value


def keys(cls: type) -> list[Key]:
    """The declared keys of a :func:`config_table` class, in declaration order (fields without a spec skipped)."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        spec = f.metadata.get("setting") or f.metadata.get("table")
        if spec is None:
            continue
        tp = hints[f.name]
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if typing.get_origin(tp) in (typing.Union, _UnionType) and len(args) == 1:
            tp = args[0]
        if isinstance(spec, Table) and spec.many:
            tp = typing.get_args(tp)[0]
        default = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
        out.append(Key(f.name, tp, spec, default))
    return out


def settings(cls: type) -> list[Key]:
    return [k for k in keys(cls) if isinstance(k.spec, Setting)]


def tables(cls: type) -> list[Key]:
    return [k for k in keys(cls) if isinstance(k.spec, Table)]


class Checker:
    """Checks TOML tables against their class's keys; every problem is one ``ConfigError`` line naming the key."""

    def __init__(self, source: str, error: Callable[[str], Exception]) -> None:
        self.source = source
        self.error = error

    def fail(self, key: str, problem: str) -> NoReturn:
        raise self.error(f"{self.source}: {key}: {problem}")

    def settings(self, data: Any, where: str, cls: type) -> dict[str, Any]:
        """Check the table ``data`` (at ``where``) against the settings of ``cls``; returns the keys present,
        converted to the fields' types."""
        if not isinstance(data, dict):
            self.fail(where, f"must be a table, got {type(data).__name__}")
        spec = {k.name: k for k in settings(cls)}
        for name in data:
            if name not in spec:
                self.fail(f"{where}.{name}", f"unknown key (known: {', '.join(sorted(spec))})")
        out = {}
        for name, key in spec.items():
            if name not in data:
                if key.required:
                    self.fail(f"{where}.{name}", "missing (required)")
                continue
            value, types = data[name], key.toml_types
            if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
                names = " or ".join("number" if t is float else t.__name__ for t in types)
                self.fail(f"{where}.{name}", f"must be {names}, got {type(value).__name__} {value!r}")
            assert isinstance(key.spec, Setting)
            problem = key.spec.problem(value)
            if isinstance(problem, tuple):
                self.fail(f"{where}.{name}{problem[0]}", problem[1])
            if problem:
                self.fail(f"{where}.{name}", problem)
            out[name] = key.convert(value)
        return out

    def table(self, data: dict[str, Any], key: Key) -> Any:
        """The nested table ``key`` of the document ``data``, built as its class (its default when absent)."""
        spec = key.spec
        assert isinstance(spec, Table)
        if key.name not in data:
            if spec.missing:
                self.fail(key.name, spec.missing)
            return key.default
        raw = data[key.name]
        if not spec.many:
            return key.type(**self.settings(raw, key.name, key.type))
        if not isinstance(raw, list):
            self.fail(key.name, f"must be an array of tables [[{key.name}]]")
        return tuple(key.type(**self.settings(item, f"{key.name}[{i}]", key.type)) for i, item in enumerate(raw))


# -- the documented example ------------------------------------------------------------------------------------------

def toml_value(value: Any) -> str:
    """``value`` as a TOML literal (numbers without a needless ``.0``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return f"{value:g}" if isinstance(value, float) else str(value)
    if isinstance(value, tuple | list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return json.dumps(str(value))


def _comment(text: str) -> list[str]:
    return textwrap.wrap(text, WIDTH - 2, initial_indent="# ", subsequent_indent="# ", break_on_hyphens=False)


def _describe(key: Key) -> str:
    spec = key.spec
    assert isinstance(spec, Setting)
    facts = ["required" if key.required else
             f"default: {spec.auto}" if spec.auto else
             "default: none" if key.default is None else f"default {toml_value(key.default)}"]
    if spec.choices:
        facts.append(f"one of {', '.join(toml_value(c) for c in spec.choices)}")
    if spec.limits():
        facts.append(spec.limits())
    text = spec.help.rstrip(". ")
    return f"{text} ({'; '.join(facts)})."


def _settings_lines(config: Any, documented: bool) -> list[str]:
    lines = []
    for key in settings(type(config)):
        spec = key.spec
        assert isinstance(spec, Setting)
        value = getattr(config, key.name)
        if documented:
            lines += _comment(_describe(key))
        if spec.auto or value is None:
            lines.append(f"# {key.name} = {toml_value(value if value is not None else spec.example)}")
        else:
            lines.append(f"{key.name} = {toml_value(value)}")
    return lines


def example_toml(config: Any, header: tuple[str, ...], top: str, top_help: str) -> str:
    """The documented example: the ``header`` paragraphs, then ``config`` (a :func:`config_table` instance) as TOML:
    its settings in table ``[top]`` (described by ``top_help``), each key under its help (default, choices, range),
    then its nested tables (one that is None shown with its defaults)."""
    lines = [line for paragraph in header for line in _comment(paragraph)]
    lines += ["", *_comment(top_help), f"[{top}]"]
    lines += _settings_lines(config, True)
    for key in tables(type(config)):
        spec = key.spec
        assert isinstance(spec, Table)
        value = getattr(config, key.name)
        lines += ["", *_comment(spec.help)]
        items = value if spec.many else [value]
        for i, item in enumerate(items):
            if i:
                lines.append("")
            lines.append(f"[[{key.name}]]" if spec.many else f"[{key.name}]")
            lines += _settings_lines(item if item is not None else key.type(), i == 0)
    return "\n".join(lines) + "\n"
