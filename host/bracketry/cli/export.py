"""``bracketry export REC --format borealhdr|rosbag1 --out DIR|FILE``."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import EXIT_OK, WORKERS, input_path, overwrite_option, quiet_option
from bracketry_base.outputs import check_output
from bracketry_base.png import PNG_COMPRESSIONS


@click.command("export")
@click.argument("recording", type=input_path())
@click.option("--format", "fmt", type=click.Choice(["borealhdr", "rosbag1"]), default="borealhdr", show_default=True,
              help="borealhdr: a BorealHDR folder tree of 16-bit PNGs; rosbag1: one ROS 1 .bag file.")
@click.option("--out", required=True, type=click.Path(path_type=Path),
              help="borealhdr: the output folder (new or empty); rosbag1: the .bag file to write.")
@click.option("--workers", type=WORKERS, default=2, show_default=True,
              help="PNG encoding threads (0 = one per CPU).")
@click.option("--keep-unpaired", is_flag=True,
              help="borealhdr: also write frames whose partner of the other camera was lost (counted either way).")
@click.option("--png-compression", type=click.Choice(PNG_COMPRESSIONS), default="opencv",
              show_default=True,
              help="borealhdr: lossless PNG encoding: opencv (cv2.imwrite defaults), stored (no compression: ~8x "
                   "faster to write at 640x400, the largest), fast (Huffman only) or small (zlib level 1).")
@overwrite_option()
@quiet_option()
def command(recording: Path, fmt: str, out: Path, workers: int, keep_unpaired: bool, png_compression: str,
            overwrite: bool, quiet: bool) -> int:
    """Export a recording (.mcap file or folder of split files; a daemon recording folder of segments segNN/
    exports to one BorealHDR tree per segment, <out>/segNN/). Truncated files are read up to their last whole
    record, like verify does.

    borealhdr: camera_left|camera_right/<exposure_ms>/<timestamp_ns>.png (16-bit raw Bayer codes), left and right
    sharing their trigger's timestamp, and calibration/ when the recording carries a calibration (rig.calibration);
    a frame whose partner of the other camera was lost is not written unless
    --keep-unpaired (the count is printed). rosbag1: a ROS 1 bag with the images, our metadata and the upstream
    /stereo/cameraN/metadata topic read by check_bag_bracketing.py.
    """
    import os

    from bracketry_base.recording.verify import recording_files, segment_folders

    segments = segment_folders(recording)
    if fmt == "rosbag1" and segments:
        raise BracketryError(f"{recording} holds {len(segments)} segments; export one segment folder per bag "
                             f"(e.g. {segments[0]})")
    check_output(out, "dir" if fmt == "borealhdr" else "file", overwrite=overwrite,
                 suffixes=(".bag",) if fmt == "rosbag1" else ())
    from bracketry_base.recording.reader import RecordingReader

    for src in segments or [recording]:
        for f in recording_files(src):
            RecordingReader(f)  # not a recording: refused before anything is written
    if fmt == "borealhdr":
        from bracketry_rig.export.borealhdr import export_borealhdr

        workers = workers or os.cpu_count() or 1
        for src, dst in ([(seg, out / seg.name) for seg in segments] or [(recording, out)]):
            summary = export_borealhdr(src, dst, workers=workers, progress=not quiet, keep_unpaired=keep_unpaired,
                                       png_compression=png_compression)
            written = ", ".join(f"{side} {n}" for side, n in sorted(summary.written.items())) or "nothing"
            click.echo(f"exported {written} images to {dst}"
                       + (f"; {summary.skipped_no_event} frames without trigger event skipped"
                          if summary.skipped_no_event else ""))
            click.echo(f"calibration: {summary.calibration} (the one the recording carries)" if summary.calibration
                       else f"calibration: none (the recording carries none, so {dst} has no calibration/; set "
                            "rig.calibration in the rig config, or add calibration/ from bracketry calibrate solve)")
            if summary.duplicates:
                click.echo(f"warning: {summary.duplicates} frame(s) with the time and exposure of a frame already "
                           "exported (a camera delivered two frames for one trigger): the first kept", err=True)
            if summary.unpaired:
                verb = "written" if keep_unpaired else "not written (--keep-unpaired writes them)"
                click.echo(f"warning: {summary.unpaired} frame(s) whose other-camera partner was lost: {verb}",
                           err=True)
    else:
        from bracketry_rig.export.rosbag1 import export_rosbag1

        counts = export_rosbag1(recording, out, overwrite=overwrite)
        click.echo(f"wrote {out}: {sum(counts.values())} messages on {len(counts)} topics")
    return EXIT_OK
