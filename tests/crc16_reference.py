"""An independent CRC-16/CCITT-FALSE (bit by bit), the reference the codec tests check bproto's CRC against."""

from __future__ import annotations


def crc16_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF), one bit at a time."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc
