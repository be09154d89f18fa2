"""Rig config validation: the examples load, and each kind of mistake is one clear line naming the key."""

from __future__ import annotations

import copy
import dataclasses
import tomllib
from pathlib import Path
from typing import Any

import pytest

from bracketry_base.paths import repo_root
from bracketry_rig.daemon import config_schema
from bracketry_rig.daemon.config import EXAMPLE as EXAMPLE_CONFIG
from bracketry_rig.daemon.config import (
    CameraConfig,
    ConfigError,
    MonitorConfig,
    PanelConfig,
    RigConfig,
    TriggerConfig,
    example_config,
    load_config,
    parse_config,
)

EXAMPLE_FILE = repo_root() / "host" / "deploy" / "rig.example.toml"


def example() -> dict[str, Any]:
    return tomllib.loads(EXAMPLE_FILE.read_text())


def test_example_config_loads_with_units() -> None:
    cfg = load_config(EXAMPLE_FILE)
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
    # the checks derived from the field table, one per kind of spec
    ("rig.split_size_mb", 8, "rig.split_size_mb: must be >= 16 MB, got 8"),
    ("rig.split_minutes", 0, "rig.split_minutes: must be > 0, got 0"),
    ("rig.min_free_mb", -1, "rig.min_free_mb: must be >= 0, got -1"),
    ("rig.status_socket", 5, "rig.status_socket: must be str, got int 5"),
    ("rig.brackets_ms", [1, "2"], "rig.brackets_ms[1]: must be a number of milliseconds, got '2'"),
    ("rig", [1], "rig: must be a table, got list"),
    ("cameras", {"side": "left"}, "cameras: must be an array of tables [[cameras]]"),
    ("cameras.0.packet_delay_ticks", -1, "cameras[0].packet_delay_ticks: must be >= 0, got -1"),
    ("cameras.0.device_id", 40123456, "cameras[0].device_id: must be str, got int 40123456"),
    ("cameras.0", "left", "cameras[0]: must be a table, got str"),
    ("panel.enabled", 1, "panel.enabled: must be bool, got int 1"),
    ("panel.baudrate", True, "panel.baudrate: must be int, got bool True"),
    ("monitor.white_dn", 0, "monitor.white_dn: must be within 1..65535, got 0"),
    ("monitor.listen", "127.0.0.1", "monitor.listen: expected HOST:PORT"),
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
    cfg = load_config(EXAMPLE_FILE.with_name("rig.simulated.toml"))
    assert [(c.side, c.profile, c.address) for c in cfg.cameras] == [("left", "aravis_fake", "127.0.0.2"),
                                                                      ("right", "aravis_fake", "127.0.0.3")]
    assert cfg.trigger.kind == "simulator" and cfg.panel.enabled
    assert cfg.stop_free_mb < cfg.min_free_mb


def test_committed_example_is_the_generated_one() -> None:
    assert EXAMPLE_FILE.read_text() == example_config(), (
        "host/deploy/rig.example.toml differs from the field table: run "
        "`.venv/bin/python -m bracketry_rig.daemon.config > host/deploy/rig.example.toml`")


def test_generated_example_reads_back_as_the_example_config() -> None:
    assert parse_config(tomllib.loads(example_config())) == EXAMPLE_CONFIG


def test_every_field_is_a_documented_key() -> None:
    """Every field of the config classes is declared in the table (only RigConfig.source is not a key), with help;
    a table's defaults are its class's."""
    for cls in (RigConfig, CameraConfig, TriggerConfig, PanelConfig, MonitorConfig):
        declared = {key.name for key in config_schema.keys(cls)}
        assert declared | ({"source"} if cls is RigConfig else set()) == {f.name for f in dataclasses.fields(cls)}
        for key in config_schema.keys(cls):
            assert key.spec.help, (cls.__name__, key.name)
            assert key.name in example_config()
    assert parse_config(example()).trigger == TriggerConfig() and parse_config(example()).panel == PanelConfig()


def test_absent_keys_take_the_declared_defaults() -> None:
    data = example()
    for table in ("trigger", "panel"):
        del data[table]
    for key in ("min_free_mb", "stop_free_mb", "split_size_mb", "split_minutes", "status_socket"):
        del data["rig"][key]
    data["cameras"] = [{k: v for k, v in cam.items() if k in ("side", "profile", "address")}
                       for cam in data["cameras"]]
    data["monitor"] = {}
    cfg = parse_config(data)
    assert cfg.trigger == TriggerConfig() and cfg.panel == PanelConfig() and cfg.monitor == MonitorConfig()
    assert cfg.camera("left") == CameraConfig(side="left", profile="basler_ace2", address="192.168.10.11")
    assert (cfg.min_free_mb, cfg.stop_free_mb, cfg.split_size_mb, cfg.split_minutes) == (2048, 512, 4096, 10.0)
    assert cfg.status_socket == Path("/run/bracketry/status.sock") and isinstance(cfg.split_minutes, float)


def test_monitor_defaults_follow_the_cameras_pixel_format() -> None:
    data = example()
    for cam in data["cameras"]:
        cam["pixel_format"] = "Mono8"
    data["monitor"] = {}
    assert parse_config(data).monitor == MonitorConfig(bayer=False, white_dn=255)
    data["monitor"] = {"bayer": True, "white_dn": 1023}
    assert parse_config(data).monitor == MonitorConfig(bayer=True, white_dn=1023)
    del data["monitor"]
    assert parse_config(data).monitor is None
