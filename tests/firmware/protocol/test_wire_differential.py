"""Differential tests: the C decoder (ASan/UBSan) and the MicroPython runtime against CPython on a seeded corpus."""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
from pathlib import Path

import pytest
from wire_corpus import frames_fnv1a, make_corpus

from bracketry_base import paths
from bracketry_rig.wire import bproto
from bracketry_testkit import build_c_under_asan

C_DIR = paths.firmware_dir() / "protocol" / "c"
HERE = Path(__file__).resolve().parent


def _python(records: list[bytes]) -> list[tuple[list[bproto.Frame], list[int]]]:
    out = []
    for rec in records:
        dec = bproto.Decoder()
        frames = dec.feed(rec)
        out.append((frames, [dec.stats[k] for k in bproto.STAT_NAMES]))
    return out


def test_wire_c_decoder_matches_python_under_asan(tmp_path: Path) -> None:
    exe = build_c_under_asan([C_DIR / "bproto.c", C_DIR / "bproto_fuzz.c"], tmp_path / "bproto_fuzz")
    records = make_corpus(4000, seed=11)
    blob = b"".join(struct.pack("<I", len(r)) + r for r in records)
    proc = subprocess.run([str(exe)], input=blob, capture_output=True, timeout=300)
    assert proc.returncode == 0, proc.stderr.decode()[-3000:]
    rows = [[int(x) for x in line.split()] for line in proc.stdout.decode().splitlines()]
    expected = [[*stats, frames_fnv1a(frames)] for frames, stats in _python(records)]
    assert len(rows) == len(expected)
    mismatches = [i for i, (a, b) in enumerate(zip(rows, expected)) if a != b]
    assert mismatches == [], f"first mismatch: record {mismatches[0]} = {records[mismatches[0]].hex()}"
    assert sum(r[0] for r in rows) > 500  # the corpus does contain plenty of valid frames


@pytest.mark.micropython
def test_wire_micropython_decoder_matches_cpython(tmp_path: Path) -> None:
    records = make_corpus(600, seed=12)
    corpus = [[rec.hex(), [[f.msg_type, f.seq, f.payload.hex()] for f in frames], stats]
              for rec, (frames, stats) in zip(records, _python(records))]
    corpus_path = tmp_path / "corpus.json"
    corpus_path.write_text(json.dumps(corpus))
    node = shutil.which("node")
    assert node is not None
    proc = subprocess.run([node, str(HERE / "wire_mpy_run.mjs"), str(paths.micropython_module_path()),
                           str(HERE / "wire_mpy_differential.py"), str(Path(bproto.__file__)), str(corpus_path),
                           str(HERE / "wire_vectors_check.py")],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "PASS 600"
