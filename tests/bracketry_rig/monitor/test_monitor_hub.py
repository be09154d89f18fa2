"""The preview hub (bounded, drop-oldest, rate-limited hand-off) and the [monitor] config table."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from bracketry_rig.cameras.camera import Frame
from bracketry_rig.daemon.config import ConfigError, parse_config
from bracketry_rig.events import TriggerEvent
from bracketry_rig.monitor.hub import PreviewHub
from bracketry_rig.pairing.pairer import PairedSet


def paired(seq: int, bracket: int, image: np.ndarray) -> PairedSet:
    ev = TriggerEvent(1, seq, bracket, 1000 << bracket, seq * 1000, time.time_ns())
    frames = {side: Frame(side, seq + 1, seq, 0, "success", image, image.shape[1], image.shape[0], "BayerRG12",
                          0, time.time_ns()) for side in ("left", "right")}
    return PairedSet(seq, ev, frames, time.time_ns())


def test_offer_is_rate_limited_per_camera_and_bracket_and_drops_oldest() -> None:
    hub = PreviewHub(rate_hz=1.0, max_items=4)
    img = np.full((40, 64), 1000, np.uint16)
    for seq in range(12):  # 2 cycles of 6 brackets within a second: only the first cycle is taken
        hub.offer(paired(seq, seq % 6, img))
    assert hub.dropped == 8  # 12 frames taken (6 brackets x 2 sides) through a 4-item queue
    assert hub.drain() == 4
    latest = hub.latest()
    assert sorted(latest) == [("left", 4), ("left", 5), ("right", 4), ("right", 5)]  # the newest four survived
    p = latest[("left", 5)]
    rgb = cv2.imdecode(np.frombuffer(p.png, np.uint8), cv2.IMREAD_COLOR)
    assert rgb.shape == (20, 32, 3) and p.exposure_us == 32000 and p.version == 1
    assert sum(p.histogram) == 20 * 32 and p.over == 0.0 and p.under == 0.0
    hub.offer(paired(12, 5, img))  # within the period: not taken
    assert hub.drain() == 0
    hub.clear()
    assert hub.latest() == {}


def test_a_set_without_event_or_pixels_is_ignored() -> None:
    hub = PreviewHub()
    pset = paired(0, 0, np.zeros((8, 8), np.uint16))
    hub.offer(PairedSet(0, None, pset.frames, 0))
    hub.offer(PairedSet(0, pset.event, {"left": None}, 0))
    assert hub.drain() == 0


BASE = {"rig": {"output_dir": "/tmp/x", "brackets_ms": [1, 2], "fps": 20},
        "cameras": [{"side": "left", "profile": "basler_ace2", "address": "10.0.0.2"},
                    {"side": "right", "profile": "basler_ace2", "address": "10.0.0.3"}]}


def test_monitor_config() -> None:
    assert parse_config(BASE).monitor is None
    mc = parse_config({**BASE, "monitor": {}}).monitor
    assert mc is not None and mc.listen == "127.0.0.1:8470" and mc.bayer and mc.white_dn == 4095
    with pytest.raises(ConfigError, match=r"monitor.listen: 'rig' is not an IPv4 address"):
        parse_config({**BASE, "monitor": {"listen": "rig:80"}})
    with pytest.raises(ConfigError, match=r"monitor.preview_hz: must be within"):
        parse_config({**BASE, "monitor": {"preview_hz": 50}})
    with pytest.raises(ConfigError, match=r"monitor.port: unknown key"):
        parse_config({**BASE, "monitor": {"port": 80}})
