"""Run tests again and again, idle and beside busy CPU loops, and count each test's failures (the flake hunt).

Usage (from the checkout's root)::

    .venv/bin/python tests/flake_hunt.py --runs 10 --hogs 0 --runs-hogged 10 --hogs-hogged 2 \\
        tests/bracketry_rig/recording tests/bracketry_rig/pairing

Each run is one ``pytest`` process over the given paths (``-p no:cacheprovider``, JUnit XML to a temporary file); a
test's outcome per run is read from that XML. ``--hogs N`` starts N ``python -c 'while True: pass'`` processes for the
run and ends them (by PID) after it. The table lists every test that failed or errored in any run, with its failures
idle and hogged, and the first line of its first failure message. Exit 0 when no test failed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class Tally:
    """Outcomes of one test over the runs of one condition."""

    runs: int = 0
    failures: int = 0
    first_message: str = ""
    first_text: str = ""  # the whole report of the first failure (message and traceback)


@dataclass
class Hunt:
    """Outcomes per condition (``idle`` / ``hogged``) and test id."""

    tallies: dict[str, dict[str, Tally]] = field(default_factory=lambda: defaultdict(dict))
    runs: dict[str, int] = field(default_factory=lambda: defaultdict(int))


def outcomes(junit_xml: Path) -> dict[str, str]:
    """Test id -> ``""`` (passed or skipped) or its failure/error report (message line first, then the traceback)."""
    result = {}
    for case in ET.parse(junit_xml).getroot().iter("testcase"):
        test_id = f"{case.get('classname', '')}::{case.get('name', '')}"
        bad = case.find("failure")
        if bad is None:
            bad = case.find("error")
        if bad is None:
            result[test_id] = ""
        else:
            first = ((bad.get("message") or "failed").splitlines() or ["failed"])[0]
            result[test_id] = f"{first}\n{bad.text or ''}"
    return result


def run_once(paths: list[str], hogs: int, extra: list[str]) -> dict[str, str]:
    """One pytest run over ``paths`` beside ``hogs`` busy loops; its outcomes (see ``outcomes``)."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            xml = Path(tmp) / "junit.xml"
            subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={xml}",
                            *extra, *paths], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
            return outcomes(xml) if xml.exists() else {"<pytest did not write its report>": "no report"}
    finally:
        for p in procs:
            p.kill()
            p.wait()


def record(hunt: Hunt, condition: str, result: dict[str, str]) -> None:
    hunt.runs[condition] += 1
    for test_id, message in result.items():
        tally = hunt.tallies[condition].setdefault(test_id, Tally())
        tally.runs += 1
        if message:
            tally.failures += 1
            tally.first_message = tally.first_message or message.splitlines()[0]
            tally.first_text = tally.first_text or message


def table(hunt: Hunt) -> str:
    """Markdown table of every test that failed in some run."""
    bad = sorted({t for c in hunt.tallies.values() for t, tl in c.items() if tl.failures})
    lines = [f"runs: {dict(hunt.runs)}; tests seen: {len({t for c in hunt.tallies.values() for t in c})}; "
             f"tests that failed at least once: {len(bad)}"]
    if bad:
        lines += ["| test | idle failures | hogged failures | first message |", "|---|---|---|---|"]
        for t in bad:
            cells = []
            for cond in ("idle", "hogged"):
                tl = hunt.tallies[cond].get(t)
                cells.append(f"{tl.failures}/{tl.runs}" if tl else "-")
            msg = next((hunt.tallies[c][t].first_message for c in ("idle", "hogged")
                        if t in hunt.tallies[c] and hunt.tallies[c][t].first_message), "")
            lines.append(f"| {t} | {cells[0]} | {cells[1]} | {msg[:120]} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("paths", nargs="+", help="test files, folders or node ids")
    ap.add_argument("--runs", type=int, default=10, help="runs on an otherwise idle machine")
    ap.add_argument("--runs-hogged", type=int, default=10, help="runs beside --hogs-hogged busy loops")
    ap.add_argument("--hogs-hogged", type=int, default=2)
    ap.add_argument("--hogs", type=int, default=0, help="busy loops during the idle runs (0)")
    ap.add_argument("-k", dest="keyword", default=None, help="pytest -k expression")
    ap.add_argument("--reports", type=Path, default=None,
                    help="folder for the whole report of each test's first failure (one file per test)")
    args = ap.parse_args(argv)
    extra = ["-k", args.keyword] if args.keyword else []
    hunt = Hunt()
    plan = [("idle", args.hogs)] * args.runs + [("hogged", args.hogs_hogged)] * args.runs_hogged
    for i, (condition, hogs) in enumerate(plan, 1):
        record(hunt, condition, run_once(args.paths, hogs, extra))
        failed = sum(1 for tl in hunt.tallies[condition].values() if tl.failures)
        print(f"run {i}/{len(plan)} ({condition}): tests with failures so far {failed}", flush=True)
    print(table(hunt))
    if args.reports:
        args.reports.mkdir(parents=True, exist_ok=True)
        for cond, tallies in hunt.tallies.items():
            for test_id, tl in tallies.items():
                if tl.first_text:
                    name = test_id.replace("::", "__").replace("/", "_").replace(".", "_")[:150]
                    (args.reports / f"{cond}-{name}.txt").write_text(tl.first_text)
    return 1 if any(tl.failures for c in hunt.tallies.values() for tl in c.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
