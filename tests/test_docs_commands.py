"""Every ``bracketry`` command shown in a fenced code block of a Markdown file of the repository is a real command.

A line of a fenced block (info string empty or one of :data:`SHELL_LANGUAGES`; other blocks, e.g. ``text`` for a
command's output, are not read) whose command starts with ``bracketry `` or ``.venv/bin/bracketry `` (after an
optional ``$ `` prompt, ``sudo`` and ``VAR=value`` assignments) is checked against the live click tree that
``bracketry.cli`` builds, subcommands resolved through its own lazy lookup (``get_command``):

- each word up to the leaf command names a real subcommand;
- each option is one of the leaf command's options (``--name=value`` too) and gets its value;
- a value of a ``click.Choice`` option is one of its choices (placeholders in capitals or ``<...>`` are not checked);
- the required options and the required arguments are given.

A line continued with ``\\`` is joined with the next one; ``#`` starts a comment; the command ends at the first shell
operator (``|``, ``&&``, ``;``, ``>``, ...). ``[...]`` marks optional words in a synopsis: the brackets are dropped and
what they hold is checked. ``...`` stands for more arguments. A failure names the file, the line and what is wrong.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass

import click

from bracketry.cli import cli
from bracketry_base.paths import repo_root
from bracketry_testkit import tracked_markdown_files

#: info strings of the fenced blocks whose lines are commands ("" = no info string)
SHELL_LANGUAGES = {"", "sh", "bash", "shell", "console", "zsh"}
#: words that end the command on a line
SHELL_OPERATORS = {"|", "||", "&", "&&", ";", ">", ">>", "<", "2>", "2>&1", "&>", "|&"}
_FENCE = re.compile(r"^\s*(```+|~~~+)\s*([^\s`]*)")
_PROGRAM = re.compile(r"^(?:\./|\.venv/bin/|/\S+/)?bracketry$")
_ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")


@dataclass(frozen=True)
class DocCommand:
    """One command of a document: where it is (1-based line of its first physical line) and its words after
    the program name."""

    path: str
    line: int
    words: tuple[str, ...]




def _words(text: str) -> list[str] | None:
    """The shell words of a command line, up to a comment or a shell operator (None when it does not parse)."""
    lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    lexer.commenters = "#"
    try:
        words = list(lexer)
    except ValueError:
        return None
    kept: list[str] = []
    for w in words:
        if w in SHELL_OPERATORS or (w and set(w) <= set("|&;<>")):
            break
        kept.append(w)
    return kept


def commands_in(text: str, path: str) -> list[DocCommand]:
    """The ``bracketry`` commands of the fenced shell blocks of one Markdown text."""
    found: list[DocCommand] = []
    fence: str | None = None
    checked = False
    pending: list[str] = []
    start = 0
    for number, raw in enumerate(text.splitlines(), start=1):
        m = _FENCE.match(raw)
        if fence is None:
            if m:
                fence, checked = m.group(1), m.group(2).lower() in SHELL_LANGUAGES
            continue
        if m and m.group(1).startswith(fence) and not m.group(2):
            fence, pending = None, []
            continue
        if not checked:
            continue
        if not pending:
            start = number
        line = raw.rstrip()
        if line.endswith("\\"):
            pending.append(line[:-1])
            continue
        pending.append(line)
        joined, pending = " ".join(pending), []
        words = _words(joined.strip().removeprefix("$ "))
        if not words:
            continue
        while words and (words[0] == "sudo" or _ASSIGNMENT.match(words[0])):
            words = words[1:]
        if words and _PROGRAM.match(words[0]):
            found.append(DocCommand(path, start, tuple(words[1:])))
    return found


def _optional_marks_dropped(words: tuple[str, ...]) -> list[str]:
    out = []
    for w in words:
        w = w.strip("[]") if w.startswith("[") or w.endswith("]") else w
        if w and w != "|":
            out.append(w)
    return out


def _is_placeholder(value: str) -> bool:
    return value.isupper() or "<" in value or "$" in value or value == "..."


def _takes_value(param: click.Option) -> bool:
    return not (param.is_flag or param.count)


def problems_of(words: tuple[str, ...]) -> list[str]:
    """What is wrong with ``bracketry WORDS`` against the live command tree (empty: nothing)."""
    args = _optional_marks_dropped(words)
    ctx = click.Context(cli, info_name="bracketry")
    command: click.Command = cli
    path = "bracketry"
    while isinstance(command, click.Group):
        if not args:
            return [f"'{path}' names no subcommand"]
        word = args.pop(0)
        if word in ("--help", "-h", "--version", "-V"):
            return []
        sub = command.get_command(ctx, word)
        if sub is None:
            return [f"'{path}' has no subcommand '{word}' (it has: {', '.join(command.list_commands(ctx))})"]
        if "Unavailable:" in (sub.help or ""):
            return [f"'{path} {word}' cannot be loaded here: {sub.help}"]
        ctx = click.Context(sub, info_name=word, parent=ctx)
        command, path = sub, f"{path} {word}"
    return _leaf_problems(command, path, args)


def _leaf_problems(command: click.Command, path: str, args: list[str]) -> list[str]:
    by_name: dict[str, click.Option] = {}
    for p in command.params:
        if isinstance(p, click.Option):
            for name in (*p.opts, *p.secondary_opts):
                by_name[name] = p
    problems: list[str] = []
    seen: set[str] = set()
    positionals: list[str] = []
    only_positionals = False
    i = 0
    while i < len(args):
        word = args[i]
        i += 1
        if only_positionals or not word.startswith("-") or word == "-" or re.fullmatch(r"-\d[\d.e]*", word):
            if word != "...":
                positionals.append(word)
            continue
        if word == "--":
            only_positionals = True
            continue
        name, eq, inline = word.partition("=")
        if name in ("--help", "-h"):
            return []
        opt = by_name.get(name)
        if opt is None:
            problems.append(f"'{path}' has no option '{name}'")
            if not eq and i < len(args) and not args[i].startswith("-"):
                i += 1  # its value, most likely: not counted as an argument
            continue
        seen.add(opt.name or name)
        if not _takes_value(opt):
            if eq:
                problems.append(f"'{path} {name}' is a flag and takes no value")
            continue
        needed = max(opt.nargs, 1)
        values = [inline] if eq else []
        while len(values) < needed and i < len(args) and (not args[i].startswith("-") or
                                                          re.fullmatch(r"-\d[\d.e]*", args[i])):
            values.append(args[i])
            i += 1
        if len(values) < needed:
            problems.append(f"'{path} {name}' needs a value")
            continue
        if isinstance(opt.type, click.Choice):
            for v in values:
                if not _is_placeholder(v) and v not in opt.type.choices:
                    problems.append(f"'{path} {name} {v}': not one of {', '.join(map(str, opt.type.choices))}")
    for p in command.params:
        if isinstance(p, click.Option) and p.required and (p.name not in seen):
            problems.append(f"'{path}' needs its required option '{p.opts[0]}'")
    arguments = [p for p in command.params if isinstance(p, click.Argument)]
    needed_args = sum(max(p.nargs, 1) if p.required else 0 for p in arguments)
    unlimited = any(p.nargs == -1 for p in arguments)
    most = sum(max(p.nargs, 0) for p in arguments)
    given = len(positionals) + (1 if "..." in args and unlimited else 0)
    if given < needed_args:
        names = " ".join(p.human_readable_name for p in arguments if p.required)
        problems.append(f"'{path}' needs its argument(s) {names} ({given} given)")
    elif not unlimited and len(positionals) > most:
        problems.append(f"'{path}' takes {most} argument(s), {len(positionals)} given: {' '.join(positionals)}")
    return problems


def _all_commands() -> list[DocCommand]:
    root = repo_root()
    found = []
    for f in tracked_markdown_files(root):
        found += commands_in(f.read_text(encoding="utf-8"), str(f.relative_to(root)))
    return found


def test_every_documented_command_is_real() -> None:
    commands = _all_commands()
    assert len(commands) >= 10, "the scan found almost no commands: the scanner is broken"
    bad = [f"{c.path}:{c.line}: {p}  [bracketry {' '.join(c.words)}]" for c in commands for p in problems_of(c.words)]
    assert not bad, "documented commands that do not run:\n" + "\n".join(bad)


# the checker itself: each kind of mistake is found, and a correct command passes

SAMPLE = """\
Intro.

