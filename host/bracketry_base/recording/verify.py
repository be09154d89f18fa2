"""Check recordings: per camera frames, drops, incomplete and unpaired frames, bracket-order breaks, exposure
mismatches (each frame's read-back exposure vs its pulse width) and missing packets, from the stored FrameMeta and
TRIGGER events (never from the summary section, so truncated files are checked too). ``repair_recording`` writes a
clean copy of a truncated file.

A recording is one ``.mcap`` file or a folder of the split files of one recording (``<name>_NNN.mcap``).
"""

from __future__ import annotations

import math
import os
from collections import defaultdict
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bracketry_base.errors import BracketryError
from bracketry_base.outputs import check_output
from bracketry_base.recording import topics as T
from bracketry_base.recording.decode import decode
from bracketry_base.recording.mcap_writer import ChunkedMcapWriter
from bracketry_base.recording.reader import RecordingReader, UnreadableRecordingError

#: read-back exposure (``FrameMeta.exposure_us_read``: chunk or register) vs the pulse width: relative and absolute
#: (µs), whichever is larger. Covers the cameras' exposure granularity (Basler ace: 1 µs steps, the register holds the
#: value rounded to them; the Aravis fake: exact) and float32 chunk values, and still flags a chunk one frame behind
#: (Aravis #312): neighbouring brackets differ by far more than 0.5 %.
EXPOSURE_READ_TOLERANCE_REL = 0.005
EXPOSURE_READ_TOLERANCE_US = 1.0
#: recordings without ``exposure_us_read``: their chunk value (``exposure_us_reported``) is checked with this wider
#: tolerance, relative and absolute (µs), whichever is larger
EXPOSURE_TOLERANCE_REL = 0.02
EXPOSURE_TOLERANCE_US = 20.0
#: at most this many trigger_seqs listed per problem kind
MAX_LISTED = 50


#: name ending of the clean copy ``verify --repair`` writes next to a truncated file
REPAIRED_SUFFIX = ".repaired.mcap"


def exposure_read_mismatch(read_us: float, commanded_us: float) -> bool:
    """True when a frame's read-back exposure differs from its pulse width by more than
    max(``EXPOSURE_READ_TOLERANCE_US``, ``EXPOSURE_READ_TOLERANCE_REL`` * pulse width); NaN (nothing read) never."""
    if math.isnan(read_us):
        return False
    return abs(read_us - commanded_us) > max(EXPOSURE_READ_TOLERANCE_REL * commanded_us, EXPOSURE_READ_TOLERANCE_US)


def _exposure_mismatch(meta: Any, commanded_us: float) -> bool | None:
    """Whether ``meta``'s exposure disagrees with its pulse width; None when the frame has no exposure read back.
    Frames with ``exposure_source`` (read-back fields) are checked by :func:`exposure_read_mismatch`; frames of
    recordings without it by their chunk value (``exposure_us_reported``) and the chunk's wider tolerance
    (``EXPOSURE_TOLERANCE_*``)."""
    source = getattr(meta, "exposure_source", None)
    if source is not None:
        read = float(meta.exposure_us_read)
        if source == "none" or math.isnan(read):
            return None
        return exposure_read_mismatch(read, commanded_us)
    reported = float(meta.exposure_us_reported)
    if math.isnan(reported):
        return None
    return abs(reported - commanded_us) > max(EXPOSURE_TOLERANCE_REL * commanded_us, EXPOSURE_TOLERANCE_US)


def recording_files(path: str | Path) -> list[Path]:
    """The .mcap files of a recording given as a file or a folder (sorted by name = split order).

    In a folder, a ``<stem>.repaired.mcap`` written by ``verify --repair`` replaces its truncated ``<stem>.mcap``
    (same place in the split order), so a repaired recording is not read twice."""
    p = Path(path)
    if p.is_dir():
        found = [f for f in p.glob("*.mcap") if f.is_file()]
        superseded = {f.name[: -len(REPAIRED_SUFFIX)] + ".mcap" for f in found if f.name.endswith(REPAIRED_SUFFIX)}
        files = sorted((f for f in found if f.name not in superseded),
                       key=lambda f: f.name.replace(REPAIRED_SUFFIX, ".mcap"))
        if not files:
            segments = segment_folders(p)
            hint = f" (it holds {len(segments)} segment folders, e.g. {segments[0].name}/)" if segments else ""
            raise UnreadableRecordingError(f"{p}: no .mcap files in this folder{hint}")
        return files
    if not p.exists():
        raise UnreadableRecordingError(f"{p}: no such file")
    return [p]


