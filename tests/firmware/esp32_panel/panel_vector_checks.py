"""The shared protocol vectors (firmware/protocol/protocol_vectors.json) fed to the panel firmware's link.

Runs unchanged under MicroPython and CPython with the firmware folder, bproto.py and protocol_vectors.json on the
path / in the working folder. Prints ``PASS <name>`` per check.
"""

import json

import bproto
import panel_app


def _load_vectors():
    for path in ("/protocol_vectors.json", "protocol_vectors.json"):
        try:
            with open(path) as fh:
                return json.loads(fh.read())
        except OSError:
            pass
    raise OSError("protocol_vectors.json not found")


V = _load_vectors()
UID = b"\x24\x6f\x28\xa1\xb2\xc3"


def unhex(s):
    return bytes([int(s[i:i + 2], 16) for i in range(0, len(s), 2)])


class Sink:
    def __init__(self):
        self.dec = bproto.Decoder()
        self.frames = []

    def write(self, data):
        self.frames.extend(self.dec.feed(data))


def fresh():
    sink = Sink()
    app = panel_app.PanelApp(sink.write, UID, 0, device_us=lambda: 42)
    del sink.frames[:]  # the boot HELLO
    return sink, app


def check_valid_host_frames():
    n = 0
    for v in V["valid"]:
        sink, app = fresh()
        frame = unhex(v["frame"])
        t = v["msg_type"]
        if t == bproto.MSG_PANEL_STATE:
            app.step(10, frame)
            assert [f.msg_type for f in sink.frames] == [bproto.MSG_ACK], v["name"]
            assert bproto.unpack_payload(bproto.MSG_ACK, sink.frames[0].payload)["acked_seq"] == v["seq"]
            assert app.screen_name == "status"
            assert app.screen[3] == (v["fields"]["message"] + " " * 20)[:20], (app.screen, v["name"])
            n += 1
        elif t == bproto.MSG_PING:
            app.step(10, frame)
            assert [f.msg_type for f in sink.frames] == [bproto.MSG_PONG]
            pong = bproto.unpack_payload(bproto.MSG_PONG, sink.frames[0].payload)
            assert pong["host_time_ns"] == v["fields"]["host_time_ns"] and pong["device_time_us"] == 42
            n += 1
        elif v["name"] == "hello_request":
            app.step(10, frame)
            assert [f.msg_type for f in sink.frames] == [bproto.MSG_HELLO]
            hello = bproto.unpack_payload(bproto.MSG_HELLO, sink.frames[0].payload)
            assert hello["device_kind"] == bproto.DEVICE_PANEL and hello["uid"][:6] == UID
            n += 1
        elif t in (bproto.MSG_HEARTBEAT, bproto.MSG_ACK):
            app.step(10, frame)  # keeps the host alive, no reply
            assert sink.frames == [] and app.link.last_host_ms == 10, v["name"]
            n += 1
    assert n >= 7, n


def check_payload_errors_nacked():
    n = 0
    for v in V["payload_errors"]:
        t = v["msg_type"]
        if t in bproto.MSG_NAMES and t not in (bproto.MSG_PANEL_STATE, bproto.MSG_PING, bproto.MSG_HELLO):
            continue  # not a panel command (the panel answers UNKNOWN_TYPE or ignores replies)
        sink, app = fresh()
        app.step(10, bproto.encode_frame(t, 77, unhex(v["payload"])))
        got = [bproto.unpack_payload(f.msg_type, f.payload) for f in sink.frames if f.msg_type == bproto.MSG_NACK]
        assert got == [{"acked_seq": 77, "code": v["nack"]}], (v["name"], got)
        n += 1
    assert n >= 4, n


def check_streams_through_panel_decoder():
    for v in V["streams"]:
        _sink, app = fresh()
        t = 10
        for chunk in v["chunks"]:
            app.link.feed(unhex(chunk), t)
            t += 1
        stats = app.link.decoder_stats
        for key in v["stats"]:
            assert stats[key] == v["stats"][key], (v["name"], key, stats[key], v["stats"][key])
        assert app.link.counters["frames_in"] == len(v["frames"]), v["name"]


def check_panel_messages_encode_like_vectors():
    for v in V["valid"]:
        if v["msg_type"] in (bproto.MSG_BUTTON, bproto.MSG_HEARTBEAT) or v["name"] == "hello_panel":
            fields = {}
            for k in v["fields"]:
                fields[k] = unhex(v["fields"][k]) if k == "uid" else v["fields"][k]
            assert bproto.encode_message(v["msg_type"], v["seq"], fields) == unhex(v["frame"]), v["name"]


for check in (check_valid_host_frames, check_payload_errors_nacked, check_streams_through_panel_decoder,
              check_panel_messages_encode_like_vectors):
    check()
    print("PASS " + check.__name__)
