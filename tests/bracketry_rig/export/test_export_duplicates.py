"""BorealHDR export of a recording where a camera delivered two frames for one trigger: one file, never two writes;
every PNG compression choice reads back as the recorded codes."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from bracketry_base.errors import BracketryError
from bracketry_base.recording import topics as T
from bracketry_rig.events import TriggerEvent
from bracketry_rig.export.borealhdr import export_borealhdr
from bracketry_rig.pairing.pairer import PairedSet
from bracketry_rig.recording.recorder import Recorder, RecorderConfig

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:mcap_ros2.reader")

BRACKETS = [1000, 2000, 4000, 8000, 16000, 32000]


def _set(k: int, version: int) -> PairedSet:
    ev = TriggerEvent(7, k, k % 6, BRACKETS[k % 6], 1_000_000 + k * 45_454, 1_700_000_000_000_000_000 + k * 45_454_000)
    rng = np.random.default_rng(k * 10 + version)
    frames = {side: SimpleNamespace(side=side, frame_id=k + 1, frame_index=k, skipped_ids=0, status="success",
                                    image=rng.integers(0, 4096, size=(120, 160), dtype=np.uint16),
                                    cam_timestamp_ns=k * 45_454_000, host_receive_ns=ev.t_start_host_ns + 9_000_000,
                                    missing_packets=0, exposure_us_reported=None) for side in T.SIDES}
    return PairedSet(k, ev, frames, ev.t_start_host_ns)


@pytest.mark.parametrize("compression", ["opencv", "stored"])
def test_a_frame_twice_is_exported_once_and_readable(tmp_path: Path, compression: str) -> None:
    rec = Recorder(tmp_path, "t", RecorderConfig(queue_max_items=1000),
                   metadata={"brackets_us": ",".join(map(str, BRACKETS)), "fps": "22.0"}).start()
    twice = {3, 4, 5, 9}
    for k in range(12):
        first = _set(k, 0)
        assert rec.put_event(first.event) and rec.put_set(first)
        if k in twice:  # the same trigger's frames again (other pixels): same time, same exposure
            assert rec.put_set(_set(k, 1))
        time.sleep(0.001)
    rec.stop()
    out = tmp_path / "tree"
    summary = export_borealhdr(rec.summary.files[0], out, workers=4, progress=False, png_compression=compression)
    assert summary.duplicates == 2 * len(twice) and summary.written == {"left": 12, "right": 12}
    for side in T.SIDES:
        for k in range(12):
            s = _set(k, 0)
            png = out / f"camera_{side}" / repr(s.event.exposure_us / 1000.0) / f"{s.event.t_start_host_ns}.png"
            img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            assert img is not None and np.array_equal(img, s.frames[side].image), png  # the first one, intact
    if compression == "stored":  # no compression: 2 bytes a pixel plus the PNG's own few hundred bytes
        assert all(160 * 120 * 2 < p.stat().st_size < 160 * 120 * 2 + 1000 for p in out.rglob("*.png"))
    with pytest.raises(BracketryError, match="unknown PNG compression"):
        export_borealhdr(rec.summary.files[0], tmp_path / "other", progress=False, png_compression="lzw")
