"""Camera addresses are dotted unicast IPv4 addresses, checked the same way everywhere (CLI, daemon config, camera).

A host name would be resolved by Aravis through a discovery broadcast on every interface; outside a private network
namespace nothing of ours may broadcast, so names, broadcast, multicast and unspecified addresses are refused.
"""

from __future__ import annotations

import ipaddress

from bracketry_base.errors import BracketryError


def unicast_ipv4(text: str) -> ipaddress.IPv4Address:
    """``text`` as a unicast IPv4 address in dotted form; BracketryError (one line) otherwise."""
    try:
        addr = ipaddress.IPv4Address(str(text).strip())
    except ValueError:
        raise BracketryError(f"{text!r} is not an IPv4 address (e.g. 192.168.10.11); cameras are opened by IP "
                             "only") from None
    if addr.is_multicast or addr.is_unspecified or str(addr).endswith(".255"):
        raise BracketryError(f"{text!r} is not a unicast IPv4 address")
    return addr
