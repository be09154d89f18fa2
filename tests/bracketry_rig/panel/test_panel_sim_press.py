"""A simulated press reaches the firmware even when its main loop scans the buttons less often than a press lasts.

The firmware is run in-process on a pty with an idle hook that makes each loop iteration take 0.25 s (a starved
process on a busy machine): a fixed 0.15 s press would be sampled once or never and lost by the debounce.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

from bracketry_rig.panel.sim import PanelSimulator

BUTTON_RECORD = 2
BUTTON_SENSORS = 1
ACTION_SHORT = 1
ACTION_LONG = 2


def test_presses_reach_a_slow_firmware_loop(tmp_path: Path) -> None:
    host_fd, board_fd = os.openpty()
    sim = PanelSimulator(os.ttyname(board_fd), tmp_path / "screen.txt")
    publish = sim._publish

    def slow_publish(app: Any) -> None:
        publish(app)
        time.sleep(0.25)

    sim._publish = slow_publish  # type: ignore[method-assign]
    result: dict[str, Any] = {}
    loop = threading.Thread(target=lambda: result.update(app=sim.run()), daemon=True)
    loop.start()
    try:
        deadline = time.monotonic() + 20
        while sim.app is None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sim.app is not None, "the firmware never ran its loop"
        sim.handle_command("record")
        sim.handle_command("sensors long")
        sim.handle_command("record")
        actions = [(b, a) for b, a, _seq in sim.app.events]
        assert actions == [(BUTTON_RECORD, ACTION_SHORT), (BUTTON_SENSORS, ACTION_LONG),
                           (BUTTON_RECORD, ACTION_SHORT)], actions
        assert not any(b.pressed for b in sim.app.buttons)
    finally:
        sim.stop()
        loop.join(10)
        os.close(host_fd)
        os.close(board_fd)
    assert not loop.is_alive()
