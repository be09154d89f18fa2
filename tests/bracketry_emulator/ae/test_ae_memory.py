"""The process memory policy of ``bracketry emulate`` (ae/memory.py): CPython's freed arenas and frame data-stack
chunks are kept and reused instead of being unmapped and mapped again (each case in a fresh process: the policy is
process-wide)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

PROBE = """
import json, sys
from bracketry_emulator.ae.memory import reuse_freed_memory
from bracketry_emulator.extensions import optional_extension

reuse_freed_memory()

def down(n):
    return 0 if n == 0 else down(n - 1) + 1

# 400 calls deep cross data-stack chunk boundaries on the way down and free the chunks on the way up
assert sum(down(400) for _ in range(500)) == 400 * 500
garbage = [[str(i)] * 8 for i in range(200_000)]  # object-allocator arenas, freed again below
del garbage
garbage = [[str(i)] * 8 for i in range(200_000)]
assert len(garbage) == 200_000
cache = optional_extension("bracketry_emulator.ae._arena_cache")
json.dump(None if cache is None else cache.stats(), sys.stdout)
"""


def _probe(**env: str) -> dict[str, object] | None:
    out = subprocess.run([sys.executable, "-c", PROBE], env={**os.environ, **env}, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    return json.loads(out)


def test_freed_arenas_and_stack_chunks_are_reused() -> None:
    stats = _probe(BRACKETRY_NO_CKERNEL="0")
    assert stats is not None, "the _arena_cache extension was not built (setup.sh builds it)"
    assert stats["installed"]
    assert stats["reused"] >= 500  # chunks of the deep calls handed out again, not mapped afresh
    assert stats["kept"] >= stats["reused"]
    assert stats["cached_bytes"] <= 16 << 20


def test_without_the_extension_nothing_is_installed() -> None:
    assert _probe(BRACKETRY_NO_CKERNEL="1") is None
