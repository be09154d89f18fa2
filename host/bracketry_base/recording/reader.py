"""Read recordings, whole or truncated (kill -9, power loss, disk full), without trusting the summary section.

The file is scanned record by record from the start: Schema and Channel records (written before any message that
uses them), Chunk records (decompressed, CRC-checked) and bare Message records. A record cut off by the end of the
file, a chunk that fails to decompress or whose CRC differs, or garbage in place of a record ends the scan or skips
that chunk; what was read before stays usable and the problem is reported in ``ReadReport``.
"""

from __future__ import annotations

import mmap
import os
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.opcode import Opcode

from bracketry_base.errors import BracketryError
from bracketry_base.recording.mcap_writer import MAGIC


class UnreadableRecordingError(BracketryError):
    """The file is not an MCAP recording at all (no magic, no header)."""


@dataclass
class RawMessage:
    """One message as stored: ``data`` is the CDR bytes (decode with ``bracketry_base.recording.decode``)."""

    topic: str
    schema_name: str
    channel_id: int
    sequence: int
    log_time: int
    publish_time: int
    data: memoryview
    #: byte offset in the file of the top-level record holding the message (its Chunk, or the Message itself):
    #: ``RecordingReader.message_at`` reads it again without a scan
    record_offset: int = -1


@dataclass
class ReadReport:
    """What the scan found: ``truncated`` (no footer), bad chunks, bytes after the last whole record."""

    path: str
    size_bytes: int = 0
    truncated: bool = False
    has_footer: bool = False
    chunks: int = 0
    bad_chunks: int = 0
    messages: int = 0
    tail_bytes_lost: int = 0
    problems: list[str] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


