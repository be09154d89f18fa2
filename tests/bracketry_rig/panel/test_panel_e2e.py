"""End to end over ptys: host panel client (real SerialLink) <-> `bracketry panel simulate` running the firmware.

The screen buffer shows what the host sent; a RECORD press reaches the host exactly once although the first ACK is
lost on the wire (the firmware re-sends, the client ACKs the duplicate without acting twice); the host sees the panel
lost and rebooted; the panel shows HOST LOST when the host goes away and recovers when it returns.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bracketry_rig.panel.client import ButtonEvent, PanelClient, connect, panel_fields
from bracketry_testkit import stop_process
from panel_pty import PtyRelay, first_ack_dropper, read_screen, start_simulator, wait_for


class HostState:
    """What the 'daemon' shows on the panel (thread-safe)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.fields = panel_fields({"cam_left": 1, "cam_right": 1, "trigger": 1, "imu": 4, "lidar": 3, "gnss": 0},
                                   21.94, 22.0, 512345, 0, "READY")

    def get(self) -> dict[str, Any]:
        with self.lock:
            return dict(self.fields)

    def update(self, **kw: Any) -> None:
        with self.lock:
            self.fields.update(kw)


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[dict[str, Any]]:
    relay = PtyRelay(drop=first_ack_dropper())
    state = HostState()
    events: list[ButtonEvent] = []
    client = connect(relay.host_path, state.get, events.append, rate_hz=5.0)
    screen = tmp_path / "screen.txt"
    procs = [start_simulator(relay.panel_path, screen)]
    env = {"relay": relay, "state": state, "events": events, "client": client, "screen": screen, "procs": procs}
    try:
        yield env
    finally:
        for p in procs:
            stop_process(p)
        client.stop()
        client.link.close()
        relay.close()


def test_panel_e2e_screen_button_once_reboot(rig: dict[str, Any]) -> None:
    client: PanelClient = rig["client"]
    screen: Path = rig["screen"]
    state: HostState = rig["state"]
    events: list[ButtonEvent] = rig["events"]
    relay: PtyRelay = rig["relay"]
    # the screen buffer shows what the host sent (ERR of the lidar blinks: compare in either phase)
    def shows(lines: list[str]) -> bool:
        got = read_screen(screen)
        return got is not None and (got == lines or got == [ln.replace("ERR", "   ") for ln in lines])

    assert wait_for(lambda: shows(["L:IDL R:IDL TRIG:IDL", "IM:CAL LI:ERR GN:OFF", "21.9/22.0 512G --:--",
                                   "READY               "]), 30), read_screen(screen)
    # the HELLO is handled on the link's reader thread, which may run after the screen already shows the state
    assert wait_for(lambda: client.panel_hello is not None, 10), "the panel's boot HELLO never reached the client"
    assert client.panel_hello is not None and client.panel_hello["device_kind"] == 2
    state.update(cam_left=2, cam_right=2, trigger=2, lidar=2, rec_seconds=3725, message="REC 0001")
    assert wait_for(lambda: shows(["L:REC R:REC TRIG:REC", "IM:CAL LI:REC GN:OFF", "21.9/22.0 512G 62:05",
                                   "REC 0001            "]), 30), read_screen(screen)
    # RECORD: the first ACK is lost on the wire -> the panel re-sends -> acted on exactly once
    rig["procs"][0].stdin.write("record\n")
    rig["procs"][0].stdin.flush()
    assert wait_for(lambda: len(events) == 1 and client.counters["duplicates"] >= 1, 30), client.counters
    assert len(relay.dropped) == 1
    assert wait_for(lambda: client.counters["acks_sent"] >= 2, 10)
    threading.Event().wait(1.5)  # the panel stops re-sending once ACKed: still exactly one event
    assert [(e.button, e.action) for e in events] == [(2, 1)] and events[0].name == "RECORD short"
    dup_before = client.counters["duplicates"]
    threading.Event().wait(1.0)
    assert client.counters["duplicates"] == dup_before
    # panel reboot: the old firmware process dies, a new one boots on the same cable
    lost_before = client.counters["lost"]
    stop_process(rig["procs"][0])
    assert wait_for(lambda: client.panel_lost, 20)
    assert wait_for(lambda: client.counters["lost"] == lost_before + 1, 10) and client.status()["lost"]
    rig["procs"].append(start_simulator(relay.panel_path, screen))
    assert wait_for(lambda: client.reboots == 1 and not client.panel_lost, 30), client.status()
    # a press after the reboot is a new event even though its event_seq restarts at 0
    rig["procs"][1].stdin.write("sensors long\n")
    rig["procs"][1].stdin.flush()
    assert wait_for(lambda: len(events) == 2, 30)
    assert events[1].name == "SENSORS long" and events[1].event_seq == 0


def test_panel_e2e_host_lost_and_back(rig: dict[str, Any]) -> None:
    client: PanelClient = rig["client"]
    screen: Path = rig["screen"]
    assert wait_for(lambda: (read_screen(screen) or [""])[-1].startswith("READY"), 30)
    client.stop()
    client.link.close()
    assert wait_for(lambda: "HOST LOST" in "".join(read_screen(screen) or []) or
                    "no host for" in "".join(read_screen(screen) or []), 20), read_screen(screen)
    rig["state"].update(message="HOST BACK")
    again = connect(rig["relay"].host_path, rig["state"].get, rate_hz=2.0)
    try:
        assert wait_for(lambda: (read_screen(screen) or [""])[-1] == "HOST BACK           ", 30), read_screen(screen)
    finally:
        again.stop()
        again.link.close()
