"""Run the shared bproto vectors against a bproto module; runs under CPython AND MicroPython (no typing, no f-strings).

CPython: ``import wire_vectors_check; wire_vectors_check.run(bproto, vectors)``. MicroPython: executed as a script
with ``bproto.py`` and ``protocol_vectors.json`` in ``/`` (see wire_mpy_run.mjs); it prints ``PASS <n>`` or raises.
"""

def _unhex(s):
    out = bytearray()
    for i in range(0, len(s), 2):
        out.append(int(s[i:i + 2], 16))
    return bytes(out)


def _hex(b):
    return "".join("{:02x}".format(x) for x in b)  # noqa: UP032 (older MicroPython lacks f-strings)


def _fields_to_json(fields):
    out = {}
    for k in fields:
        v = fields[k]
        out[k] = _hex(v) if isinstance(v, (bytes, bytearray)) else v
    return out


def _fields_from_json(fields):
    out = {}
    for k in fields:
        out[k] = _unhex(fields[k]) if k == "uid" else fields[k]
    return out


def run(bproto, vectors):
    """Check every vector; returns ``(number_of_checks, list_of_failure_strings)``."""
    fails = []
    n = 0
    for c in vectors["crc16"]:
        n += 1
        if bproto.crc16(_unhex(c["data"])) != c["crc"]:
            fails.append("crc16 " + c["data"][:16])
        if bproto.crc16_table(_unhex(c["data"])) != c["crc"]:
            fails.append("crc16_table " + c["data"][:16])
    for c in vectors["cobs"]:
        n += 1
        if bproto.cobs_encode(_unhex(c["decoded"])) != _unhex(c["encoded"]):
            fails.append("cobs_encode " + c["decoded"][:16])
        if bproto.cobs_decode(_unhex(c["encoded"])) != _unhex(c["decoded"]):
            fails.append("cobs_decode " + c["encoded"][:16])
    for v in vectors["valid"]:
        n += 1
        fields = _fields_from_json(v["fields"])
        payload = bproto.pack_payload(v["msg_type"], fields)
        if payload != _unhex(v["payload"]):
            fails.append("pack_payload " + v["name"])
        frame = bproto.encode_message(v["msg_type"], v["seq"], fields)
        if frame != _unhex(v["frame"]):
            fails.append("encode_message " + v["name"])
        dec = bproto.Decoder()
        frames = dec.feed(_unhex(v["frame"]))
        if len(frames) != 1:
            fails.append("decode " + v["name"])
            continue
        f = frames[0]
        if (f.ver, f.msg_type, f.seq, f.payload) != (1, v["msg_type"], v["seq"], _unhex(v["payload"])):
            fails.append("decoded frame " + v["name"])
        if _fields_to_json(bproto.unpack_payload(f.msg_type, f.payload)) != v["fields"]:
            fails.append("unpack_payload " + v["name"])
        if bproto.MSG_NAMES[v["msg_type"]] != v["type_name"]:
            fails.append("type name " + v["name"])
    for s in vectors["streams"]:
        n += 1
        dec = bproto.Decoder()
        got = []
        for chunk in s["chunks"]:
            for f in dec.feed(_unhex(chunk)):
                got.append({"msg_type": f.msg_type, "seq": f.seq, "payload": _hex(f.payload)})
        if got != s["frames"]:
            fails.append("stream frames " + s["name"])
        for k in bproto.STAT_NAMES:
            if dec.stats[k] != s["stats"][k]:
                fails.append("stream " + s["name"] + " " + k + " = " + str(dec.stats[k]) + " expected "
                             + str(s["stats"][k]))
    for p in vectors["payload_errors"]:
        n += 1
        try:
            bproto.unpack_payload(p["msg_type"], _unhex(p["payload"]))
            fails.append("unpack_payload accepted " + p["name"])
        except ValueError:
            pass
        if bproto.nack_code_for(p["msg_type"], _unhex(p["payload"])) != p["nack"]:
            fails.append("nack_code_for " + p["name"])
    for r in vectors["set_brackets_checks"]:
        n += 1
        if bproto.check_set_brackets(r["period_us"], r["exposures_us"]) != r["nack"]:
            fails.append("check_set_brackets " + str(r["period_us"]) + " " + str(r["exposures_us"]))
    return n, fails


if __name__ == "__main__":
    import json

    import bproto as _bproto

    with open("/protocol_vectors.json") as fh:
        _vectors = json.load(fh)
    _n, _fails = run(_bproto, _vectors)
    for _f in _fails:
        print("FAIL " + _f)
    if _fails:
        raise AssertionError(str(len(_fails)) + " vector failures")
    print("PASS " + str(_n))
