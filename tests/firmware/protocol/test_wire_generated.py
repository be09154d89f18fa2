"""The message bindings generated from firmware/protocol/messages.json are up to date and follow the table.

``firmware/protocol/generate.py --check`` is what CI runs through this test: it fails naming every stale file
(fix: ``make protocol``). The generator is also run on a copy with a changed table to show the check can fail.
"""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

from bracketry_base import paths
from bracketry_rig.wire import bproto

PROTO = paths.repo_root() / "firmware" / "protocol"


def _generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bproto_generate", PROTO / "generate.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_wire_generated_parts_are_up_to_date() -> None:
    done = subprocess.run([sys.executable, str(PROTO / "generate.py"), "--check"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stdout + done.stderr


def test_wire_generated_check_fails_on_a_stale_file(tmp_path: Path) -> None:
    gen = _generator()
    table = json.loads((PROTO / "messages.json").read_text(encoding="utf-8"))
    table["messages"][1]["fields"][0]["name"] = "acked_sequence"  # ACK: every binding names its field
    changed = tmp_path / "messages.json"
    changed.write_text(json.dumps(table), encoding="utf-8")
    targets = {}
    for kind, path in gen.TARGETS.items():
        targets[kind] = tmp_path / path.name
        shutil.copy(path, targets[kind])
    assert gen.stale(targets, PROTO / "messages.json") == []
    assert sorted(p.name for p in gen.stale(targets, changed)) == sorted(p.name for p in targets.values())


def test_wire_python_layouts_follow_the_table() -> None:
    table = json.loads((PROTO / "messages.json").read_text(encoding="utf-8"))
    sizes = {"u8": 1, "u16": 2, "u32": 4, "u64": 8}
    assert table["version"] == bproto.VERSION
    for msg in table["messages"]:
        t = msg["type"]
        assert bproto.MSG_NAMES[t] == msg["name"] and getattr(bproto, "MSG_" + msg["name"]) == t
        fixed = [f for f in msg["fields"] if not f["type"].endswith("]")]
        size = sum(sizes.get(f["type"], f.get("size", 0)) for f in fixed)
        names = tuple(f["name"] for f in msg["fields"] if "count_of" not in f)
        assert bproto.field_names(t) == names
        if len(fixed) == len(msg["fields"]):
            assert len(bproto.pack_payload(t, {n: _sample(msg, n) for n in names})) == size
        assert bproto.nack_code_for(t, b"\x00" * (size + 1)) == bproto.NACK_BAD_LENGTH
    for nack in table["nack_codes"]:
        assert getattr(bproto, "NACK_" + nack["name"]) == nack["code"]
    rule = table["set_brackets_rule"]
    assert bproto.check_set_brackets(rule["min_period_us"], [rule["min_exposure_us"]]) == 0
    assert bproto.check_set_brackets(rule["min_period_us"], [rule["min_exposure_us"] - 1]) == bproto.NACK_BAD_VALUE


def _sample(msg: dict, name: str) -> object:
    f = next(f for f in msg["fields"] if f["name"] == name)
    return {"bytes": b"\x01", "ascii": "OK"}.get(f["type"], 1)


def test_wire_panel_state_value_rule_from_the_table() -> None:
    fields = bproto.unpack_payload(bproto.MSG_PANEL_STATE, bproto.pack_payload(bproto.MSG_PANEL_STATE, {
        "cam_left": 4, "cam_right": 0, "trigger": 1, "imu": 2, "lidar": 3, "gnss": 4, "free_disk_mb": 1,
        "fps_left_centi": 1, "fps_right_centi": 1, "rec_seconds": 1, "message": "x"}))
    assert bproto.check_values(bproto.MSG_PANEL_STATE, fields) == 0
    fields["gnss"] = 5
    assert bproto.check_values(bproto.MSG_PANEL_STATE, fields) == bproto.NACK_BAD_VALUE
    too_long = {"period_us": 1000, "exposures_us": [801]}
    assert bproto.check_values(bproto.MSG_SET_BRACKETS, too_long) == bproto.NACK_BAD_VALUE
