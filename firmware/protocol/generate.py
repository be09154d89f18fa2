#!/usr/bin/env python3
"""Write the message bindings of bproto from the one message table ``messages.json`` (next to this file).

Generated, between ``BEGIN GENERATED <part>`` / ``END GENERATED <part>`` markers in each file:

- ``PROTOCOL.md``: the message table of section 3 and the value rules;
- ``c/bproto.h``: version, message types, NACK codes, device kinds, payload lengths, value-rule constants, one struct
  per message, the pack/unpack/check prototypes and the any-message union;
- ``c/bproto.c``: the pack/unpack functions (byte offsets computed here), the per-message value checks and the
  type dispatch;
- ``host/bracketry_rig/wire/bproto.py``: the same constants and the ``struct`` layouts the Python codec (CPython and
  MicroPython) packs and unpacks with.

Everything outside the markers (framing, CRC, COBS, the streaming decoder, the SET_BRACKETS rule's logic) is written
by hand. Usage::

    python firmware/protocol/generate.py          # rewrite the generated parts (make protocol)
    python firmware/protocol/generate.py --check  # exit 1 naming every stale file
                                                   # (tests/firmware/protocol/test_wire_generated.py)

Standard library only: it runs before any virtual environment exists.
"""

from __future__ import annotations

import argparse
import json
import re
import struct
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
TABLE = HERE / "messages.json"
TARGETS = {
    "md": HERE / "PROTOCOL.md",
    "h": HERE / "c" / "bproto.h",
    "c": HERE / "c" / "bproto.c",
    "py": REPO / "host" / "bracketry_rig" / "wire" / "bproto.py",
}
_INT = {"u8": ("B", "uint8_t", 1), "u16": ("H", "uint16_t", 2), "u32": ("I", "uint32_t", 4),
        "u64": ("Q", "uint64_t", 8)}
_ORIGIN = "by firmware/protocol/generate.py from messages.json: do not edit (make protocol)"
_MARK = {"md": "<!-- {} -->", "h": "/* {} */", "c": "/* {} */", "py": "# {}"}


class TableError(Exception):
    """The message table is inconsistent."""


# --------------------------------------------------------------------------------------------------- the table
def load(path: Path = TABLE) -> dict:
    """The message table with derived facts per message: ``fmt`` (struct format of the fixed part), ``size`` (fixed
    part in bytes), ``array`` (the variable-array field or None), ``offsets`` (byte offset of every fixed field)."""
    table = json.loads(path.read_text(encoding="utf-8"))
    seen: set[int] = set()
    for msg in table["messages"]:
        if msg["type"] in seen or not 0 <= msg["type"] <= 255:
            raise TableError(f"message {msg['name']}: duplicate or out-of-range type {msg['type']}")
        seen.add(msg["type"])
        fmt, offset, msg["array"], msg["offsets"] = "<", 0, None, {}
        for i, f in enumerate(msg["fields"]):
            kind = f["type"]
            if kind.endswith("]"):
                elem, count = kind[:-1].split("[")
                if i != len(msg["fields"]) - 1 or elem not in _INT:
                    raise TableError(f"{msg['name']}.{f['name']}: an array must be the last field, of an int type")
                counts = [g for g in msg["fields"] if g.get("count_of") == f["name"]]
                if len(counts) != 1 or counts[0]["name"] != count or counts[0]["type"] != "u8":
                    raise TableError(f"{msg['name']}.{f['name']}: needs exactly one u8 count field named {count}")
                msg["array"] = {"field": f, "elem": elem, "count": count}
                continue
            msg["offsets"][f["name"]] = offset
            if kind in _INT:
                fmt += _INT[kind][0]
                offset += _INT[kind][2]
            elif kind in ("bytes", "ascii"):
                fmt += f"{f['size']}s"
                offset += f["size"]
            else:
                raise TableError(f"{msg['name']}.{f['name']}: unknown type {kind}")
        if struct.calcsize(fmt) != offset:
            raise TableError(f"{msg['name']}: layout {fmt} is not {offset} bytes")
        msg["fmt"], msg["size"] = fmt, offset
    return table


def _lower(msg: dict) -> str:
    return str(msg["name"]).lower()