```sh
bracketry demo --quick --out demo-out      # fine
bracketry benchmark SUITE/manifest.yaml --methods all --out b \\
    --slam builtin --no-such-option 3
.venv/bin/bracketry nosuch thing
$ sudo bracketry hw bandwidth --fps
PYTHONPATH=. bracketry emulate DATASET --slam-pace realtime --out runs/ | tail
bracketry calibrate solve --out cal
```

```text
bracketry demo: 450 + 450 frames recorded
```
"""


def test_the_checker_finds_each_kind_of_mistake() -> None:
    commands = commands_in(SAMPLE, "SAMPLE.md")
    assert [c.line for c in commands] == [4, 5, 7, 8, 9, 10]  # the text block is not read
    got = {c.line: problems_of(c.words) for c in commands}
    assert got[4] == []
    assert got[5] == ["'bracketry benchmark' has no option '--no-such-option'"]
    assert got[7][0].startswith("'bracketry' has no subcommand 'nosuch'")
    assert got[8] == ["'bracketry hw bandwidth --fps' needs a value"]
    assert got[9] == ["'bracketry emulate' has no option '--slam-pace'"]
    assert got[10] == ["'bracketry calibrate solve' needs its argument(s) SESSION (0 given)"]


def test_choices_and_required_options_are_checked() -> None:
    assert problems_of(("benchmark", "D", "--out", "b", "--slam", "orbslam3")) == []
    assert problems_of(("benchmark", "D", "--out", "b", "--slam", "nosuch")) == [
        "'bracketry benchmark --slam nosuch': not one of orbslam3, builtin"]
    assert problems_of(("benchmark", "D", "--out", "b", "--slam", "SLAM")) == []  # a placeholder
    assert problems_of(("benchmark", "D")) == ["'bracketry benchmark' needs its required option '--out'"]
    assert problems_of(("train",)) == ["'bracketry train' names no subcommand"]
