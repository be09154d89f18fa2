"""The optional compiled extensions (``_lut12``, ``_pngcodec``, ``_zhang_terms``, ``_upstream_kernels``, synth's
``_kernels``): each is built with the package where a C compiler is available (pyproject.toml), and every caller keeps
a numpy / OpenCV path that gives the same results where it is not.

:func:`optional_extension` imports one once per process and returns None when it was not built or when the
environment variable ``BRACKETRY_NO_CKERNEL`` is ``1`` (read at the first look-up; the fallbacks then run
everywhere). Tests and benchmarks that compare both paths in one process use :func:`extensions_disabled` (the
fallbacks inside the block, the compiled paths again after it); :func:`clear_extension_cache` forgets every look-up,
so that the next one reads ``BRACKETRY_NO_CKERNEL`` again.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

#: Set to ``1`` to run every fallback instead of the compiled extensions.
NO_CKERNEL_ENV = "BRACKETRY_NO_CKERNEL"

_MODULES: dict[str, ModuleType | None] = {}
_DISABLED = 0  # depth of nested extensions_disabled() blocks


def optional_extension(name: str) -> ModuleType | None:
    """The extension module ``name`` (full dotted name, e.g. ``"bracketry_emulator.emulation._lut12"``), or None
    when it was not built, when ``BRACKETRY_NO_CKERNEL=1`` or inside :func:`extensions_disabled`. Looked up once."""
    if _DISABLED:
        return None
    try:
        return _MODULES[name]
    except KeyError:
        pass
    module: ModuleType | None = None
    if os.environ.get(NO_CKERNEL_ENV) != "1":
        try:
            module = importlib.import_module(name)
        except ImportError:
            module = None
    _MODULES[name] = module
    return module


def clear_extension_cache() -> None:
    """Forget every look-up: the next :func:`optional_extension` call reads ``BRACKETRY_NO_CKERNEL`` again."""
    _MODULES.clear()


@contextmanager
def extensions_disabled() -> Iterator[None]:
    """Within the block :func:`optional_extension` returns None for every extension, so the fallbacks run (in every
    thread of the process); after it the looked-up modules are used again. Blocks may nest."""
    global _DISABLED
    _DISABLED += 1
    try:
        yield
    finally:
        _DISABLED -= 1