def _size_const(f: dict) -> str:
    return str(f.get("const") or f["name"].upper() + "_LEN")


def _fixed(msg: dict) -> list[dict]:
    return [f for f in msg["fields"] if not f["type"].endswith("]")]


def _maxed(msg: dict) -> list[dict]:
    return [f for f in msg["fields"] if "max" in f]


# ------------------------------------------------------------------------------------------------------ markdown
def _md_row_fields(msg: dict) -> str:
    parts = []
    for f in msg["fields"]:
        name = f["name"] + ("[" + msg["array"]["count"] + "]" if msg["array"] and f is msg["array"]["field"] else "")
        extra = []
        if f["type"] in ("bytes", "ascii"):
            extra.append(f"{f['size']} bytes")
        if "doc" in f:
            extra.append(f["doc"])
        parts.append(name + (" (" + ": ".join(extra) + ")" if extra else ""))
    return ", ".join(parts) if parts else "—"


def gen_md(table: dict) -> dict[str, str]:
    rows = ["| type | name | direction | payload | size | fields |", "|---|---|---|---|---|---|"]
    for msg in table["messages"]:
        t = f"0x{msg['type']:02x}"
        if msg.get("empty_request"):
            rows.append(f"| {t} | {msg['name']} (request) | {msg['empty_request']} | empty | 0 | — |")
        if msg["array"]:
            a = msg["array"]
            payload = f"`{msg['fmt']}` + {a['count']}×`<{_INT[a['elem']][0]}`"
            size = f"{msg['size']}+{_INT[a['elem']][2]}{a['count']}"
        else:
            payload = f"`{msg['fmt']}`" if msg["fields"] else "empty"
            size = str(msg["size"])
        rows.append(f"| {t} | {msg['name']} | {msg['direction']} | {payload} | {size} | {_md_row_fields(msg)} |")
    r = table["set_brackets_rule"]
    rules = [
        "",
        "Value rules (a device answers NACK BAD_VALUE otherwise; `check_set_brackets` / `check_values` in Python,",
        "`bproto_check_set_brackets` / `bproto_check_<msg>` in C):",
        "",
        f"- SET_BRACKETS: 1 ≤ n ≤ {r['max_brackets']}, {r['min_period_us']} ≤ period_us ≤ {r['max_period_us']}, "
        f"every exposure_us ≥ {r['min_exposure_us']} and exposure_us + {r['exposure_margin_us']} ≤ period_us.",
    ]
    for msg in table["messages"]:
        for top in sorted({f["max"] for f in _maxed(msg)}):
            names = ", ".join(f["name"] for f in _maxed(msg) if f["max"] == top)
            rules.append(f"- {msg['name']}: {names} ≤ {top}.")
    nacks = ", ".join(f"{n['code']} {n['name']} ({n['doc']})" for n in table["nack_codes"])
    rules += ["", f"NACK codes: {nacks}."]
    return {"messages": "\n".join(rows + rules)}


# ---------------------------------------------------------------------------------------------------------- C
def _c_consts(table: dict) -> str:
    out = [f"#define BPROTO_VERSION {table['version']}", ""]
    out += [f"#define BPROTO_MSG_{m['name']} 0x{m['type']:02X}u" for m in table["messages"]]
    out += [""] + [f"#define BPROTO_NACK_{n['name']} {n['code']}u" for n in table["nack_codes"]]
    out += [""] + [f"#define BPROTO_DEVICE_{d['name']} {d['code']}u" for d in table["device_kinds"]]
    out += ["", "/* payload sizes (bytes); a variable message: its fixed part (_MIN) and one array item (_ITEM) */"]
    for m in table["messages"]:
        if m["array"]:
            out.append(f"#define BPROTO_LEN_{m['name']}_MIN {m['size']}u")
            out.append(f"#define BPROTO_LEN_{m['name']}_ITEM {_INT[m['array']['elem']][2]}u")
        else:
            note = " /* device->host; the host's request is empty */" if m.get("empty_request") else ""
            out.append(f"#define BPROTO_LEN_{m['name']} {m['size']}u{note}")
    out += ["", "/* sizes of the fixed-size text and byte fields */"]
    for m in table["messages"]:
        for f in m["fields"]:
            if f["type"] in ("bytes", "ascii"):
                out.append(f"#define BPROTO_{_size_const(f)} {f['size']}u")
    out += ["", "/* SET_BRACKETS value rule (see bproto_check_set_brackets) */"]
    for key, value in table["set_brackets_rule"].items():
        if not key.startswith("_"):
            out.append(f"#define BPROTO_{key.upper()} {value}u")
    for m in table["messages"]:
        for f in _maxed(m):
            out.append(f"#define BPROTO_{m['name']}_{f['name'].upper()}_MAX {f['max']}u")
    return "\n".join(out)


