"""The compiled hot loops of the synthetic world's frames (``_kernels.c``, built with the package): the ray caster's
nearest trunk hits and their shading (render.py) and a noisy exposure from pre-drawn normals (camera_model.py), each
bit for bit what the numpy path beside its call computes (the fallback)."""

from __future__ import annotations

from typing import Any

from bracketry_emulator.extensions import optional_extension


def synth_kernels() -> Any:
    """The ``_kernels`` extension module, or None when it was not built or ``BRACKETRY_NO_CKERNEL=1`` (then numpy
    computes the same values; :func:`bracketry_emulator.extensions.optional_extension`)."""
    return optional_extension(f"{__package__}._kernels")
