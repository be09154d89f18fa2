"""``bracketry wire decode`` / ``bracketry wire encode``: hex, files, stdin, a live pty, and one-line errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from wire_fake_device import FakeDevice

from bracketry.cli import main
from bracketry_rig.wire import bproto, vectors


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    rc = main(["wire", *args])
    out, err = capsys.readouterr()
    return rc, out, err


def test_wire_cli_encode_matches_vectors(capsys: pytest.CaptureFixture[str]) -> None:
    """Every valid vector can be typed on the command line and gives the exact frame bytes."""
    for v in vectors.load_vectors()["valid"]:
        args = [v["type_name"], "--seq", str(v["seq"])]
        for k, val in v["fields"].items():
            args.append(f"{k}={','.join(map(str, val)) if isinstance(val, list) else val}")
        rc, out, err = run(capsys, "encode", *args)
        assert rc == 0, err
        assert out.strip() == v["frame"], v["name"]


def test_wire_cli_decode_hex_prints_fields(capsys: pytest.CaptureFixture[str]) -> None:
    frame = bproto.encode_message(bproto.MSG_NACK, 12, {"acked_seq": 4, "code": bproto.NACK_BAD_VALUE})
    rc, out, err = run(capsys, "decode", frame.hex(" "))
    assert rc == 0
    assert out.strip() == "seq=12 NACK acked_seq=4 code=3(BAD_VALUE)"
    assert "1 frames ok, 0 rejected" in err


def test_wire_cli_decode_stream_vectors_json(capsys: pytest.CaptureFixture[str]) -> None:
    """The stream vectors decoded by the CLI give the expected frames and counters (exit 1 when bytes were bad)."""
    for s in vectors.load_vectors()["streams"]:
        data = "".join(s["chunks"])
        if not data:
            continue
        rc, out, _ = run(capsys, "decode", "--json", data)
        lines = [json.loads(x) for x in out.splitlines()]
        frames = [{"msg_type": x["type"], "seq": x["seq"], "payload": x["payload"]} for x in lines[:-1]]
        assert frames == s["frames"], s["name"]
        stats = lines[-1]["stats"]
        assert {k: stats[k] for k in s["stats"]} == s["stats"], s["name"]
        assert rc == (1 if any(v for k, v in s["stats"].items() if k not in ("frames_ok", "bytes_discarded"))
                      else 0)


def test_wire_cli_decode_file_binary_and_hexdump(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = bproto.encode_message(bproto.MSG_PING, 1, {"host_time_ns": 5}) + bproto.encode_message(bproto.MSG_STOP, 2)
    raw = tmp_path / "capture.bin"
    raw.write_bytes(b"\xfe\xfe\x00" + frames)
    rc, out, err = run(capsys, "decode", str(raw))
    assert rc == 1 and out.splitlines() == ["seq=1 PING host_time_ns=5", "seq=2 STOP"]
    assert "cobs_errors=1" in err
    dump = tmp_path / "dump.txt"
    dump.write_text(frames.hex(" ") + "\n")
    rc, out, _ = run(capsys, "decode", str(dump))
    assert rc == 0 and len(out.splitlines()) == 2


def test_wire_cli_unknown_type_and_bad_payload_are_shown(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = run(capsys, "encode", "0x7e", "--payload", "01 02")
    assert rc == 0
    rc, out, _ = run(capsys, "decode", out.strip() + bproto.encode_frame(bproto.MSG_ACK, 3, b"\x01").hex())
    assert rc == 0
    lines = out.splitlines()
    assert lines[0].startswith("seq=0 0x7e payload=0102 (unknown message type")
    assert lines[1].startswith("seq=3 ACK payload=01 (wrong payload length")


@pytest.mark.parametrize("args,message", [
    (["encode", "NOPE"], "unknown message type NOPE"),
    (["encode", "ACK"], "missing field(s) for ACK: acked_seq"),
    (["encode", "ACK", "acked_seq=70000"], "out of range"),
    (["encode", "ACK", "seq=1"], "unknown field 'seq' for ACK (fields: acked_seq)"),
    (["encode", "SET_BRACKETS", "period_us=x", "exposures_us=1"], "is not an integer"),
    (["encode", "0x7e"], "use --payload HEX"),
    (["decode", "xyz"], "neither a file nor hex"),
    (["decode"], "give either SOURCE"),
    (["decode", "--port", "/nonexistent/ttyX"], "cannot open serial port /nonexistent/ttyX"),
])
def test_wire_cli_errors_are_one_line(args: list[str], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    rc, _, err = run(capsys, *args)
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err


def test_wire_cli_encode_formats_and_out_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_file = tmp_path / "f.bin"
    rc, out, _ = run(capsys, "encode", "STOP", "--seq", "7", "--format", "c", "--out", str(out_file))
    assert rc == 0 and out.startswith("{0x") and out.strip().endswith("0x00}")
    assert bproto.decode_frame(out_file.read_bytes()).seq == 7


def test_wire_cli_live_port(capsys: pytest.CaptureFixture[str]) -> None:
    """decode --port on a pty: --hello gets the device's HELLO, then its heartbeats."""
    with FakeDevice(send_hello_at_boot=False) as dev:
        rc, out, err = run(capsys, "decode", "--port", dev.path, "--hello", "--count", "2", "--duration", "20")
    assert rc == 0, err
    lines = out.splitlines()
    assert len(lines) == 2
    assert "HELLO device_kind=1(trigger)" in lines[0]
    assert "HEARTBEAT" in lines[1]