def _c_field_decl(msg: dict, f: dict) -> str:
    doc = f"  /* {f['doc']} */" if "doc" in f else ""
    if msg["array"] and f is msg["array"]["field"]:
        return f"    {_INT[msg['array']['elem']][1]} {f['name']}[BPROTO_{msg['name']}_MAX_N];{doc}"
    if f["type"] == "bytes":
        return f"    uint8_t {f['name']}[BPROTO_{_size_const(f)}];{doc}"
    if f["type"] == "ascii":
        return (f"    char {f['name']}[BPROTO_{_size_const(f)} + 1u];  /* NUL-terminated printable ASCII: space padded "
                f"when packed, trailing spaces removed when unpacked */")
    return f"    {_INT[f['type']][1]} {f['name']};{doc}"


def _c_messages_h(table: dict) -> str:
    out = []
    for m in table["messages"]:
        if m["array"]:
            a = m["array"]
            out.append(f"/* most {a['field']['name']} a {m['name']} payload can carry (the structural limit) */")
            out.append(f"#define BPROTO_{m['name']}_MAX_N ((BPROTO_MAX_PAYLOAD - BPROTO_LEN_{m['name']}_MIN) / "
                       f"BPROTO_LEN_{m['name']}_ITEM)")
    for m in table["messages"]:
        if not m["fields"]:
            out += ["", f"/* 0x{m['type']:02X} {m['name']} has no fields (empty payload). */"]
            continue
        out += ["", f"typedef struct {{ /* 0x{m['type']:02X} {m['name']}, {m['direction']} */"]
        out += [_c_field_decl(m, f) for f in m["fields"]]
        out.append(f"}} bproto_{_lower(m)}_t;")
    out.append("")
    for m in table["messages"]:
        if m["fields"]:
            out.append(f"int bproto_pack_{_lower(m)}(const bproto_{_lower(m)}_t *m, uint8_t *out, size_t out_cap);")
    for m in table["messages"]:
        if m["fields"]:
            out.append(f"uint8_t bproto_unpack_{_lower(m)}(const uint8_t *payload, size_t len, "
                       f"bproto_{_lower(m)}_t *m);")
        else:
            out.append(f"uint8_t bproto_unpack_{_lower(m)}(const uint8_t *payload, size_t len);")
    for m in table["messages"]:
        if m["array"]:
            out.append(f"/* 1 if a {m['name']} payload of len bytes is structurally valid */")
            out.append(f"int bproto_{_lower(m)}_len_ok(const uint8_t *payload, size_t len);")
        if _maxed(m):
            out.append(f"/* 0 if the {m['name']} values are within their ranges, else BPROTO_NACK_BAD_VALUE */")
            out.append(f"uint8_t bproto_check_{_lower(m)}(const bproto_{_lower(m)}_t *m);")
    out += ["", "/* Any message: type plus the struct of that type. */", "typedef struct {",
            "    uint8_t type;          /* BPROTO_MSG_* */",
            "    uint8_t hello_request; /* HELLO only: 1 = the host's request (empty payload, u.hello unused) */",
            "    union {"]
    out += [f"        bproto_{_lower(m)}_t {_lower(m)};" for m in table["messages"] if m["fields"]]
    out += ["    } u;", "} bproto_msg_t;"]
    return "\n".join(out)


def _c_put(f: dict, off: str, src: str) -> str:
    kind = f["type"]
    if kind == "u8":
        return f"    out[{off}] = {src};"
    return f"    bproto_put_{kind}(&out[{off}], {src});"


