"""The serial wire protocol (bproto v1): codec, host link layer, clock model.

- :mod:`bracketry_rig.wire.bproto`: the codec, one module shared with the MicroPython panel firmware.
- :mod:`bracketry_rig.wire.link`: :class:`SerialLink` (pyserial; ports, ``socket://``, ptys).
- :mod:`bracketry_rig.wire.clock`: :class:`ClockModel` (device microseconds -> host nanoseconds).
- :mod:`bracketry_rig.wire.vectors`: the shared test vectors of ``firmware/protocol/protocol_vectors.json``.

The specification is ``firmware/protocol/PROTOCOL.md``.
"""

from bracketry_rig.wire import bproto
from bracketry_rig.wire.errors import DeviceLostError, LinkClosedError, NackError, WireError

__all__ = ["DeviceLostError", "LinkClosedError", "NackError", "WireError", "bproto"]
