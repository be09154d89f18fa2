"""Camera response functions on 12-bit codes: sRGB model, TUM pcalib files (TUM or upstream lifting), calibration.

Python API::

    from bracketry_emulator.crf import load_response
    resp = load_response("srgb")                      # the BorealHDR sample's sRGB-encoded codes (default)
    resp = load_response("calibration/pcalib_inside1.txt", lifting="upstream")
    lut = resp.lut(0.5)                               # uint16 (4096,) emulation table for t_target / t_source = 0.5
"""

from __future__ import annotations

from pathlib import Path

from .pcalib import Lifting, load_pcalib, pcalib256_from_icrf, response_from_pcalib, save_pcalib
from .response import (
    N_CODES,
    SATURATED_CODE,
    Response,
    SrgbResponse,
    TableResponse,
    UpstreamResponse,
    srgb_eotf,
    srgb_oetf,
)

__all__ = [
    "N_CODES",
    "SATURATED_CODE",
    "Lifting",
    "Response",
    "SrgbResponse",
    "TableResponse",
    "UpstreamResponse",
    "load_pcalib",
    "load_response",
    "pcalib256_from_icrf",
    "response_from_pcalib",
    "save_pcalib",
    "srgb_eotf",
    "srgb_oetf",
]


def load_response(spec: str | Path = "srgb", lifting: Lifting = "tum") -> Response:
    """``"srgb"`` -> :class:`SrgbResponse`; a path -> the pcalib file with the given lifting."""
    if isinstance(spec, str) and spec.lower() == "srgb":
        return SrgbResponse()
    path = Path(spec)
    return response_from_pcalib(load_pcalib(path), lifting=lifting, name=path.name)
