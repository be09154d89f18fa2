"""Rig config validation: the examples load, and each kind of mistake is one clear line naming the key."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path
from typing import Any

import pytest

from bracketry.daemon.config import ConfigError, load_config, parse_config
from bracketry.paths import repo_root

EXAMPLE = repo_root() / "host" / "deploy" / "rig.example.toml"


def example() -> dict[str, Any]:
    return tomllib.loads(EXAMPLE.read_text())


def test_example_config_loads_with_units() -> None:
    cfg = load_config(EXAMPLE)
    assert cfg.brackets_us == (1000, 2000, 4000, 8000, 16000, 32000)
    assert cfg.period_us == 45455
    assert [c.side for c in cfg.cameras] == ["left", "right"]
    assert cfg.camera("left").trigger_activation == "FallingEdge"
    assert cfg.trigger.baudrate == 921600


def mutate(path: str, value: Any) -> dict[str, Any]:
    data = copy.deepcopy(example())
    node: Any = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if k.isdigit() else node[k]
    last = keys[-1]
    if value is DELETE:
        del node[int(last) if last.isdigit() else last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return data


DELETE = object()

BAD_CASES = [
    ("rig.fps", 0.1, "rig.fps: must be within"),
    ("rig.fps", "fast", "rig.fps: must be int or number"),
    ("rig.brackets_ms", [], "rig.brackets_ms: must list 1..16"),
    ("rig.brackets_ms", [1, 2, 50], "rig.brackets_ms[2]: 50 ms does not fit"),
    ("rig.brackets_ms", [0.001], "below the 0.010 ms minimum"),
    ("rig.output_dir", DELETE, "rig.output_dir: missing (required)"),
    ("rig.outptu_dir", "/x", "rig.outptu_dir: unknown key"),
    ("rig.stop_free_mb", 999999, "rig.stop_free_mb: (999999) must not exceed"),
    ("cameras.0.side", "middle", "cameras[0].side: must be one of left, right"),
    ("cameras.1.side", "left", "need exactly one left and one right camera"),
    ("cameras.0.profile", "pylon", "cameras[0].profile: must be one of"),
    ("cameras.0.address", "192.168.10.300", "cameras[0].address: not an IPv4 address"),
    ("cameras.1.address", "192.168.10.11", "same address"),
    ("cameras.0.address", DELETE, "cameras[0]: needs address"),
    ("cameras.0.packet_size_bytes", 100000, "cameras[0].packet_size_bytes: must be within"),
    ("cameras.0.trigger_activation", "Falling", "cameras[0].trigger_activation: must be one of"),
    ("cameras.0.pixel_format", "RGB8", "cameras[0].pixel_format: must be one of"),
    ("trigger.baudrate", 12345, "trigger.baudrate: unsupported baud rate"),
    ("trigger.kind", "usb", "trigger.kind: must be one of"),
    ("panel.refresh_hz", 30, "panel.refresh_hz: must be within 2..5 Hz"),
    ("panel.port", "/dev/bracketry-trigger", "panel.port: same serial port as trigger.port"),
    ("cameras", DELETE, "cameras: missing"),
    ("extra", {"a": 1}, "extra: unknown table"),
]


@pytest.mark.parametrize(("path", "value", "message"), BAD_CASES, ids=[c[2][:40] for c in BAD_CASES])
def test_invalid_config_is_rejected_with_key_and_reason(path: str, value: Any, message: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(mutate(path, value), "rig.toml")
    text = str(info.value)
    assert message in text
    assert text.startswith("rig.toml: ")
    assert "\n" not in text


def test_unreadable_and_non_toml_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig\nfps = 22\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_simulated_example_config_loads() -> None:
    cfg = load_config(EXAMPLE.with_name("rig.simulated.toml"))
    assert [(c.side, c.profile, c.address) for c in cfg.cameras] == [("left", "aravis_fake", "127.0.0.2"),
                                                                      ("right", "aravis_fake", "127.0.0.3")]
    assert cfg.trigger.kind == "simulator" and cfg.panel.enabled
    assert cfg.stop_free_mb < cfg.min_free_mb
