"""The daemon in-process with the trigger simulator on a pty and an Aravis fake camera on 127.0.0.1: a camera that
cannot start its stream at RECORD goes ERR, its empty segment is removed and the daemon keeps running."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from bracketry_base.paths import repo_root
from bracketry_rig.daemon.config import parse_config
from bracketry_rig.daemon.rig import DaemonOptions, RigDaemon
from bracketry_rig.daemon.state import SensorState

pytestmark = pytest.mark.aravis

SIM_CONFIG = repo_root() / "host" / "deploy" / "rig.simulated.toml"


def test_a_camera_that_cannot_stream_at_record_goes_err_and_leaves_no_segment(tmp_path: Path) -> None:
    from bracketry_rig.cameras.fake import FakeCameraServer
    from bracketry_rig.trigger.simulator import simulate_on_pty

    data = tomllib.loads(SIM_CONFIG.read_text())
    data["rig"].update(output_dir=str(tmp_path / "rec"), status_socket=str(tmp_path / "status.sock"))
    data["panel"]["enabled"] = False
    sim, port = simulate_on_pty(tmp_path / "trigger")
    data["trigger"]["port"] = port
    data["cameras"][0]["address"] = "127.0.0.1"  # left: the fake camera; right: nobody there (ERR at SENSORS)
    server = FakeCameraServer("127.0.0.1", "STREAMFAIL1").start()
    daemon = RigDaemon(parse_config(data, "test"), DaemonOptions(width=160, height=100))
    try:
        daemon.on_button("sensors")
        states = daemon.state.snapshot().states
        assert states["cam_left"] == SensorState.IDLE and states["trigger"] == SensorState.IDLE
        assert states["cam_right"] == SensorState.ERR
        daemon.cameras["left"].device.leave_control()  # GVCP writes still work, streaming does not
        daemon.on_button("record")  # must not raise
        snap = daemon.state.snapshot()
        assert snap.states["cam_left"] == SensorState.ERR and "left" not in daemon.cameras
        assert "Controller privilege required" in snap.errors["cam_left"]
        assert snap.message == "REC WAITING" and daemon.recording and daemon.segment_index == 0
        assert not [p for p in (tmp_path / "rec").rglob("*") if p.is_file()]  # the empty segment was removed
    finally:
        daemon.close()
        server.stop()
        sim.close()
    assert not daemon.recording
