"""Pixel formats (PFNC codes) and conversion of raw GVSP payloads to uint16 images.

All images returned here are ``numpy.ndarray`` of dtype ``uint16`` and shape ``(height, width)`` holding the sensor
codes LSB-aligned (12-bit formats: 0..4095). Packed formats are unpacked with vectorised numpy (no per-pixel
Python loops).

BayerRG12p (PFNC, "LSB-first" packing, code 0x010C0059): two pixels in three bytes,
``p0 = b0 | (b1 & 0x0F) << 8`` and ``p1 = (b1 >> 4) | b2 << 4``.
BayerRG12Packed (GigE Vision legacy, 0x010C002B) uses a different layout and is not supported.
"""

from __future__ import annotations

import numpy as np

#: PFNC pixel-format codes (GenICam Pixel Format Naming Convention)
PIXEL_FORMAT_CODES: dict[str, int] = {
    "Mono8": 0x01080001,
    "Mono16": 0x01100007,
    "BayerRG8": 0x01080009,
    "BayerRG12": 0x01100011,
    "BayerRG12p": 0x010C0059,
    "BayerRG12Packed": 0x010C002B,
}
PIXEL_FORMAT_NAMES: dict[int, str] = {code: name for name, code in PIXEL_FORMAT_CODES.items()}

#: bits per pixel on the wire
BITS_PER_PIXEL: dict[str, int] = {"Mono8": 8, "BayerRG8": 8, "Mono16": 16, "BayerRG12": 16, "BayerRG12p": 12}


def payload_bytes(pixel_format: str, width: int, height: int) -> int:
    """Size in bytes of one image of ``width`` x ``height`` pixels in ``pixel_format`` (no chunk data)."""
    bits = BITS_PER_PIXEL[pixel_format] * width * height
    return (bits + 7) // 8


def unpack_bayer_rg12p(raw: bytes | bytearray | memoryview | np.ndarray, width: int, height: int) -> np.ndarray:
    """Unpack a PFNC BayerRG12p payload into a ``(height, width)`` uint16 image of 12-bit codes.

    ``raw`` must hold at least ``width * height * 3 / 2`` bytes (``width * height`` even); extra bytes (chunk data)
    are ignored.
    """
    n_pixels = width * height
    if n_pixels % 2:
        raise ValueError(f"BayerRG12p needs an even pixel count, got {width}x{height}")
    n_bytes = n_pixels * 3 // 2
    buf = np.frombuffer(raw, dtype=np.uint8) if not isinstance(raw, np.ndarray) else raw.view(np.uint8).ravel()
    if buf.size < n_bytes:
        raise ValueError(f"BayerRG12p payload too short: {buf.size} bytes for {width}x{height} (need {n_bytes})")
    triplets = buf[:n_bytes].reshape(-1, 3).astype(np.uint16)
    out = np.empty((n_pixels // 2, 2), dtype=np.uint16)
    out[:, 0] = triplets[:, 0] | ((triplets[:, 1] & 0x0F) << 8)
    out[:, 1] = (triplets[:, 1] >> 4) | (triplets[:, 2] << 4)
    return out.reshape(height, width)


def pack_bayer_rg12p(image: np.ndarray) -> bytes:
    """Pack a uint16 image of 12-bit codes (values above 4095 are an error) into PFNC BayerRG12p bytes."""
    flat = np.ascontiguousarray(image, dtype=np.uint16).ravel()
    if flat.size % 2:
        raise ValueError("BayerRG12p needs an even pixel count")
    if flat.size and int(flat.max()) > 0x0FFF:
        raise ValueError("BayerRG12p holds 12-bit codes only (max 4095)")
    pairs = flat.reshape(-1, 2)
    out = np.empty((pairs.shape[0], 3), dtype=np.uint8)
    out[:, 0] = pairs[:, 0] & 0xFF
    out[:, 1] = ((pairs[:, 0] >> 8) & 0x0F) | ((pairs[:, 1] & 0x0F) << 4)
    out[:, 2] = pairs[:, 1] >> 4
    return out.tobytes()


def payload_to_image(raw: bytes | memoryview | np.ndarray, pixel_format: str, width: int, height: int) -> np.ndarray:
    """Convert a raw payload to a ``(height, width)`` uint16 image (a copy; the buffer can be re-queued at once).

    Mono16/BayerRG12 are little-endian 16-bit words (12-bit codes stay LSB-aligned); 8-bit formats are widened.
    """
    buf = np.frombuffer(raw, dtype=np.uint8) if not isinstance(raw, np.ndarray) else raw.view(np.uint8).ravel()
    if pixel_format == "BayerRG12p":
        return unpack_bayer_rg12p(buf, width, height)
    need = payload_bytes(pixel_format, width, height)
    if buf.size < need:
        raise ValueError(f"{pixel_format} payload too short: {buf.size} bytes for {width}x{height} (need {need})")
    if BITS_PER_PIXEL[pixel_format] == 16:
        return buf[:need].view("<u2").reshape(height, width).astype(np.uint16, copy=True)
    if BITS_PER_PIXEL[pixel_format] == 8:
        return buf[:need].reshape(height, width).astype(np.uint16)
    raise ValueError(f"unsupported pixel format {pixel_format}")
