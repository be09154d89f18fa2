"""Documents say what is, not what was: no history wording in the prose of any Markdown file of the repository.

The prose of every Markdown file git tracks is scanned for the phrases of
:data:`HISTORY_PHRASES` (case-insensitive, whole words). Fenced code blocks and inline code spans are not prose
(``systemctl enable --now`` is a command) and are left out. A measurement's date belongs in docs/RESULTS.md's header,
a change's story in the git log. :data:`ALLOWED` lists the few (file, phrase) pairs where such a word says what is;
each entry says why.
"""

from __future__ import annotations

import re

from bracketry_base.paths import repo_root
from bracketry_testkit import tracked_markdown_files

#: phrases that tell a story of changes instead of what is (regular expressions, case-insensitive)
HISTORY_PHRASES: tuple[str, ...] = (
    r"\bas before\b", r"\bthan before\b", r"\bbefore the change\b", r"\bbefore this change\b",
    r"\bbefore\s*[):]", r"\bbefore\.(?:\s|$)",
    r"\bnow\b", r"\bnowadays\b", r"\bpreviously\b", r"\bformerly\b", r"\buntil recently\b",
    r"\bprevious (?:release|version|commit|implementation|demo)\b", r"\b(?:this|last|next) release\b",
    r"\bno longer\b", r"\bany ?more\b", r"\bused to be\b", r"\bwe used to\b",
    r"\bold (?:name|spelling|method|code|kernel|version|emulator|renderer)\b",
    r"\bearlier (?:release|version|emulator|code|implementation|commit|kernel|blur)\b",
    r"\bformer (?:kernel|method|code|version|release|name|emulator)\b",
    r"\bnew in\b", r"\btoday's\b",
    r"\b(?:was|were|has been|have been) (?:changed|replaced|renamed|removed|added|fixed)\b",
)
#: (file, phrase found) pairs allowed, each with its reason
ALLOWED: dict[tuple[str, str], str] = {}

_FENCE = re.compile(r"^\s*(```+|~~~+)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1", re.DOTALL)
_PATTERN = re.compile("|".join(f"(?:{p})" for p in HISTORY_PHRASES), re.IGNORECASE)




def history_wording(text: str) -> list[tuple[int, str]]:
    """(1-based line, phrase) of each history phrase in the prose of a Markdown text."""
    prose = []
    fence: str | None = None
    for line in text.splitlines():
        m = _FENCE.match(line)
        if m and (fence is None or m.group(1).startswith(fence)):
            fence = m.group(1) if fence is None else None
            prose.append("")
        else:
            prose.append("" if fence is not None else line)
    # a code span may run over a line break: blank it out, keeping its line breaks
    joined = _CODE_SPAN.sub(lambda c: "\n" * c.group(0).count("\n"), "\n".join(prose))
    found = []
    for number, line in enumerate(joined.split("\n"), start=1):
        for hit in _PATTERN.finditer(line):
            found.append((number, hit.group(0)))
    return found


def test_no_history_wording_in_any_document() -> None:
    root = repo_root()
    files = tracked_markdown_files(root)
    assert any(f.name == "README.md" for f in files)
    bad = []
    for f in files:
        rel = str(f.relative_to(root))
        for number, phrase in history_wording(f.read_text(encoding="utf-8")):
            if (rel, phrase.lower()) not in ALLOWED:
                bad.append(f"{rel}:{number}: '{phrase}'")
    assert not bad, "history wording (say what is, not what was):\n" + "\n".join(bad)


def test_the_scan_finds_history_in_prose_only() -> None:
    text = ("The demo takes 3 min, as before.\n"
            "It no longer writes PNGs (`--now` is an option).\n"
            "```sh\nsystemctl enable --now bracketry\n```\n"
            "Time before failure is counted in steps; the old name `calibrate-crf` works.\n"
            "RTE is now 3.8 %.\n")
    assert history_wording(text) == [(1, "as before"), (2, "no longer"), (6, "old name"), (7, "now")]