def segment_folders(path: str | Path) -> list[Path]:
    """The segment folders (``segNN/``, each a recording of its own) of a daemon recording root, sorted; [] when
    ``path`` holds .mcap files itself or is not a folder."""
    p = Path(path)
    if not p.is_dir() or any(f.is_file() for f in p.glob("*.mcap")):
        return []
    return sorted(d for d in p.iterdir() if d.is_dir() and any(f.is_file() for f in d.glob("*.mcap")))


def expand_segments(path: str | Path) -> list[Path]:
    """``path`` itself, or the segment folders of a daemon recording root (trigger_seq restarts in each)."""
    return segment_folders(path) or [Path(path)]


@dataclass
class SideReport:
    """Counts for one camera; ``seqs`` lists (up to MAX_LISTED) trigger_seqs of each problem kind.
    ``exposures_checked``: frames whose read-back exposure was compared with their pulse width (the others have no
    read-back or no TRIGGER event); ``exposure_mismatches`` counts the ones that disagree."""

    frames: int = 0
    images: int = 0
    drops: int = 0
    incomplete: int = 0
    unpaired: int = 0
    bracket_order_breaks: int = 0
    exposure_mismatches: int = 0
    exposures_checked: int = 0
    missing_packets: int = 0
    timestamp_mismatches: int = 0
    missing_images: int = 0
    lost_triggers: int = 0  # software triggers the camera reported lost (RigStatus), whose frames are drops
    seqs: dict[str, list[int]] = field(default_factory=dict)

    def note(self, kind: str, seq: int) -> None:
        setattr(self, kind, getattr(self, kind) + 1)
        listed = self.seqs.setdefault(kind, [])
        if len(listed) < MAX_LISTED:
            listed.append(seq)


@dataclass
class VerifyReport:
    recording: str
    readable: bool = True
    error: str | None = None
    files: list[dict[str, Any]] = field(default_factory=list)
    truncated: bool = False
    events: int = 0
    events_missing: int = 0
    events_missing_seqs: list[int] = field(default_factory=list)
    first_seq: int | None = None
    last_seq: int | None = None
    tail_lost: int = 0
    tail_lost_s: float = 0.0
    fps: float | None = None
    queue_overflows: int = 0
    sides: dict[str, SideReport] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.readable and not self.problems

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ok"] = self.ok
        for side in d["sides"].values():
            side["seqs"] = {k: v for k, v in side["seqs"].items() if v}
        return d


def _stored_schema(reader: RecordingReader, msg: Any) -> str | None:
    """The message's schema text as stored in its file: messages are decoded with their file's own definition (a
    recording made before a field was added lacks it)."""
    return reader.schemas.get(reader.channels[msg.channel_id][1], ("", "", ""))[2] or None


def _load(files: list[Path], report: VerifyReport) -> tuple[dict[int, Any], dict[str, dict[int, Any]],
                                                            dict[str, set[int]], dict[str, str], list[Any]]:
    events: dict[int, Any] = {}
    metas: dict[str, dict[int, Any]] = defaultdict(dict)
    images: dict[str, set[int]] = defaultdict(set)
    metadata: dict[str, str] = {}
    statuses: list[Any] = []
    for path in files:
        reader = RecordingReader(path)
        for msg in reader.messages():
            if msg.topic == T.TRIGGER_TOPIC:
                ev = decode(msg.schema_name, msg.data, _stored_schema(reader, msg))
                events[int(ev.trigger_seq)] = ev
            elif msg.topic.endswith("/frame_meta"):
                side = msg.topic.split("/")[2]
                meta = decode(msg.schema_name, msg.data, _stored_schema(reader, msg))
                if int(meta.trigger_seq) in metas[side]:
                    report.problems.append(f"camera {side}: two frames for trigger_seq {meta.trigger_seq}")
                metas[side][int(meta.trigger_seq)] = meta
            elif msg.topic.endswith("/image_raw"):
                images[msg.topic.split("/")[2]].add(msg.sequence)
            elif msg.topic == T.STATUS_TOPIC:
                statuses.append(decode(msg.schema_name, msg.data, _stored_schema(reader, msg)))
        rr = reader.report
        metadata.update(rr.metadata.get(T.METADATA_NAME, {}))
        report.files.append({"path": str(path), "size_bytes": rr.size_bytes, "truncated": rr.truncated,
                             "chunks": rr.chunks, "bad_chunks": rr.bad_chunks, "messages": rr.messages,
                             "tail_bytes_lost": rr.tail_bytes_lost, "problems": rr.problems})
        report.truncated |= rr.truncated
    return events, metas, images, metadata, statuses


# a trigger_seq at or above this is no pulse number of a recording (a negative index stored as uint32): such records
# are reported, never iterated over
MAX_VALID_SEQ = 2**31 - 1