def _read_str(b: memoryview, off: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", b, off)
    return bytes(b[off + 4:off + 4 + n]).decode(), off + 4 + n


def _decompress(compression: str, data: memoryview, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return bytes(lz4.frame.decompress(data))
    raise ValueError(f"unknown chunk compression {compression!r}")


class RecordingReader:
    """Scan one MCAP file. ``messages(topics)`` yields ``RawMessage`` in file order; ``report`` after the scan."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            with open(self.path, "rb") as f:
                size = os.fstat(f.fileno()).st_size
                mapped: Any = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
        except (OSError, ValueError) as exc:
            raise UnreadableRecordingError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}") from exc
        self._data = memoryview(mapped)
        if len(self._data) < len(MAGIC) or bytes(self._data[:8]) != MAGIC:
            raise UnreadableRecordingError(f"{path}: not an MCAP file (bad magic)")
        self.schemas: dict[int, tuple[str, str, str]] = {}  # id -> (name, encoding, text)
        self.channels: dict[int, tuple[str, int, str]] = {}  # id -> (topic, schema id, message encoding)
        self.report = ReadReport(path=str(path), size_bytes=len(self._data))
        self._header_seen = False

    def topics(self) -> dict[str, str]:
        """topic -> schema name of the channels seen so far (complete after a ``messages()`` pass)."""
        return {t: self.schemas.get(s, ("?",))[0] for t, s, _ in self.channels.values()}

    def _records(self, buf: memoryview, start: int, in_chunk: bool) -> Iterator[tuple[int, memoryview, int]]:
        off = start
        end = len(buf)
        while off < end:
            if end - off < 9:
                if not in_chunk:
                    self.report.truncated = True
                    self.report.tail_bytes_lost = end - off
                return
            opcode, length = struct.unpack_from("<BQ", buf, off)
            if off + 9 + length > end:
                if not in_chunk:
                    self.report.truncated = True
                    self.report.tail_bytes_lost = end - off
                    self.report.problems.append(f"record at byte {off} cut off by the end of the file")
                return
            yield opcode, buf[off + 9:off + 9 + length], off
            off += 9 + length

    def messages(self, topics: set[str] | None = None) -> Iterator[RawMessage]:
        """Every message of the given topics (all when None), in file order; tolerant of truncation."""
        buf = self._data
        for opcode, body, off in self._records(buf, 8, in_chunk=False):
            if opcode == Opcode.HEADER:
                self._header_seen = True
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._define(opcode, body)
            elif opcode == Opcode.MESSAGE:
                msg = self._message(body, topics, off)
                if msg is not None:
                    yield msg
            elif opcode == Opcode.CHUNK:
                yield from self._chunk(body, off, topics)
            elif opcode == Opcode.METADATA:
                name, o = _read_str(body, 0)
                (n,) = struct.unpack_from("<I", body, o)
                o += 4
                stop = o + n
                md: dict[str, str] = {}
                while o < stop:
                    k, o = _read_str(body, o)
                    v, o = _read_str(body, o)
                    md[k] = v
                self.report.metadata[name] = md
            elif opcode == Opcode.DATA_END:
                continue
            elif opcode == Opcode.FOOTER:
                self.report.has_footer = True
                break
            elif opcode > Opcode.DATA_END or opcode == 0:
                self.report.problems.append(f"unknown opcode 0x{opcode:02x} at byte {off}: scan stopped")
                self.report.truncated = True
                break
        if not self.report.has_footer:
            self.report.truncated = True
        elif bytes(buf[-8:]) != MAGIC:
            self.report.truncated = True
            self.report.problems.append("closing magic missing after the footer")
        if not self._header_seen:
            raise UnreadableRecordingError(f"{self.path}: no MCAP header record")

    def _define(self, opcode: int, body: memoryview) -> None:
        if opcode == Opcode.SCHEMA:
            (sid,) = struct.unpack_from("<H", body, 0)
            name, o = _read_str(body, 2)
            enc, o = _read_str(body, o)
            (n,) = struct.unpack_from("<I", body, o)
            self.schemas[sid] = (name, enc, bytes(body[o + 4:o + 4 + n]).decode())
        else:
            cid, sid = struct.unpack_from("<HH", body, 0)
            topic, o = _read_str(body, 4)
            enc, o = _read_str(body, o)
            self.channels[cid] = (topic, sid, enc)

    def message_at(self, record_offset: int, channel_id: int, log_time: int) -> memoryview | None:
        """The data of the message on ``channel_id`` at ``log_time`` in the top-level record at ``record_offset``
        (a ``RawMessage.record_offset`` of an earlier scan of this file): random access to one message without a
        scan. None when it is not there."""
        buf = self._data
        if record_offset < 8 or record_offset + 9 > len(buf):
            return None
        opcode, length = struct.unpack_from("<BQ", buf, record_offset)
        body = buf[record_offset + 9:record_offset + 9 + length]
        if opcode == Opcode.MESSAGE:
            records: Iterator[tuple[int, memoryview, int]] = iter([(opcode, body, record_offset)])
        elif opcode == Opcode.CHUNK:
            try:
                inner = memoryview(self._chunk_data(body))
            except Exception:
                return None
            records = self._records(inner, 0, in_chunk=True)
        else:
            return None
        for op, rbody, _ in records:
            if op == Opcode.MESSAGE:
                cid, _seq, t = struct.unpack_from("<HIQ", rbody, 0)
                if cid == channel_id and t == log_time:
                    return rbody[22:]
        return None

    def _message(self, body: memoryview, topics: set[str] | None, record_offset: int) -> RawMessage | None:
        cid, seq, log_time, pub_time = struct.unpack_from("<HIQQ", body, 0)
        channel = self.channels.get(cid)
        if channel is None:
            self.report.problems.append(f"message on unknown channel {cid}")
            return None
        self.report.messages += 1
        if topics is not None and channel[0] not in topics:
            return None
        schema_name = self.schemas.get(channel[1], ("?",))[0]
        return RawMessage(channel[0], schema_name, cid, seq, log_time, pub_time, body[22:], record_offset)

    @staticmethod
    def _chunk_data(body: memoryview) -> bytes:
        _t0, _t1, size, crc = struct.unpack_from("<QQQI", body, 0)
        compression, o = _read_str(body, 28)
        (n,) = struct.unpack_from("<Q", body, o)
        data = _decompress(compression, body[o + 8:o + 8 + n], size)
        if len(data) != size or (crc and zlib.crc32(data) != crc):
            raise ValueError("size or CRC mismatch")
        return data

    def _chunk(self, body: memoryview, off: int, topics: set[str] | None) -> Iterator[RawMessage]:
        self.report.chunks += 1
        try:
            data = self._chunk_data(body)
        except Exception as exc:
            self.report.bad_chunks += 1
            self.report.problems.append(f"chunk at byte {off} unreadable ({exc}): skipped")
            return
        inner = memoryview(data)
        for opcode, rbody, _ in self._records(inner, 0, in_chunk=True):
            if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._define(opcode, rbody)
            elif opcode == Opcode.MESSAGE:
                msg = self._message(rbody, topics, off)
                if msg is not None:
                    yield msg
