"""``bracketry verify REC... [--json] [--repair]``: check recordings; exit 0 clean, 1 problems, 2 unreadable."""

from __future__ import annotations

import json
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, EXIT_PROBLEMS, EXIT_USAGE, output_file, overwrite_option
from bracketry_base.recording.reader import UnreadableRecordingError
from bracketry_base.recording.verify import (
    REPAIRED_SUFFIX,
    check_repair_target,
    expand_segments,
    format_report,
    recording_files,
    repair_recording,
    verify_recording,
)


@click.command("verify")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(exists=True, path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document (list of reports).")
@click.option("--repair", is_flag=True,
              help=f"Write <file>{REPAIRED_SUFFIX}, a clean finished copy of each truncated file, next to it; the "
                   "truncated file is kept (readers then use the copy in its place).")
@click.option("--out", type=output_file(suffixes=(".mcap",)),
              help="With --repair and exactly one truncated file: the repaired copy's path (.mcap).")
@overwrite_option("With --repair: replace an existing repaired copy (never the truncated input itself).")
def command(recordings: tuple[Path, ...], as_json: bool, repair: bool, out: Path | None, overwrite: bool) -> int:
    """Check recordings (.mcap files or folders of split files): frames, drops, incomplete and unpaired frames,
    bracket-order breaks, exposure mismatches and missing packets per camera. Truncated files are read too; with
    --repair a clean copy <file>.repaired.mcap is written next to each truncated file (which stays) and is read in
    its place by verify, export and emulate. A daemon recording folder holding segment folders (segNN/) is checked
    segment by segment.

    Exit code: 0 all clean, 1 problems found, 2 a recording is unreadable (or bad usage).
    """
    if out is not None and not repair:
        raise BracketryError("--out needs --repair")
    targets = [seg for r in recordings for seg in expand_segments(r)]
    reports = [verify_recording(r) for r in targets]
    repaired: list[dict[str, object]] = []
    if repair:
        todo = []
        for report in reports:
            if not report.readable:
                continue
            for f in recording_files(report.recording):
                entry = next((x for x in report.files if x["path"] == str(f)), None)
                if entry is not None and entry["truncated"]:
                    todo.append(f)
        if out is not None and len(todo) > 1:
            raise BracketryError(f"--out names one repaired file but {len(todo)} files need repair; omit --out "
                                 f"(each copy goes next to its file as <file>{REPAIRED_SUFFIX})")
        # every destination is checked before anything is written (no half-done repair, no overwrite)
        for f in todo:
            check_repair_target(f, out, overwrite=overwrite)
        for f in todo:
            try:
                dst, n = repair_recording(f, out, overwrite=overwrite)
            except UnreadableRecordingError as exc:
                repaired.append({"file": str(f), "error": str(exc)})
                continue
            repaired.append({"file": str(f), "repaired": str(dst), "messages": n})
    if as_json:
        click.echo(json.dumps({"reports": [r.as_dict() for r in reports], "repaired": repaired}, indent=1))
    else:
        for r in reports:
            click.echo(format_report(r))
        for item in repaired:
            if "error" in item:
                click.echo(f"repair failed: {item['file']}: {item['error']}")
            else:
                click.echo(f"repaired: {item['file']} -> {item['repaired']} ({item['messages']} messages)")
    unreadable = [r for r in reports if not r.readable]
    if unreadable:
        more = f" (and {len(unreadable) - 1} more unreadable)" if len(unreadable) > 1 else ""
        click.echo(f"error: {unreadable[0].error}{more}", err=True)
        return EXIT_USAGE
    return EXIT_OK if all(r.ok for r in reports) else EXIT_PROBLEMS
