"""Events passed between the rig's components (trigger client -> pairing -> recording, daemon -> panel).

These are plain data; the wire encoding of the trigger event is the TRIGGER message of the wire protocol
(``firmware/protocol/PROTOCOL.md``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class TriggerEvent:
    """One trigger pulse, shared by both cameras.

    Attributes:
        session_id: the START command's session id.
        trigger_seq: pulse number since START (0 for the first pulse), as sent by the device (uint32).
        bracket_index: index of the pulse's exposure in the bracket table (0..n-1).
        exposure_us: pulse width = exposure time, microseconds.
        t_start_device_us: device clock (64-bit, microseconds) at the pulse start.
        t_start_host_ns: the same instant in host time (``time.time_ns()`` epoch), through the link's clock model;
            None when no clock model is available yet.
    """

    session_id: int
    trigger_seq: int
    bracket_index: int
    exposure_us: int
    t_start_device_us: int
    t_start_host_ns: int | None = None
