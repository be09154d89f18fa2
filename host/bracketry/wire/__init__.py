"""The serial wire protocol (bproto v1): codec, host link layer, clock model.

- :mod:`bracketry.wire.bproto`: the codec, one module shared with the MicroPython panel firmware.
- :mod:`bracketry.wire.link`: :class:`SerialLink` (pyserial; ports, ``socket://``, ptys).
- :mod:`bracketry.wire.clock`: :class:`ClockModel` (device microseconds -> host nanoseconds).
- :mod:`bracketry.wire.vectors`: the shared test vectors of ``firmware/protocol/protocol_vectors.json``.

The specification is ``firmware/protocol/PROTOCOL.md``.
"""

from bracketry.wire import bproto
from bracketry.wire.errors import DeviceLostError, LinkClosedError, NackError, WireError

__all__ = ["DeviceLostError", "LinkClosedError", "NackError", "WireError", "bproto"]