def test_wire_cli_subprocess_pipe_and_no_traceback() -> None:
    """Through the real entry point: encode | decode - ; a bad value gives one line and exit 2."""
    exe = [sys.executable, "-m", "bracketry", "wire"]
    enc = subprocess.run([*exe, "encode", "BUTTON", "button=2", "action=1", "event_seq=9"], capture_output=True,
                         text=True, timeout=120, check=True)
    dec = subprocess.run([*exe, "decode", "-"], input=enc.stdout, capture_output=True, text=True, timeout=120)
    assert dec.returncode == 0 and dec.stdout.strip() == "seq=0 BUTTON button=2 action=1 event_seq=9"
    bad = subprocess.run([*exe, "encode", "BUTTON", "button=300", "action=1", "event_seq=9"], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and bad.stderr.startswith("error: ")


def test_wire_cli_ping(capsys: pytest.CaptureFixture[str]) -> None:
    with FakeDevice(drift_ppm=50.0) as dev:
        rc, out, err = run(capsys, "ping", dev.path, "--count", "20", "--interval", "0.005", "--timeout", "1.0",
                           "--json")
    assert rc == 0, err
    result = json.loads(out)
    assert result["device"]["device_kind"] == 1 and result["device"]["uid"] == b"FAKE-DEVICE1".hex()
    assert result["clock"]["samples"] == 20
    assert result["clock"]["error_bound_us"] > result["clock"]["min_rtt_us"] / 2  # no better than its best sample
    assert result["rtt_us"]["min"] <= result["rtt_us"]["median"] <= result["rtt_us"]["max"]
    with FakeDevice() as dev:
        rc, out, _ = run(capsys, "ping", dev.path, "--count", "3", "--timeout", "1.0")
    assert rc == 0 and out.startswith("device: trigger fw 1.2.3") and "clock model: residual" in out


def test_wire_cli_ping_silent_device(capsys: pytest.CaptureFixture[str]) -> None:
    dev = FakeDevice(heartbeat=False, send_hello_at_boot=False)
    dev.silent = True
    with dev:
        rc, _, err = run(capsys, "ping", dev.path, "--count", "1", "--timeout", "0.05")
    assert rc == 2 and "no reply to HELLO" in err and err.count("\n") == 1
