"""A camera frame as the pairer reads it (the fields of ``bracketry_rig.cameras.camera.Frame`` it uses), for the pairing
tests, plus the pulse that really exposed it."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class PairingFrame:
    """``cam_timestamp_ns``: camera clock; ``host_receive_ns``: host clock; ``true_pulse``: the trigger pulse that
    exposed the frame in the test's own schedule (-1: not tracked), for asserting where the pairer put it."""

    side: str
    frame_id: int
    frame_index: int
    status: str
    cam_timestamp_ns: int
    host_receive_ns: int
    missing_packets: int = 0
    skipped_ids: int = 0
    exposure_us_reported: float | None = None
    trigger_seq: int | None = None
    true_pulse: int = -1
    image: object = None
