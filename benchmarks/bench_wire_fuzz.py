"""Fuzz benchmark of the bproto decoders: random and mutated frames through C (ASan/UBSan) and Python.

Builds firmware/protocol/c/bproto_fuzz.c twice with host gcc (ASan/UBSan, and -O2 for speed), generates a corpus of
independent records (valid frames, mutated frames in several categories, crafted frames with a valid CRC but a
wrong length/version, pure garbage), then:

- feeds every record to a fresh C decoder under the sanitizers: the process must exit 0 (no crash, no sanitizer
  report; every decoded frame is re-encoded and decoded again inside the harness);
- feeds every record to a fresh Python decoder (``bracketry_rig.wire.bproto``): must never raise;
- checks C and Python agree record by record (frames and every counter);
- checks every corrupted record is rejected (no decoded frame differs from the original frame);
- prints Python decoder frames/s (median of repeats), C -O2 frames/s, and their ratio.

Usage: ``.venv/bin/python benchmarks/bench_wire_fuzz.py [--quick] [--frames N] [--seed S]``.
"""

from __future__ import annotations

import argparse
import random
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

from bracketry_base import paths
from bracketry_rig.wire import bproto

sys.path.insert(0, str(paths.repo_root() / "tests" / "firmware" / "protocol"))
# the per-record digest the C fuzz harness prints, shared with the tests
from wire_corpus import frames_fnv1a

C_DIR = paths.firmware_dir() / "protocol" / "c"

#: mutation categories: name -> weight
MUTATIONS = {"bit_flip": 3, "byte_substitution": 3, "burst_2_bytes": 2, "multi_byte_random": 2, "truncate": 2,
             "insert_byte": 1, "delete_byte": 1, "insert_zero": 1, "splice_two_frames": 1, "swap_bytes": 1,
             "crafted_bad_length": 1, "crafted_bad_version": 1}


def _random_valid(rng: random.Random) -> tuple[bytes, tuple[int, int, bytes]]:
    """A valid frame: half real messages with random fields, half random type/payload."""
    if rng.random() < 0.5:
        t = rng.choice([bproto.MSG_ACK, bproto.MSG_NACK, bproto.MSG_HEARTBEAT, bproto.MSG_PING, bproto.MSG_PONG,
                        bproto.MSG_START, bproto.MSG_TRIGGER, bproto.MSG_BUTTON, bproto.MSG_SET_BRACKETS])
        if t == bproto.MSG_SET_BRACKETS:
            exposures_us = [rng.randrange(1 << 32) for _ in range(rng.randint(1, 16))]
            payload = bproto.pack_payload(t, {"period_us": rng.randrange(1 << 32), "exposures_us": exposures_us})
        else:
            payload = bytes(rng.randrange(256) for _ in range(len(bproto.pack_payload(t, _zero_fields(t)))))
    else:
        t = rng.randrange(256)
        n = rng.choice([0, 1, 2, 8, rng.randrange(256), 253, 254, 255])
        payload = bytes(rng.randrange(256) if rng.random() < 0.8 else 0 for _ in range(n))
    seq = rng.randrange(65536)
    return bproto.encode_frame(t, seq, payload), (t, seq, payload)


def _zero_fields(t: int) -> dict[str, object]:
    return {n: (b"" if n == "uid" else "" if n == "message" else 0) for n in bproto.field_names(t)}


