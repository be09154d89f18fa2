"""A seeded corpus of byte streams for differential tests: valid frames, mutated frames, garbage, concatenations."""

from __future__ import annotations

import random

from bracketry_rig.wire import bproto


def frames_fnv1a(frames: list[bproto.Frame]) -> int:
    """32-bit FNV-1a over each frame's type, seq (LE), payload length (LE) and payload: the digest the C fuzz
    harness prints per record, so the C, CPython and MicroPython decoders can be compared record by record."""
    h = 2166136261
    for f in frames:
        for b in (f.msg_type, f.seq & 0xFF, f.seq >> 8, len(f.payload) & 0xFF, len(f.payload) >> 8, *f.payload):
            h = ((h ^ b) * 16777619) & 0xFFFFFFFF
    return h


def make_corpus(n: int, seed: int) -> list[bytes]:
    """``n`` independent records (bytes), each to be fed to a fresh decoder."""
    rng = random.Random(seed)
    out: list[bytes] = []

    def frame() -> bytes:
        size = rng.choice([0, 2, 5, 8, 21, 38, rng.randrange(256), 255])
        payload = bytes(0 if rng.random() < 0.15 else rng.randrange(1, 256) for _ in range(size))
        return bproto.encode_frame(rng.randrange(256), rng.randrange(65536), payload)

    while len(out) < n:
        kind = rng.randrange(6)
        if kind == 0:
            rec = frame()
        elif kind == 1:  # byte substitutions
            b = bytearray(frame())
            for _ in range(rng.randint(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            rec = bytes(b)
        elif kind == 2:  # truncation / deletion / insertion
            b = bytearray(frame())
            i = rng.randrange(len(b))
            op = rng.randrange(3)
            if op == 0:
                del b[i:]
            elif op == 1:
                del b[i]
            else:
                b.insert(i, rng.randrange(256))
            rec = bytes(b)
        elif kind == 3:  # garbage
            rec = bytes(rng.randrange(256) for _ in range(rng.choice([1, 10, 100, 270, 600])))
        elif kind == 4:  # several frames with garbage between
            rec = b"".join(frame() + bytes(rng.randrange(256) for _ in range(rng.randrange(4)))
                           for _ in range(rng.randint(2, 4)))
        else:  # long runs without a delimiter, then a frame
            rec = bytes([rng.randrange(1, 256)]) * rng.choice([264, 265, 266, 300]) + b"\x00" + frame()
        out.append(rec)
    return out
