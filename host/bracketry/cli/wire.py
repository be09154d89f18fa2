"""``bracketry wire``: decode and encode bproto frames by hand (hex, capture files, a live serial port)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    EXIT_PROBLEMS,
    Duration,
    Integer,
    Number,
    count,
    option,
    output_file,
    overwrite_option,
    positive,
)
from bracketry_rig.wire import bproto
from bracketry_rig.wire.errors import WireError
from bracketry_rig.wire.text import (
    describe_frame,
    describe_stats,
    frame_to_json,
    looks_like_hex_text,
    parse_fields,
    parse_hex,
)


@click.group("wire")
def command() -> None:
    """Encode and decode frames of the serial wire protocol (firmware/protocol/PROTOCOL.md)."""


def _emit(frame: bproto.Frame, as_json: bool, t_s: float | None = None) -> None:
    if as_json:
        obj = frame_to_json(frame)
        if t_s is not None:
            obj["t_s"] = round(t_s, 6)
        click.echo(json.dumps(obj))
    else:
        prefix = f"{t_s:10.3f}s " if t_s is not None else ""
        click.echo(prefix + describe_frame(frame))


def _summary(dec: bproto.Decoder, as_json: bool, frames: int | None = None, n_bytes: int = 0) -> int:
    """Print the decoder counters; exit 1 when bytes were rejected, or when input bytes held no complete frame."""
    if as_json:
        click.echo(json.dumps({"stats": dec.stats}))
    if frames == 0 and n_bytes:
        click.echo(f"error: the {n_bytes} input byte(s) hold no complete frame (a frame ends with a 0x00 delimiter; "
                   f"{describe_stats(dec.stats)})", err=True)
        return EXIT_PROBLEMS
    if not as_json:
        click.echo(describe_stats(dec.stats), err=True)
    return EXIT_PROBLEMS if dec.errors else EXIT_OK


def _read_input(source: str) -> bytes:
    if source == "-":
        data = sys.stdin.buffer.read()
        return parse_hex(data.decode("ascii")) if looks_like_hex_text(data) else data
    path = Path(source)
    try:
        is_file = path.is_file()
    except OSError:  # e.g. a long hex string is too long for a file name
        is_file = False
    if is_file:
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise BracketryError(f"cannot read {path}: {exc.strerror}") from exc
        return parse_hex(data.decode("ascii")) if looks_like_hex_text(data) else data
    try:
        return parse_hex(source)
    except ValueError as exc:
        raise BracketryError(f"{source!r} is neither a file nor hex ({exc})") from exc


@command.command("decode")
@click.argument("source", required=False)
@click.option("--port", help="Read a live serial port (path or pyserial URL such as socket://127.0.0.1:5000).")
@click.option("--baud", type=Integer(300, 16_000_000), default=921600, show_default=True, help="Baud rate of --port.")
@option("--duration-s", "duration_s", aliases=("--duration",), type=Duration(), default=None,
        help="With --port: stop after this many seconds.")
@click.option("--count", type=count(1), default=None, help="With --port: stop after this many frames.")
@click.option("--hello", "send_hello", is_flag=True, help="With --port: send a HELLO request first.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per frame, then the decoder counters.")
def decode(source: str | None, port: str | None, baud: int, duration_s: float | None, count: int | None,
           send_hello: bool, as_json: bool) -> int:
    """Print every frame in SOURCE (hex string, a file with raw bytes or a hex dump, or - for stdin) or on --port.

    Each valid frame is one line of readable fields; rejected bytes are counted in the summary (stderr).
    Exit code 0 when nothing was rejected, 1 when bytes were rejected or SOURCE holds no complete frame.
    """
    if (source is None) == (port is None):
        raise BracketryError("give either SOURCE (hex, file or -) or --port")
    dec = bproto.Decoder()
    if source is not None:
        data = _read_input(source)
        n = 0
        for frame in dec.feed(data):
            _emit(frame, as_json)
            n += 1
        return _summary(dec, as_json, n, len(data))
    assert port is not None
    from bracketry_rig.wire.link import open_serial

    try:
        ser = open_serial(port, baud)
    except WireError as exc:
        raise BracketryError(str(exc)) from exc
    n = 0
    t0 = time.monotonic()
    try:
        if send_hello:
            ser.write(b"\x00" + bproto.encode_message(bproto.MSG_HELLO, 0, {}))
        while (duration_s is None or time.monotonic() - t0 < duration_s) and (count is None or n < count):
            data = ser.read(max(1, ser.in_waiting))
            for frame in dec.feed(data):
                _emit(frame, as_json, time.monotonic() - t0)
                n += 1
                if count is not None and n >= count:
                    break
    except KeyboardInterrupt:
        pass
    except OSError as exc:
        raise BracketryError(f"{port}: {exc}") from exc
    finally:
        ser.close()
    return _summary(dec, as_json)


@command.command("encode")
@click.argument("msg_type", metavar="TYPE")
@click.argument("fields", nargs=-1)
@click.option("--seq", type=Integer(0, 0xFFFF), default=0, show_default=True, help="Sequence number (0..65535).")
@click.option("--payload", "payload_hex", help="Raw payload in hex instead of fields (any type, even unknown).")
@click.option("--format", "fmt", type=click.Choice(["hex", "spaced", "c"]), default="hex", show_default=True,
              help="hex: one hex string; spaced: bytes separated by spaces; c: a C array initialiser.")
@click.option("--out", "out_path", type=output_file(), help="Also write the raw frame bytes to this file.")
@overwrite_option()
@click.option("--port", help="Also send the frame to this serial port (path or pyserial URL).")
def encode(msg_type: str, fields: tuple[str, ...], seq: int, payload_hex: str | None, fmt: str,
           out_path: Path | None, overwrite: bool, port: str | None) -> int:
    """Build one frame: TYPE is a name (PING, SET_BRACKETS, ...) or a number, FIELDS are name=value.

    \b
    Examples:
      bracketry wire encode PING host_time_ns=123
      bracketry wire encode SET_BRACKETS period_us=50000 exposures_us=1000,2000,4000
      bracketry wire encode PANEL_STATE cam_left=REC cam_right=REC trigger=IDLE imu=OFF lidar=OFF gnss=OFF \\
          free_disk_mb=1000 fps_left_centi=1000 fps_right_centi=1000 rec_seconds=0 'message=hello'
    """
    try:
        t = bproto.type_by_name(msg_type)
    except ValueError as exc:
        raise BracketryError(f"{exc} (known: {', '.join(bproto.MSG_NAMES.values())})") from exc
    try:
        if payload_hex is not None:
            if fields:
                raise ValueError("give either --payload or fields, not both")
            frame = bproto.encode_frame(t, seq, parse_hex(payload_hex))
        else:
            if t not in bproto.MSG_NAMES:
                raise ValueError(f"type 0x{t:02x} has no known fields: use --payload HEX")
            frame = bproto.encode_message(t, seq, parse_fields(t, list(fields)))
    except ValueError as exc:
        raise BracketryError(str(exc)) from exc
    if fmt == "hex":
        click.echo(frame.hex())
    elif fmt == "spaced":
        click.echo(frame.hex(" "))
    else:
        click.echo("{" + ", ".join(f"0x{b:02x}" for b in frame) + "}")
    if out_path is not None:
        try:
            out_path.write_bytes(frame)
        except OSError as exc:
            raise BracketryError(f"cannot write {out_path}: {exc.strerror}") from exc
    if port is not None:
        from bracketry_rig.wire.link import open_serial

        try:
            ser = open_serial(port)
        except WireError as exc:
            raise BracketryError(str(exc)) from exc
        try:
            ser.write(frame)
            ser.flush()
        finally:
            ser.close()
    return 0


@command.command("ping")
@click.argument("port")
@click.option("--baud", type=Integer(300, 16_000_000), default=921600, show_default=True, help="Baud rate.")
@click.option("--count", type=count(1, 100000), default=32, show_default=True,
              help="Number of PING/PONG exchanges.")
@option("--interval-s", "interval_s", aliases=("--interval",), type=Number(0.0, 60.0), default=0.02,
        show_default=True, help="Seconds between PINGs.")
@option("--timeout-s", "timeout_s", aliases=("--timeout",), type=positive(60.0), default=0.1, show_default=True,
        help="Reply timeout per attempt (s).")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON.")
def ping(port: str, baud: int, count: int, interval_s: float, timeout_s: float, as_json: bool) -> int:
    """Check a live link: HELLO, then COUNT PINGs; print round trips, the clock model and the link counters."""
    import statistics

    from bracketry_rig.wire.link import SerialLink

    try:
        link = SerialLink(port, baud, heartbeat_period_s=None, reconnect=False, name=port)
    except WireError as exc:
        raise BracketryError(str(exc)) from exc
    rtts_us: list[float] = []
    try:
        info = link.hello(timeout_s=timeout_s)
        for _ in range(count):
            t0 = time.perf_counter()
            link.ping(timeout_s=timeout_s)
            rtts_us.append((time.perf_counter() - t0) * 1e6)
            time.sleep(interval_s)
        clock = link.clock.summary()
        counters = link.counters
    except WireError as exc:
        raise BracketryError(str(exc)) from exc
    finally:
        link.close()
    rtt = {"min": min(rtts_us), "median": statistics.median(rtts_us), "max": max(rtts_us)}
    nonzero = {k: v for k, v in counters.items() if v}
    result = {"device": {k: (v.hex() if isinstance(v, bytes) else v) for k, v in info.items()},
              "rtt_us": rtt, "clock": clock, "counters": nonzero}
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return 0
    kind = {bproto.DEVICE_TRIGGER: "trigger", bproto.DEVICE_PANEL: "panel"}.get(info["device_kind"], "unknown")
    click.echo(f"device: {kind} fw {info['fw_major']}.{info['fw_minor']}.{info['fw_patch']} "
               f"uid {info['uid'].hex()} proto 1.{info['proto_minor']}")
    click.echo(f"round trip: min {rtt['min']:.0f} us, median {rtt['median']:.0f} us, max {rtt['max']:.0f} us "
               f"({count} pings)")
    click.echo(f"clock model: residual {clock['residual_us']:.1f} us, error bound {clock['error_bound_us']:.0f} us, "
               f"drift {clock['drift_ppm']:+.1f} ppm "
               f"({clock['fit_samples']} of {clock['samples']} samples)")
    click.echo("counters: " + " ".join(f"{k}={v}" for k, v in sorted(nonzero.items())))
    return 0