def _drop_invalid_seqs(events: dict[int, Any], metas: dict[str, dict[int, Any]], images: dict[str, set[int]],
                       report: VerifyReport) -> None:
    """Remove (and report) records whose trigger_seq cannot be a pulse number, so the checks stay bounded."""
    bad_events = [s for s in events if s > MAX_VALID_SEQ]
    for seq in bad_events:
        del events[seq]
    if bad_events:
        report.problems.append(f"{len(bad_events)} trigger event(s) with an invalid trigger_seq (e.g. {bad_events[0]})")
    for side, side_metas in metas.items():
        bad = [s for s in side_metas if s > MAX_VALID_SEQ]
        for seq in bad:
            del side_metas[seq]
            images.get(side, set()).discard(seq)
        if bad:
            report.problems.append(f"camera {side}: {len(bad)} frame(s) with an invalid trigger_seq (e.g. {bad[0]})")


def verify_recording(path: str | Path) -> VerifyReport:
    """Check one recording (file or folder of split files)."""
    report = VerifyReport(recording=str(path))
    try:
        files = recording_files(path)
        events, metas, images, metadata, statuses = _load(files, report)
    except UnreadableRecordingError as exc:
        report.readable = False
        report.error = str(exc)
        return report
    sides = tuple(s for s in metadata.get("sides", ",".join(T.SIDES)).split(",") if s)
    report.fps = float(metadata["fps"]) if "fps" in metadata else None
    n_brackets = len(metadata["brackets_us"].split(",")) if metadata.get("brackets_us") else None
    if n_brackets is None:
        indices = [int(e.bracket_index) for e in events.values()]
        n_brackets = max(indices) + 1 if indices else 1
    _drop_invalid_seqs(events, metas, images, report)
    all_seqs = set(events) | {s for m in metas.values() for s in m}
    if not all_seqs:
        report.sides = {s: SideReport() for s in sides}
        report.problems.append("no frames and no trigger events recorded")
        return report
    first, last = min(all_seqs), max(all_seqs)
    if report.truncated or metadata.get("repaired_from"):
        # what lies after the last trigger_seq recorded by every camera was lost with the open chunk
        complete = [max(metas[s]) for s in sides if metas.get(s)]
        last_whole = min(complete) if len(complete) == len(sides) else first - 1
        report.tail_lost = last - last_whole
        last = last_whole
        if report.fps:
            report.tail_lost_s = report.tail_lost / report.fps
    report.first_seq, report.last_seq = first, last
    report.events = len(events)
    for seq in range(first, last + 1):
        if seq not in events:
            report.events_missing += 1
            if len(report.events_missing_seqs) < MAX_LISTED:
                report.events_missing_seqs.append(seq)
    for side in sides:
        sr = SideReport()
        side_metas = metas.get(side, {})
        prev: tuple[int, int] | None = None  # (trigger_seq, bracket_index) of the last frame with an event
        for seq in range(first, last + 1):
            meta = side_metas.get(seq)
            if meta is None:
                sr.note("drops", seq)
                continue
            sr.frames += 1
            sr.missing_packets += int(meta.missing_packets)
            if meta.status != "success":
                sr.note("incomplete", seq)
            elif seq not in images.get(side, set()):
                sr.note("missing_images", seq)
            if not meta.paired:
                sr.note("unpaired", seq)
            if meta.note == "timestamp_mismatch":
                sr.note("timestamp_mismatches", seq)
            ev = events.get(seq)
            if ev is not None:
                # upstream rule (index == previous + 1 mod n), made drop-aware: a dropped frame is a drop, not a break
                if prev is not None and int(ev.bracket_index) != (prev[1] + seq - prev[0]) % n_brackets:
                    sr.note("bracket_order_breaks", seq)
                prev = (seq, int(ev.bracket_index))
                mismatch = _exposure_mismatch(meta, float(ev.exposure_us))
                if mismatch is not None:
                    sr.exposures_checked += 1
                    if mismatch:
                        sr.note("exposure_mismatches", seq)
        sr.images = len(images.get(side, set()))
        report.sides[side] = sr
    report.queue_overflows = max((int(s.queue_overflows) for s in statuses), default=0)
    for side, sr in report.sides.items():  # (a status of a recording made before the field: absent, 0)
        sr.lost_triggers = max((int(getattr(s, f"lost_triggers_{side}", 0) or 0) for s in statuses), default=0)
    _problems(report)
    return report