def _c_get(f: dict, off: str, dst: str) -> str:
    kind = f["type"]
    if kind == "u8":
        return f"    {dst} = payload[{off}];"
    return f"    {dst} = bproto_get_{kind}(&payload[{off}]);"


def _c_pack(m: dict) -> list[str]:
    name, low = m["name"], _lower(m)
    out = [f"int bproto_pack_{low}(const bproto_{low}_t *m, uint8_t *out, size_t out_cap)", "{"]
    if m["array"]:
        a = m["array"]
        out += [f"    if (m->{a['count']} > BPROTO_{name}_MAX_N) {{", "        return -1;", "    }",
                f"    size_t len = BPROTO_LEN_{name}_MIN + BPROTO_LEN_{name}_ITEM * (size_t)m->{a['count']};"]
        length = "len"
    else:
        length = f"BPROTO_LEN_{name}"
    out += [f"    if (out_cap < {length}) {{", "        return -1;", "    }"]
    for f in _fixed(m):
        off = str(m["offsets"][f["name"]])
        if f["type"] == "bytes":
            out.append(f"    memcpy(&out[{off}], m->{f['name']}, BPROTO_{_size_const(f)});")
        elif f["type"] == "ascii":
            out += [f"    if (pack_ascii(m->{f['name']}, &out[{off}], BPROTO_{_size_const(f)}) != 0) {{",
                    "        return -1;", "    }"]
        else:
            out.append(_c_put(f, off, f"m->{f['name']}"))
    if m["array"]:
        a = m["array"]
        out += [f"    for (size_t i = 0; i < m->{a['count']}; i++) {{",
                "    " + _c_put({"type": a["elem"]}, f"BPROTO_LEN_{name}_MIN + BPROTO_LEN_{name}_ITEM * i",
                               f"m->{a['field']['name']}[i]"), "    }"]
    out += [f"    return (int){length};", "}"]
    return out


def _c_unpack(m: dict) -> list[str]:
    name, low = m["name"], _lower(m)
    if not m["fields"]:
        return [f"uint8_t bproto_unpack_{low}(const uint8_t *payload, size_t len)", "{", "    (void)payload;",
                f"    return len == BPROTO_LEN_{name} ? 0u : BPROTO_NACK_BAD_LENGTH;", "}"]
    out = [f"uint8_t bproto_unpack_{low}(const uint8_t *payload, size_t len, bproto_{low}_t *m)", "{"]
    check = f"!bproto_{low}_len_ok(payload, len)" if m["array"] else f"len != BPROTO_LEN_{name}"
    out += [f"    if ({check}) {{", "        return BPROTO_NACK_BAD_LENGTH;", "    }"]
    for f in _fixed(m):
        off = str(m["offsets"][f["name"]])
        if f["type"] == "bytes":
            out.append(f"    memcpy(m->{f['name']}, &payload[{off}], BPROTO_{_size_const(f)});")
        elif f["type"] == "ascii":
            out += [f"    if (unpack_ascii(&payload[{off}], BPROTO_{_size_const(f)}, m->{f['name']}) != 0) {{",
                    "        return BPROTO_NACK_BAD_VALUE;", "    }"]
        else:
            out.append(_c_get(f, off, f"m->{f['name']}"))
    if m["array"]:
        a = m["array"]
        out += [f"    for (size_t i = 0; i < m->{a['count']}; i++) {{",
                "    " + _c_get({"type": a["elem"]}, f"BPROTO_LEN_{name}_MIN + BPROTO_LEN_{name}_ITEM * i",
                               f"m->{a['field']['name']}[i]"), "    }"]
    out += ["    return 0;", "}"]
    return out


