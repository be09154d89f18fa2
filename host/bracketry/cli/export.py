"""``bracketry export REC --format borealhdr|rosbag1 --out DIR``."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry.errors import BracketryError


@click.command("export")
@click.argument("recording", type=click.Path(path_type=Path, exists=True))
@click.option("--format", "fmt", type=click.Choice(["borealhdr", "rosbag1"]), default="borealhdr", show_default=True)
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="borealhdr: output folder; rosbag1: the .bag file to write.")
@click.option("--workers", type=int, default=2, show_default=True, help="PNG encoding threads.")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def command(recording: Path, fmt: str, out: Path, workers: int, no_progress: bool) -> int:
    """Export a recording (.mcap file or folder of split files; a daemon recording folder of segments segNN/
    exports to one BorealHDR tree per segment, <out>/segNN/).

    borealhdr: camera_left|camera_right/<exposure_ms>/<timestamp_ns>.png (16-bit raw Bayer codes), left and right
    sharing their trigger's timestamp. rosbag1: a ROS 1 bag with the images, our metadata and the upstream
    /stereo/cameraN/metadata topic read by check_bag_bracketing.py.
    """
    from bracketry.recording.verify import segment_folders

    segments = segment_folders(recording)
    if fmt == "borealhdr":
        from bracketry.export.borealhdr import export_borealhdr

        if out.exists() and any(out.iterdir()):
            raise BracketryError(f"{out} is not empty; choose an empty or new folder")
        for src, dst in ([(seg, out / seg.name) for seg in segments] or [(recording, out)]):
            summary = export_borealhdr(src, dst, workers=workers, progress=not no_progress)
            written = ", ".join(f"{side} {n}" for side, n in sorted(summary.written.items())) or "nothing"
            click.echo(f"exported {written} images to {dst}"
                       + (f"; {summary.skipped_no_event} frames without trigger event skipped"
                          if summary.skipped_no_event else ""))
    else:
        from bracketry.export.rosbag1 import export_rosbag1

        if segments:
            raise BracketryError(f"{recording} holds {len(segments)} segments; export one segment folder per bag "
                                 f"(e.g. {segments[0]})")
        counts = export_rosbag1(recording, out)
        click.echo(f"wrote {out}: {sum(counts.values())} messages on {len(counts)} topics")
    return 0
