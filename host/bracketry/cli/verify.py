"""``bracketry verify REC... [--json] [--repair]``: check recordings; exit 0 clean, 1 problems, 2 unreadable."""

from __future__ import annotations

import json
from pathlib import Path

import click

from bracketry.recording.reader import UnreadableRecordingError
from bracketry.recording.verify import (
    expand_segments,
    format_report,
    recording_files,
    repair_recording,
    verify_recording,
)


@click.command("verify")
@click.argument("recordings", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON document (list of reports).")
@click.option("--repair", is_flag=True, help="Write <file>.repaired.mcap, a clean copy of each truncated file.")
@click.option("--out", type=click.Path(path_type=Path), help="With --repair and one file: the repaired file's path.")
def command(recordings: tuple[Path, ...], as_json: bool, repair: bool, out: Path | None) -> int:
    """Check recordings (.mcap files or folders of split files): frames, drops, incomplete and unpaired frames,
    bracket-order breaks, exposure mismatches and missing packets per camera. Truncated files are read too; a
    repaired copy (<file>.repaired.mcap) replaces its truncated file. A daemon recording folder holding segment
    folders (segNN/) is checked segment by segment.

    Exit code: 0 all clean, 1 problems found, 2 a recording is unreadable.
    """
    targets = [seg for r in recordings for seg in expand_segments(r)]
    reports = [verify_recording(r) for r in targets]
    repaired: list[dict[str, object]] = []
    if repair:
        for report in reports:
            if not report.readable:
                continue
            for f in recording_files(report.recording):
                entry = next((x for x in report.files if x["path"] == str(f)), None)
                if entry is None or not entry["truncated"]:
                    continue
                try:
                    dst, n = repair_recording(f, out if out and len(targets) == 1 else None)
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
    if any(not r.readable for r in reports):
        return 2
    return 0 if all(r.ok for r in reports) else 1