def _problems(report: VerifyReport) -> None:
    for side, sr in report.sides.items():
        for kind in ("drops", "incomplete", "unpaired", "bracket_order_breaks", "exposure_mismatches",
                     "timestamp_mismatches", "missing_images"):
            n = getattr(sr, kind)
            if n:
                listed = ", ".join(map(str, sr.seqs.get(kind, [])[:10])) + (" ..." if n > 10 else "")
                report.problems.append(f"camera {side}: {n} {kind.replace('_', ' ')} (trigger_seq {listed})")
        if sr.missing_packets:
            report.problems.append(f"camera {side}: {sr.missing_packets} missing packets")
        if sr.lost_triggers:
            report.problems.append(f"camera {side}: {sr.lost_triggers} software trigger(s) lost by the camera "
                                   f"(no frame for them: among the drops)")
    if report.events_missing:
        listed = ", ".join(map(str, report.events_missing_seqs[:10]))
        report.problems.append(f"{report.events_missing} trigger events missing (trigger_seq {listed})")
    if report.queue_overflows:
        report.problems.append(f"{report.queue_overflows} items dropped by the recorder queue")
    if report.truncated:
        lost = f", last {report.tail_lost} trigger_seqs lost" if report.tail_lost else ""
        secs = f" ({report.tail_lost_s:.2f} s)" if report.fps and report.tail_lost else ""
        report.problems.append(f"truncated file (no footer){lost}{secs}: bracketry verify --repair writes a clean copy")


def format_report(report: VerifyReport) -> str:
    """Human-readable text of a report."""
    if not report.readable:
        return f"{report.recording}: UNREADABLE: {report.error}"
    lines = [f"{report.recording}: {'OK' if report.ok else 'PROBLEMS'} "
             f"(trigger_seq {report.first_seq}..{report.last_seq}, {report.events} events"
             f"{', truncated' if report.truncated else ''})"]
    for side, sr in report.sides.items():
        lines.append(f"  {side:>5}: frames {sr.frames}  drops {sr.drops}  incomplete {sr.incomplete}  "
                     f"unpaired {sr.unpaired}  bracket-order breaks {sr.bracket_order_breaks}  "
                     f"exposure mismatches {sr.exposure_mismatches}/{sr.exposures_checked} read back  "
                     f"missing packets {sr.missing_packets}"
                     + (f"  lost software triggers {sr.lost_triggers}" if sr.lost_triggers else ""))
    lines += [f"  - {p}" for p in report.problems]
    return "\n".join(lines)


def repaired_path(src: str | Path, dst: str | Path | None = None) -> Path:
    """Where the repaired copy of ``src`` goes: ``dst``, or ``<stem>.repaired.mcap`` next to ``src``."""
    src = Path(src)
    return Path(dst) if dst else src.with_name(src.stem + REPAIRED_SUFFIX)


def check_repair_target(src: str | Path, dst: str | Path | None = None, *, overwrite: bool = False) -> Path:
    """The repaired copy's path after the output checks (never the input, never an existing file without
    ``overwrite``, its folder must exist); BracketryError otherwise. Nothing is written."""
    src = Path(src)
    if src.is_dir():
        raise BracketryError(f"{src}: --repair takes .mcap files, not folders")
    out = repaired_path(src, dst)
    if out.resolve() == src.resolve():
        raise BracketryError("--repair never overwrites its input")
    return check_output(out, "file", overwrite=overwrite, what="repaired copy")


def repair_recording(src: str | Path, dst: str | Path | None = None, *, overwrite: bool = False) -> tuple[Path, int]:
    """Write a clean, finished copy of a (truncated) recording file; returns (path, messages copied).

    Default output: ``<stem>.repaired.mcap`` next to ``src``; an existing file is replaced only with ``overwrite``,
    and only once the copy is complete (written under a temporary name, then renamed). Schemas, channels and
    metadata are kept; the metadata gains ``repaired_from``.
    """
    src = Path(src)
    out = check_repair_target(src, dst, overwrite=overwrite)
    reader = RecordingReader(src)
    tmp = out.with_name(f".{out.name}.partial")
    writer = ChunkedMcapWriter(tmp, fsync_interval_s=None)
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    n = 0
    try:
        for msg in reader.messages():
            if msg.channel_id not in channel_map:
                topic, sid, enc = reader.channels[msg.channel_id]
                if sid not in schema_map:
                    name, senc, text = reader.schemas[sid]
                    schema_map[sid] = writer.register_schema(name, text.encode(), senc)
                channel_map[msg.channel_id] = writer.register_channel(topic, schema_map[sid], enc)
            writer.add_message(channel_map[msg.channel_id], msg.log_time, bytes(msg.data),
                               publish_time=msg.publish_time, sequence=msg.sequence)
            n += 1
        for name, md in reader.report.metadata.items():
            writer.add_metadata(name, {**md, "repaired_from": str(src)} if name == T.METADATA_NAME else md)
        writer.finish()
    except BaseException:
        writer.close()
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, out)
    return out, n
