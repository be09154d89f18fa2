"""The compiled hot loops of the synthetic world's frames (``_kernels.c``, built with the package): the ray caster's
nearest trunk hits and their shading (render.py) and a noisy exposure from pre-drawn normals (camera_model.py), each
bit for bit what the numpy path beside its call computes (the fallback)."""

from __future__ import annotations

import importlib
import os
from typing import Any

_MODULE: Any = None
_TRIED = False


def synth_kernels() -> Any:
    """The ``_kernels`` extension module, or None when it was not built or ``BRACKETRY_NO_CKERNEL=1`` (then numpy
    computes the same values)."""
    global _MODULE, _TRIED
    if not _TRIED:
        _TRIED = True
        if os.environ.get("BRACKETRY_NO_CKERNEL") != "1":
            try:
                _MODULE = importlib.import_module(f"{__package__}._kernels")
            except ImportError:
                _MODULE = None
    return _MODULE


def use_kernels(enabled: bool) -> None:
    """Use the compiled loops (when built) or force the numpy paths, e.g. to compare both in one process."""
    global _MODULE, _TRIED
    _MODULE, _TRIED = None, not enabled