def _c_messages_c(table: dict) -> str:
    out: list[str] = []
    out += ["int bproto_expected_len(uint8_t type)", "{", "    switch (type) {"]
    for m in table["messages"]:
        value = "0" if m.get("empty_request") else "-1" if m["array"] else f"(int)BPROTO_LEN_{m['name']}"
        out.append(f"    case BPROTO_MSG_{m['name']}: return {value};")
    out += ["    default: return -2;", "    }", "}"]
    for m in table["messages"]:
        if m["array"]:
            cnt = m["offsets"][m["array"]["count"]]
            out += ["", f"int bproto_{_lower(m)}_len_ok(const uint8_t *payload, size_t len)", "{",
                    f"    return len >= BPROTO_LEN_{m['name']}_MIN &&",
                    f"           len == BPROTO_LEN_{m['name']}_MIN + BPROTO_LEN_{m['name']}_ITEM * "
                    f"(size_t)payload[{cnt}];", "}"]
    for m in table["messages"]:
        if m["fields"]:
            out += ["", *_c_pack(m)]
    for m in table["messages"]:
        out += ["", *_c_unpack(m)]
    for m in table["messages"]:
        if _maxed(m):
            out += ["", f"uint8_t bproto_check_{_lower(m)}(const bproto_{_lower(m)}_t *m)", "{"]
            for f in _maxed(m):
                out += [f"    if (m->{f['name']} > BPROTO_{m['name']}_{f['name'].upper()}_MAX) {{",
                        "        return BPROTO_NACK_BAD_VALUE;", "    }"]
            out += ["    return 0;", "}"]
    out += ["", "int bproto_pack_msg(const bproto_msg_t *m, uint8_t *out, size_t out_cap)", "{",
            "    switch (m->type) {"]
    for m in table["messages"]:
        low = _lower(m)
        call = f"bproto_pack_{low}(&m->u.{low}, out, out_cap)" if m["fields"] else "0"
        if m.get("empty_request"):
            call = f"m->hello_request ? 0 : {call}"
        out.append(f"    case BPROTO_MSG_{m['name']}: return {call};")
    out += ["    default: return -1;", "    }", "}", "",
            "uint8_t bproto_unpack_msg(uint8_t type, const uint8_t *payload, size_t len, bproto_msg_t *m)", "{",
            "    m->type = type;", "    m->hello_request = 0;", "    switch (type) {"]
    for m in table["messages"]:
        low = _lower(m)
        call = f"bproto_unpack_{low}(payload, len, &m->u.{low})" if m["fields"] else \
            f"bproto_unpack_{low}(payload, len)"
        if m.get("empty_request"):
            out += [f"    case BPROTO_MSG_{m['name']}:", "        if (len == 0u) {",
                    "            m->hello_request = 1;", "            return 0;", "        }",
                    f"        return {call};"]
        else:
            out.append(f"    case BPROTO_MSG_{m['name']}: return {call};")
    out += ["    default: return BPROTO_NACK_UNKNOWN_TYPE;", "    }", "}"]
    return "\n".join(out)


# ------------------------------------------------------------------------------------------------------- Python
def _py_tuple(items: list[str], indent: int) -> str:
    """A Python tuple literal of ``items`` wrapped under 120 columns (continuation lines indented by ``indent``)."""
    if not items:
        return "()"
    lines, line = [], "("
    for i, item in enumerate(items):
        piece = item + ("," if i < len(items) - 1 or len(items) == 1 else "")
        if len(line) + len(piece) + (0 if lines else indent) > 115 and line != "(":
            lines.append(line.rstrip())
            line = " " * indent + " "
        line += piece + " "
    lines.append(line.rstrip() + ")")
    return "\n".join(lines)


