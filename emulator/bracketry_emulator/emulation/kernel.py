"""The emulation kernel: apply a 4096-entry lookup table to a 12-bit image, and a cache of tables.

Because the emulation formula is a per-pixel function of an integer code, one table per (source exposure, factor)
gives bit-identical output to evaluating the formula per pixel, > 100x faster than the authors' two
``scipy.interpolate.interp1d`` calls per pixel.

The gather is a small C extension, ``_lut12`` (``_lut12.c`` next to this file), built with the package (setuptools
compiles it at install time; nothing is compiled or written at run time). It releases the GIL and reads the uint16
codes as they are, where numpy's ``take`` first widens them to 64-bit indices, which costs 2-3x. Where the extension
was not built (a machine without a C compiler at install time), or with ``BRACKETRY_NO_CKERNEL=1``, numpy's ``take``
is used; both give identical results.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..crf.response import N_CODES, Response, Rounding
from ..extensions import optional_extension

Gather = Callable[[object, object, object], None]


def c_kernel() -> Gather | None:
    """The compiled gather ``gather(lut, src, dst)`` of the ``_lut12`` extension, or None when the extension was not
    built (or ``BRACKETRY_NO_CKERNEL=1``; :func:`..extensions.optional_extension`)."""
    module = optional_extension(f"{__package__}._lut12")
    return None if module is None else module.gather  # type: ignore[no-any-return]


def code_counts() -> Callable[[object, int], tuple[int, int]] | None:
    """The compiled ``code_counts(src, code) -> (pixels >= code, pixels == 0)`` of the ``_lut12`` extension (one
    pass over a C-contiguous uint16 buffer), or None as :func:`c_kernel`."""
    module = optional_extension(f"{__package__}._lut12")
    return None if module is None else module.code_counts  # type: ignore[no-any-return]


#: Pixels per chunk: small enough for the cache, large enough to amortise the call.
CHUNK_PIXELS = 1 << 18
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=min(2, os.cpu_count() or 1), thread_name_prefix="bracketry-lut")
    return _POOL


def _take_chunks(lut: np.ndarray, src: np.ndarray, dst: np.ndarray) -> None:
    fn = c_kernel() if (lut.dtype == np.uint16 and src.dtype == np.uint16 and lut.flags.c_contiguous) else None
    if fn is not None:
        fn(lut, src, dst)
        return
    for s in range(0, src.size, CHUNK_PIXELS):
        np.take(lut, src[s:s + CHUNK_PIXELS], out=dst[s:s + CHUNK_PIXELS], mode="clip")


def apply_lut(lut: np.ndarray, image: np.ndarray, out: np.ndarray | None = None, threads: bool = True
              ) -> np.ndarray:
    """``lut[image]`` for a uint16 (4096,) table and a uint16 HxW image of codes 0..4095 -> uint16 HxW.

    Uses the compiled C gather when available (memory-bound: one thread is fastest), else numpy ``take`` in
    cache-sized chunks on two threads for large images (``take`` releases the GIL).
    Input must be 12-bit codes (the C path masks to 12 bits, numpy clips).
    """
    if lut.shape != (N_CODES,):
        raise ValueError(f"lut must have {N_CODES} entries, got {lut.shape}")
    src = np.ascontiguousarray(image)
    lut = np.ascontiguousarray(lut)
    if out is None or not out.flags.c_contiguous or out.shape != src.shape or out.dtype != lut.dtype:
        out = np.empty(src.shape, dtype=lut.dtype)
    flat_src, flat_dst = src.reshape(-1), out.reshape(-1)
    use_c = c_kernel() is not None and lut.dtype == np.uint16 and src.dtype == np.uint16
    if use_c or not threads or flat_src.size < 4 * CHUNK_PIXELS or (os.cpu_count() or 1) < 2:
        _take_chunks(lut, flat_src, flat_dst)
        return out
    half = (flat_src.size // 2 // CHUNK_PIXELS + 1) * CHUNK_PIXELS
    futures = [_pool().submit(_take_chunks, lut, flat_src[a:b], flat_dst[a:b])
               for a, b in ((0, half), (half, flat_src.size))]
    for f in futures:
        f.result()
    return out


class LutCache:
    """Emulation tables per (factor, rounding) for one response, least recently used first out."""

    def __init__(self, response: Response, max_entries: int = 512) -> None:
        self.response = response
        self.max_entries = max_entries
        self._tables: OrderedDict[tuple[float, str], np.ndarray] = OrderedDict()

    def get(self, factor: float, rounding: Rounding) -> np.ndarray:
        """uint16 (4096,) table: code -> f(factor * f^-1(code)) with the given rounding."""
        key = (float(factor), rounding)
        table = self._tables.get(key)
        if table is None:
            table = self.response.lut(factor, rounding)
            self._tables[key] = table
            if len(self._tables) > self.max_entries:
                self._tables.popitem(last=False)
        else:
            self._tables.move_to_end(key)
        return table
