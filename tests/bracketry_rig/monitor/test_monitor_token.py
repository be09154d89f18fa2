"""The monitor on a non-loopback address refuses requests without the right token (checked in a private network
namespace, so nothing listens beyond this machine's loopback); a loopback address serves the page without one."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from bracketry_rig.cameras.netns import netns_argv, netns_available
from bracketry_rig.monitor.address import is_loopback, parse_listen
from bracketry_rig.monitor.server import TOKEN_ALPHABET, new_token
from bracketry_testkit import missing_component

HERE = Path(__file__).resolve().parent


def test_listen_addresses_and_tokens() -> None:
    assert parse_listen("127.0.0.1:8470") == ("127.0.0.1", 8470)
    assert is_loopback("127.0.0.1") and not is_loopback("192.168.4.1") and not is_loopback("0.0.0.0")
    for bad in ("8470", "localhost:8470", "127.0.0.1:99999", "127.0.0.1:http", ":80"):
        with pytest.raises(ValueError):
            parse_listen(bad)
    tokens = {new_token() for _ in range(50)}
    assert len(tokens) == 50 and all(len(t) == 10 and set(t) <= set(TOKEN_ALPHABET) for t in tokens)


def test_token_is_required_beyond_loopback(tmp_path: Path) -> None:
    reason = netns_available()
    if reason:
        missing_component(f"private network namespace unavailable: {reason}")
    res = subprocess.run(netns_argv([sys.executable, str(HERE / "token_check.py"), str(tmp_path)], ("10.77.0.1",)),
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    r = json.loads(res.stdout.strip().splitlines()[-1])
    assert r["message"] == f"WEB KEY {r['token']}"  # the LCD's message line shows the token
    for name in ("page", "status", "apply"):
        assert r[f"{name}_none"][0] == 401, r
        assert r[f"{name}_wrong"][0] == 403, r
    assert r["page_query"][0] == 200 and r["status_right"][0] == 200
    assert r["status_right"][1]["sensors"]["cam_left"] == "OFF"
    assert r["apply_too_long"][0] == 400 and "does not fit" in r["apply_too_long"][1]["error"], r
    assert r["apply_right"] == [200, {"ok": True, "brackets_us": [500, 1000, 2000]}]
    assert r["brackets_after"] == [500, 1000, 2000]
    assert r["sensors_on"] == [200, {"ok": True, "sensors_ok": False}]
    assert r["sensors_on_status"]["trigger"] == "ERR" and r["sensors_on_status"]["cam_left"] == "ERR"
    assert r["record_start"][0] == 200 and r["record_start"][1]["segment_started"] is False, r["record_start"]
    assert r["apply_recording"][0] == 409 and r["sensors_off_recording"][0] == 409
    assert r["record_stop"][0] == 200 and r["sensors_off"][0] == 200
    assert r["unknown"][0] == 400


def test_simulate_monitor_port_in_use_is_a_one_line_error(tmp_path: Path) -> None:
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        res = subprocess.run([sys.executable, "-m", "bracketry", "simulate", "--out", str(tmp_path / "sim"),
                              "--monitor", str(port), "--no-world"], capture_output=True, text=True, timeout=60)
    assert res.returncode != 0
    assert f"--monitor {port}: cannot listen on 127.0.0.1:{port}" in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
