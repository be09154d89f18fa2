"""Status socket, state store and sd_notify, exercised for real (UNIX sockets in tmp_path)."""

from __future__ import annotations

import json
import socket
from pathlib import Path
from typing import Any

import pytest

from bracketry.cli import main
from bracketry_base import paths
from bracketry_base.errors import BracketryError
from bracketry_rig.daemon.sdnotify import Notifier
from bracketry_rig.daemon.state import RigState, SensorState
from bracketry_rig.daemon.status import StatusServer, query


def test_status_round_trip_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    state = RigState()
    state.set_state("cam_left", SensorState.REC)
    state.set_state("trigger", SensorState.ERR, "device lost")
    state.set_fps("left", 21.9)
    pressed: list[str] = []

    def handler(req: dict[str, Any]) -> dict[str, Any]:
        if req.get("cmd") == "status":
            return {"ok": True, "state": state.snapshot().to_json()}
        if req.get("cmd") == "button":
            pressed.append(req["button"])
            return {"ok": True}
        return {"ok": False, "error": "unknown cmd"}

    sock = tmp_path / "status.sock"
    server = StatusServer(sock, handler)
    try:
        reply = query(sock, {"cmd": "status"})
        assert reply["state"]["states"]["cam_left"] == "REC"
        assert reply["state"]["errors"] == {"trigger": "device lost"}
        assert query(sock, {"cmd": "button", "button": "record"}) == {"ok": True}
        assert pressed == ["record"]
        # garbage does not kill the server
        with socket.socket(socket.AF_UNIX) as s:
            s.connect(str(sock))
            s.sendall(b"not json\n")
            assert json.loads(s.recv(1000))["ok"] is False
        assert main(["status", "--socket", str(sock)]) == 0
        out = capsys.readouterr().out
        assert "cam_left=REC" in out and "error trigger: device lost" in out
        # the socket named by a config file (rig.status_socket)
        example = (paths.repo_root() / "host" / "deploy" / "rig.example.toml").read_text()
        default_line = 'status_socket = "/run/bracketry/status.sock"'
        assert default_line in example
        cfg = tmp_path / "rig.toml"
        cfg.write_text(example.replace(default_line, f'status_socket = "{sock}"', 1))
        assert main(["status", "--config", str(cfg)]) == 0
        assert "cam_left=REC" in capsys.readouterr().out
    finally:
        server.close()
    assert not sock.exists()


def test_status_without_daemon_is_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(BracketryError, match="no daemon is listening"):
        query(tmp_path / "none.sock", {"cmd": "status"})
    assert main(["status", "--socket", str(tmp_path / "none.sock")]) == 2
    assert capsys.readouterr().err.startswith("error: no daemon is listening")


def test_sd_notify_datagrams(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as recv:
        recv.bind(str(path))
        recv.settimeout(2)
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        monkeypatch.setenv("WATCHDOG_USEC", "10000000")
        n = Notifier()
        assert n.enabled and n.watchdog_interval_s == 5.0
        assert n.ready() and n.watchdog()
        assert recv.recv(100) == b"READY=1"
        assert recv.recv(100) == b"WATCHDOG=1"
    monkeypatch.delenv("NOTIFY_SOCKET")
    assert Notifier().ready() is False


def test_sd_notify_never_blocks_on_a_listener_that_does_not_read(tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "notify.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as recv:
        recv.bind(str(path))
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        n = Notifier()
        sent = [n.watchdog() for _ in range(200)]  # the datagram queue (max_dgram_qlen) fills: False, no hang
        assert sent[0] and not all(sent)
        assert n.stopping() is False
        assert recv.recv(100) == b"WATCHDOG=1"


def test_state_snapshot_and_message_truncation() -> None:
    st = RigState()
    st.set_message("x" * 30)
    st.count("drops_left", 2)
    snap = st.snapshot()
    assert snap.message == "x" * 20
    assert snap.counters == {"drops_left": 2}
    assert all(v == SensorState.OFF for v in snap.states.values())
    with pytest.raises(KeyError):
        st.set_state("sonar", SensorState.IDLE)