def gen_py(table: dict) -> dict[str, str]:
    out = [f"VERSION = {table['version']}", ""]
    out += [f"MSG_{m['name']} = 0x{m['type']:02x}" for m in table["messages"]]
    out += [""] + [f"NACK_{n['name']} = {n['code']}" for n in table["nack_codes"]]
    out += [""] + [f"DEVICE_{d['name']} = {d['code']}" for d in table["device_kinds"]]
    out.append("")
    for key, value in table["set_brackets_rule"].items():
        if not key.startswith("_"):
            out.append(f"{key.upper()} = {value}")
    for m in table["messages"]:
        for f in m["fields"]:
            if f["type"] in ("bytes", "ascii"):
                out.append(f"{_size_const(f)} = {f['size']}")
    out += ["", "MSG_NAMES = {"]
    out += [f"    MSG_{m['name']}: \"{m['name']}\"," for m in table["messages"]]
    out += ["}", "NACK_NAMES = {"]
    out += [f"    NACK_{n['name']}: \"{n['name']}\"," for n in table["nack_codes"]]
    out += ["}", "",
            "# Fixed layouts: type -> (struct format, field names); \"Ns\" fields are bytes (zero padded) or,",
            "# when named in _ASCII_FIELDS, printable ASCII text (space padded). An empty HELLO is the request.",
            "_LAYOUTS = {"]
    for m in table["messages"]:
        if not m["array"]:
            head = f"    MSG_{m['name']}: (\"{m['fmt']}\", "
            names = _py_tuple([f"\"{f['name']}\"" for f in m["fields"]], len(head))
            out.append(f"{head}{names}),")
    out += ["}",
            "# Variable layouts: type -> (struct format of the fixed part, its field names, count field, array field,",
            "# struct format of one item); the count field is not a dict field (it is the array's length).",
            "_ARRAYS = {"]
    for m in table["messages"]:
        if m["array"]:
            a = m["array"]
            head = _py_tuple([f"\"{f['name']}\"" for f in _fixed(m) if f["name"] != a["count"]], 0)
            out.append(f"    MSG_{m['name']}: (\"{m['fmt']}\", {head}, \"{a['count']}\", "
                       f"\"{a['field']['name']}\", \"<{_INT[a['elem']][0]}\"),")
    ascii_fields = [f"\"{f['name']}\"" for m in table["messages"] for f in m["fields"] if f["type"] == "ascii"]
    out += ["}", "_ASCII_FIELDS = " + _py_tuple(ascii_fields, 16),
            "# Per-field value ranges: type -> ((field name, largest value), ...)", "_VALUE_MAX = {"]
    for m in table["messages"]:
        if _maxed(m):
            head = f"    MSG_{m['name']}: "
            out.append(head + _py_tuple([f"(\"{f['name']}\", {f['max']})" for f in _maxed(m)], len(head)) + ",")
    out.append("}")
    return {"constants": "\n".join(out)}


def gen_all(table: dict) -> dict[str, dict[str, str]]:
    """Generated text per target and part."""
    return {"md": gen_md(table), "h": {"constants": _c_consts(table), "messages": _c_messages_h(table)},
            "c": {"messages": _c_messages_c(table)}, "py": gen_py(table)}


# -------------------------------------------------------------------------------------------------- the files
def render(kind: str, text: str, parts: dict[str, str]) -> str:
    """``text`` with every generated part replaced; TableError if a part's markers are missing."""
    mark = _MARK[kind]
    for part, body in parts.items():
        begin = mark.format(f"BEGIN GENERATED {part} {_ORIGIN}")
        end = mark.format(f"END GENERATED {part}")
        start = mark.split("{}")[0] + f"BEGIN GENERATED {part} "
        pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
        if len(pattern.findall(text)) != 1:
            raise TableError(f"{kind}: expected one '{part}' region marked BEGIN/END GENERATED")
        text = pattern.sub(lambda _m, b=body, bg=begin, e=end: bg + "\n" + b + "\n" + e, text)
    return text


def stale(targets: dict[str, Path] = TARGETS, table_path: Path = TABLE) -> list[Path]:
    """Files whose generated parts differ from what the table generates now."""
    generated = gen_all(load(table_path))
    out = []
    for kind, path in targets.items():
        text = path.read_text(encoding="utf-8")
        if render(kind, text, generated[kind]) != text:
            out.append(path)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="only check; exit 1 if a generated part is stale")
    args = parser.parse_args(argv)
    try:
        generated = gen_all(load())
        changed = []
        for kind, path in TARGETS.items():
            text = path.read_text(encoding="utf-8")
            new = render(kind, text, generated[kind])
            if new != text:
                changed.append(path)
                if not args.check:
                    path.write_text(new, encoding="utf-8")
    except (TableError, OSError, KeyError, ValueError) as exc:
        print(f"generate.py: error: {exc}", file=sys.stderr)
        return 2
    for path in changed:
        rel = path.relative_to(REPO)
        print(f"{'stale' if args.check else 'written'}: {rel}" + (" (run: make protocol)" if args.check else ""))
    return 1 if args.check and changed else 0


if __name__ == "__main__":
    sys.exit(main())
