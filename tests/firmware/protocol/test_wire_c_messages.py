"""The C message layer (bproto_pack_* / bproto_unpack_*) against the Python codec, beyond the frozen vectors.

A seeded corpus of payloads of every type (right and wrong lengths, random bytes, SET_BRACKETS of every count,
PANEL_STATE messages with and without non-printable bytes) is judged by CPython's ``unpack_payload`` /
``nack_code_for``; the C harness (ASan/UBSan) must unpack the accepted ones to the same fields and re-pack the same
bytes (``M`` lines), and give the same NACK code for the rejected ones (``P`` lines).
"""

from __future__ import annotations

import random
import subprocess
from pathlib import Path

from bracketry_base import paths
from bracketry_rig.wire import bproto, vectors
from bracketry_testkit import build_c_under_asan

C_DIR = paths.firmware_dir() / "protocol" / "c"
UNKNOWN_TYPES = (0x00, 0x07, 0x13, 0x21, 0x32, 0x7E, 0xFF)


def _build_harness(tmp_path: Path) -> Path:
    return build_c_under_asan([C_DIR / "bproto.c", C_DIR / "bproto_test.c"], tmp_path / "bproto_test",
                              ("-Wconversion",))


def _run_harness(exe: Path, tmp_path: Path, lines: list[str]) -> str:
    text = tmp_path / "lines.txt"
    text.write_text("\n".join(lines) + "\n")
    proc = subprocess.run([str(exe), str(text)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    return proc.stdout.strip().splitlines()[-1]


def _payloads(rng: random.Random) -> list[tuple[int, bytes]]:
    out: list[tuple[int, bytes]] = []

    def rand(n: int) -> bytes:
        return bytes(rng.randrange(256) for _ in range(n))

    def text(n: int) -> bytes:
        return bytes(rng.choice(b" AZaz09:-.~ !") for _ in range(n))

    for msg_type in sorted(bproto.MSG_NAMES):
        size = 21 if msg_type == bproto.MSG_HELLO else 5 if msg_type == bproto.MSG_SET_BRACKETS else \
            bproto._SIZES[msg_type]
        for _ in range(40):
            out.append((msg_type, rand(size)))
        for n in {0, 1, max(size - 1, 0), size + 1, 2 * size + 3, 255}:
            out.append((msg_type, rand(n)))
        for _ in range(10):
            out.append((msg_type, rand(rng.randrange(256))))
    for count in range(0, 63):  # every count a payload can hold (1..16 are the valid tables)
        body = rng.randrange(2**32).to_bytes(4, "little") + bytes([count])
        body += b"".join(rng.randrange(2**32).to_bytes(4, "little") for _ in range(count))
        out.append((bproto.MSG_SET_BRACKETS, body))
        out.append((bproto.MSG_SET_BRACKETS, body[:-1]))
        if len(body) < 255:
            out.append((bproto.MSG_SET_BRACKETS, body + b"\x00"))
    for count in (63, 64, 200, 255):
        out.append((bproto.MSG_SET_BRACKETS, b"\x10\x27\x00\x00" + bytes([count]) + rand(min(4 * count, 250))))
    for _ in range(120):  # PANEL_STATE: printable messages (spaces anywhere), then one bad byte in some
        msg = bytearray(text(bproto.PANEL_MESSAGE_LEN))
        if rng.random() < 0.3:
            msg[rng.randrange(len(msg))] = rng.choice([0x00, 0x09, 0x1F, 0x7F, 0x80, 0xC3, 0xE9, 0xFF])
        out.append((bproto.MSG_PANEL_STATE, rand(18) + bytes(msg)))
    out.append((bproto.MSG_PANEL_STATE, rand(18) + b" " * 20))
    out.append((bproto.MSG_PANEL_STATE, rand(18) + b"   LEADING  inner   "))
    for msg_type in UNKNOWN_TYPES:
        for n in (0, 2, 21):
            out.append((msg_type, rand(n)))
    return out


def _expected_lines(cases: list[tuple[int, bytes]]) -> tuple[list[str], int, int]:
    """Harness lines with the Python codec's verdict; also the counts of accepted and rejected payloads."""
    lines = []
    accepted = rejected = 0
    for seq, (msg_type, payload) in enumerate(cases):
        nack = bproto.nack_code_for(msg_type, payload)
        lines.append(vectors.c_payload_line(msg_type, payload.hex(), nack))
        if nack == 0:
            accepted += 1
            fields = vectors.fields_to_json(bproto.unpack_payload(msg_type, payload))
            frame = bproto.encode_frame(msg_type, seq & 0xFFFF, payload)
            lines.append(vectors.c_message_line(msg_type, seq & 0xFFFF, frame.hex(), payload.hex(), fields))
        else:
            rejected += 1
    return lines, accepted, rejected


def test_wire_c_text_has_a_field_check_for_every_valid_vector() -> None:
    v = vectors.load_vectors()
    m_lines = [ln for ln in vectors.to_c_text(v).splitlines() if ln.startswith("M ")]
    assert len(m_lines) == len(v["valid"])
    assert {int(ln.split()[1]) for ln in m_lines} == set(bproto.MSG_NAMES)
    for ln, vec in zip(m_lines, v["valid"], strict=True):
        assert len(ln.split()) == 5 + len(vec["fields"])  # M type seq frame payload + one token per field


def test_wire_c_messages_match_python_codec(tmp_path: Path) -> None:
    cases = _payloads(random.Random(20261123))
    lines, accepted, rejected = _expected_lines(cases)
    assert accepted > 300 and rejected > 300
    codes = {bproto.nack_code_for(t, p) for t, p in cases}
    assert codes == {0, bproto.NACK_UNKNOWN_TYPE, bproto.NACK_BAD_LENGTH, bproto.NACK_BAD_VALUE}
    last = _run_harness(_build_harness(tmp_path), tmp_path, lines)
    assert last.startswith("PASS")
    # the harness counts its built-in checks too; every corpus line is one check
    assert int(last.split()[1]) >= len(lines)
