"""The monitor's listen address: ``HOST:PORT`` parsing and the loopback test (no server imports here)."""

from __future__ import annotations

import ipaddress


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv4 address) -> (host, port); ValueError naming the problem."""
    host, sep, port_s = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"expected HOST:PORT, e.g. 127.0.0.1:8470, got {text!r}")
    try:
        ipaddress.IPv4Address(host)
    except ValueError:
        raise ValueError(f"{host!r} is not an IPv4 address") from None
    if not port_s.isdigit() or not 0 <= int(port_s) <= 65535:
        raise ValueError(f"port must be 0..65535 (0: any free port), got {port_s!r}")
    return host, int(port_s)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8 (reading the page needs no token there)."""
    return ipaddress.IPv4Address(host).is_loopback