def _mutate(frame: bytes, kind: str, rng: random.Random, other: bytes) -> bytes:
    body = bytearray(frame[:-1])  # mutate the encoded bytes, keep the delimiter
    n = len(body)
    if kind == "bit_flip":
        i = rng.randrange(n)
        body[i] ^= 1 << rng.randrange(8)
        if body[i] == 0:  # would create a delimiter: flip another bit instead
            body[i] ^= 1 << ((rng.randrange(7) + 1) % 8) | 1
    elif kind == "byte_substitution":
        i = rng.randrange(n)
        v = rng.randrange(1, 256)
        body[i] = v if v != body[i] else (v % 255) + 1
    elif kind == "burst_2_bytes":
        i = rng.randrange(max(1, n - 1))
        for j in (i, min(i + 1, n - 1)):
            v = rng.randrange(1, 256)
            body[j] = v if v != body[j] else (v % 255) + 1
    elif kind == "multi_byte_random":
        for i in rng.sample(range(n), min(n, rng.randint(3, 8))):
            v = rng.randrange(1, 256)
            body[i] = v if v != body[i] else (v % 255) + 1
    elif kind == "truncate":
        del body[rng.randrange(1, n):]
    elif kind == "insert_byte":
        body.insert(rng.randrange(n + 1), rng.randrange(1, 256))
    elif kind == "delete_byte":
        del body[rng.randrange(n)]
    elif kind == "insert_zero":
        body.insert(rng.randrange(1, n), 0)
    elif kind == "splice_two_frames":
        cut = rng.randrange(1, n)
        body = body[:cut] + bytearray(other[rng.randrange(1, len(other) - 1):-1])
    elif kind == "swap_bytes":
        i, j = rng.sample(range(n), 2)
        if body[i] == body[j]:
            body[i] = (body[i] % 255) + 1
        body[i], body[j] = body[j], body[i]
    elif kind in ("crafted_bad_length", "crafted_bad_version"):
        dec = bytearray(bproto.cobs_decode(bytes(body)))
        if kind == "crafted_bad_length":
            good = struct.unpack_from("<H", dec, 4)[0]
            choices = [v for v in (good + 1, good - 1, 256, 0xFFFF, rng.randrange(65536)) if v != good and v >= 0]
            struct.pack_into("<H", dec, 4, rng.choice(choices))
        else:
            dec[0] = rng.choice([0, 2, 3, 0xFF])
        dec[-2:] = struct.pack("<H", bproto.crc16(bytes(dec[:-2])))  # CRC made valid on purpose
        return bproto.cobs_encode(bytes(dec)) + b"\x00"
    return bytes(body) + b"\x00"


Content = tuple[int, int, bytes]


def build_corpus(n_frames: int, seed: int) -> tuple[list[bytes], list[str], list[list[Content]]]:
    """Records, their category, and the (type, seq, payload) contents a record may legitimately decode to: the
    original of a valid record; for a splice whose bytes happen to equal the other frame exactly, that frame."""
    rng = random.Random(seed)
    records: list[bytes] = []
    kinds: list[str] = []
    originals: list[list[Content]] = []
    names = list(MUTATIONS)
    weights = [MUTATIONS[k] for k in names]
    while len(records) < n_frames:
        frame, orig = _random_valid(rng)
        r = rng.random()
        if r < 0.2:
            records.append(frame)
            kinds.append("valid")
            originals.append([orig])
        elif r < 0.9:
            kind = rng.choices(names, weights)[0]
            other, other_orig = _random_valid(rng)
            mutated = _mutate(frame, kind, rng, other)
            records.append(mutated)
            kinds.append(kind)
            originals.append([other_orig] if mutated == other else [])
        else:
            n = rng.choice([rng.randrange(1, 40), rng.randrange(40, 300), rng.randrange(300, 1200)])
            records.append(bytes(rng.randrange(256) for _ in range(n)))
            kinds.append("garbage")
            originals.append([])
    return records, kinds, originals




def python_pass(records: list[bytes]) -> tuple[list[list[bproto.Frame]], list[tuple[int, ...]], float]:
    frames: list[list[bproto.Frame]] = []
    stats: list[tuple[int, ...]] = []
    t0 = time.perf_counter()
    for rec in records:
        dec = bproto.Decoder()
        frames.append(dec.feed(rec))
        stats.append(tuple(dec.stats[k] for k in bproto.STAT_NAMES))
    return frames, stats, time.perf_counter() - t0


def build_c(out_dir: Path, sanitize: bool) -> Path:
    gcc = shutil.which("gcc")
    if gcc is None:
        sys.exit("gcc not found")
    exe = out_dir / ("bproto_fuzz_asan" if sanitize else "bproto_fuzz_o2")
    flags = ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer"] \
        if sanitize else ["-O2"]
    subprocess.run([gcc, "-std=c99", "-Wall", "-Wextra", "-Werror", *flags, str(C_DIR / "bproto.c"),
                    str(C_DIR / "bproto_fuzz.c"), "-o", str(exe)], check=True)
    return exe


def c_pass(exe: Path, blob: bytes) -> tuple[int, list[tuple[int, ...]], float, str]:
    t0 = time.perf_counter()
    proc = subprocess.run([str(exe)], input=blob, capture_output=True, timeout=1200)
    dt = time.perf_counter() - t0
    rows = [tuple(int(x) for x in line.split()) for line in proc.stdout.decode().splitlines()]
    return proc.returncode, rows, dt, proc.stderr.decode()[-2000:]


_MPY_TIMER = """
import time
import bproto
with open("/stream.bin", "rb") as fh:
    data = fh.read()
dec = bproto.Decoder()
t0 = time.ticks_us()
n = 0
for i in range(0, len(data), 256):
    n += len(dec.feed(data[i:i + 256]))
dt = time.ticks_diff(time.ticks_us(), t0)
print("MPY", n, dt)
"""


def micropython_rate(stream: bytes, tmp: Path) -> tuple[int, float] | None:
    """(frames, seconds) of the real MicroPython WebAssembly runtime decoding ``stream`` in 256-byte reads."""
    node = shutil.which("node")
    mjs = paths.micropython_module_path()
    runner = Path(__file__).resolve().parents[1] / "tests" / "firmware" / "protocol" / "wire_mpy_run.mjs"
    if node is None or not mjs.exists() or not runner.exists():
        return None
    (tmp / "stream.bin").write_bytes(stream)
    (tmp / "timer.py").write_text(_MPY_TIMER)
    cmd = [node, str(runner), str(mjs), str(tmp / "timer.py"), bproto.__file__, str(tmp / "stream.bin")]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    for line in proc.stdout.splitlines():
        if line.startswith("MPY "):
            _, n, dt_us = line.split()
            return int(n), int(dt_us) / 1e6
    print("MicroPython run failed:", proc.stderr[-500:])
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="20,000 records, one Python repeat")
    ap.add_argument("--frames", type=int, default=None,
                    help="number of records (default 150,000: >= 100,000 random or mutated)")
    ap.add_argument("--seed", type=int, default=20261122)
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats of the Python pass (default 3)")
    args = ap.parse_args()
    n = args.frames or (20_000 if args.quick else 150_000)
    repeats = args.repeats or (1 if args.quick else 3)

    t0 = time.perf_counter()
    records, kinds, originals = build_corpus(n, args.seed)
    total_bytes = sum(len(r) for r in records)
    print(f"corpus: {n} records, {total_bytes / 1e6:.1f} MB, built in {time.perf_counter() - t0:.1f} s")
    print("  " + ", ".join(f"{k}={v}" for k, v in Counter(kinds).most_common()))

    # Python: correctness + timing
    times = []
    py_frames: list[list[bproto.Frame]] = []
    py_stats: list[tuple[int, ...]] = []
    py_crash = 0
    for _ in range(repeats):
        try:
            py_frames, py_stats, dt = python_pass(records)
        except Exception as exc:  # the decoder must never raise
            py_crash += 1
            print(f"PYTHON DECODER RAISED: {exc!r}")
            break
        times.append(dt)
    py_med = statistics.median(times) if times else float("nan")

    # one continuous stream of the valid frames (the realistic case): frames/s
    valid_stream = b"".join(r for r, k in zip(records, kinds) if k == "valid")
    n_valid = kinds.count("valid")
    st_times = []
    for _ in range(repeats):
        dec = bproto.Decoder()
        t1 = time.perf_counter()
        got = 0
        for i in range(0, len(valid_stream), 4096):  # 4 KiB reads, as from a serial port
            got += len(dec.feed(valid_stream[i:i + 4096]))
        st_times.append(time.perf_counter() - t1)
        assert got == n_valid, (got, n_valid)
    st_med = statistics.median(st_times)

    # the same stream through the pure-Python CRC/COBS code paths (what MicroPython runs), under CPython
    fast_paths = (bproto.crc16, bproto.cobs_decode)
    bproto.crc16, bproto.cobs_decode = bproto.crc16_table, bproto.cobs_decode_py
    try:
        pure_times = []
        for _ in range(repeats):
            dec = bproto.Decoder()
            t1 = time.perf_counter()
            got = sum(len(dec.feed(valid_stream[i:i + 4096])) for i in range(0, len(valid_stream), 4096))
            pure_times.append(time.perf_counter() - t1)
            assert got == n_valid
    finally:
        bproto.crc16, bproto.cobs_decode = fast_paths
    pure_med = statistics.median(pure_times)

    # rejection of corrupted records (Python)
    undetected: Counter[str] = Counter()
    per_kind: Counter[str] = Counter(kinds)
    valid_lost = 0
    for frames, kind, orig in zip(py_frames, kinds, originals):
        decoded = [(f.msg_type, f.seq, f.payload) for f in frames]
        if kind == "valid":
            valid_lost += decoded != orig
        elif any(d not in orig for d in decoded):  # a frame that is not exactly a frame that was sent
            undetected[kind] += 1

    blob = b"".join(struct.pack("<I", len(r)) + r for r in records)
    with tempfile.TemporaryDirectory() as tmp:
        asan = build_c(Path(tmp), sanitize=True)
        fast = build_c(Path(tmp), sanitize=False)
        rc, c_rows, c_asan_s, c_err = c_pass(asan, blob)
        c_times = []
        for _ in range(repeats):
            _rc, _rows, dt, _err = c_pass(fast, blob)
            c_times.append(dt)
        mpy_valid = [r for r, k in zip(records, kinds) if k == "valid"][:3000]
        mpy = micropython_rate(b"".join(mpy_valid), Path(tmp))
    c_med = statistics.median(c_times)

    py_rows = [(*s, frames_fnv1a(f)) for s, f in zip(py_stats, py_frames)]
    disagree = sum(a != b for a, b in zip(py_rows, c_rows)) + abs(len(py_rows) - len(c_rows))

    print()
    print(f"C decoder under ASan/UBSan: exit code {rc} ({'no crash, no sanitizer report' if rc == 0 else 'CRASH'}),"
          f" {len(c_rows)} records, {c_asan_s:.2f} s")
    if rc != 0:
        print(c_err)
    print(f"Python decoder: {py_crash} exceptions")
    print(f"C vs Python, record by record (frames + all counters): {disagree} disagreements of {n}")
    print(f"valid records not decoded exactly: {valid_lost} of {n_valid}")
    print("corrupted records accepted with altered content (per category):")
    for k in MUTATIONS:
        print(f"  {k:<20} {undetected[k]:>5} of {per_kind[k]}")
    same = sum(1 for k, o in zip(kinds, originals) if k in MUTATIONS and o)
    n_corrupt = sum(per_kind[k] for k in MUTATIONS) - same
    print(f"  {'garbage':<20} {undetected['garbage']:>5} of {per_kind['garbage']}")
    print(f"  {'total':<20} {sum(undetected.values()):>5} of {n_corrupt + per_kind['garbage']}")
    if same:
        print(f"  ({same} splices reproduced another complete valid frame byte for byte: not corruption)")
    print()
    print(f"speed (median of {repeats}):")
    print(f"  Python, fresh decoder per record: {n / py_med:>12,.0f} frames/s  "
          f"({total_bytes / py_med / 1e6:.1f} MB/s)")
    print(f"  Python, continuous stream:        {n_valid / st_med:>12,.0f} frames/s  "
          f"({len(valid_stream) / st_med / 1e6:.1f} MB/s)")
    print(f"  Python, continuous stream, pure-Python CRC+COBS (MicroPython code path): {n_valid / pure_med:>10,.0f}"
          " frames/s")
    if mpy is not None:
        print(f"  MicroPython (WebAssembly runtime, Node), continuous stream: {mpy[0] / mpy[1]:>10,.0f} frames/s"
              f"  ({mpy[0]} frames)")
    print(f"  C -O2 (incl. process + re-encode check): {n / c_med:>12,.0f} frames/s")
    print(f"  ratio C / Python (per record):     {py_med / c_med:.1f}x")
    ok = rc == 0 and py_crash == 0 and disagree == 0 and valid_lost == 0 and sum(undetected.values()) == 0
    print("RESULT:", "PASS" if ok else "FAIL")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
