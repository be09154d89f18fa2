"""MicroPython side of the differential test: decode every record of /corpus.json and compare with CPython's result.

The corpus file holds ``[[record_hex, frames, stats], ...]`` with ``frames`` as ``[[type, seq, payload_hex], ...]``
and ``stats`` as the 7 counters in STAT order. Prints ``PASS <n>`` or raises.
"""
import json

import bproto
from wire_vectors_check import _hex, _unhex

with open("/corpus.json") as fh:
    corpus = json.load(fh)
bad = 0
for rec_hex, frames, stats in corpus:
    dec = bproto.Decoder()
    rec = _unhex(rec_hex)
    got = []
    # feed in uneven chunks, as from a UART
    i = 0
    step = 1
    while i < len(rec):
        for f in dec.feed(rec[i:i + step]):
            got.append([f.msg_type, f.seq, _hex(f.payload)])
        i += step
        step = step * 3 % 17 + 1
    if got != frames or [dec.stats[k] for k in bproto.STAT_NAMES] != stats:
        bad += 1
        if bad < 5:
            print("MISMATCH " + rec_hex[:40])
if bad:
    raise AssertionError(str(bad) + " records differ")
print("PASS " + str(len(corpus)))
