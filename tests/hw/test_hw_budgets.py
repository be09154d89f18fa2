"""hw/ calculators reproduce the paper's figures: ~872 Mbit/s per camera, ~79 W, 1.7 h / 5.5 h per pack."""

from __future__ import annotations

from pathlib import Path

import pytest

from bracketry.cli import main
from bracketry_base.errors import BracketryError
from bracketry_rig.hwcalc import bandwidth as bw
from bracketry_rig.hwcalc import bom, power

PAPER_CAMERA_MBPS = 872.0
PAPER_TOTAL_W = 79.0


def test_hw_bandwidth_unpacked_12bit_matches_paper() -> None:
    s = bw.stream_bandwidth(22, 1920, 1200, "BayerRG12", 1500)
    assert s.payload_bytes_per_frame == 1920 * 1200 * 2
    assert s.payload_mbps == pytest.approx(811.0, abs=0.1)
    # the paper measured ~872 Mbit/s per camera; the header model gives the wire rate within 3 %
    assert s.wire_mbps == pytest.approx(PAPER_CAMERA_MBPS, rel=0.03)
    assert s.payload_mbps < s.ip_mbps < s.wire_mbps
    # two cameras overflow 1 GbE (the paper's bandwidth lesson) but fit the 10 GbE uplink
    verdicts = {v.link: v for v in bw.uplink_verdicts(s, 2)}
    assert not verdicts["1GbE"].fits and verdicts["10GbE"].fits
    assert s.wire_mbps < 1000  # each camera alone fits its own 1 GbE port


def test_hw_bandwidth_packed_and_jumbo() -> None:
    packed = bw.stream_bandwidth(22, 1920, 1200, "BayerRG12p", 1500)
    assert packed.payload_bytes_per_frame == 1920 * 1200 * 3 // 2
    assert packed.payload_mbps == pytest.approx(608.3, abs=0.1)
    assert not {v.link: v for v in bw.uplink_verdicts(packed, 2)}["1GbE"].fits  # 2 x ~639 > 1000
    jumbo = bw.stream_bandwidth(22, 1920, 1200, "BayerRG12", 9000)
    std = bw.stream_bandwidth(22, 1920, 1200, "BayerRG12", 1500)
    assert jumbo.data_packets_per_frame < std.data_packets_per_frame / 5
    assert jumbo.overhead_fraction < 0.01 < std.overhead_fraction
    with pytest.raises(ValueError):
        bw.stream_bandwidth(22, 1920, 1200, "BayerXX", 1500)


def test_hw_power_budget_matches_paper() -> None:
    parts = bom.load_bom()
    budget = power.power_budget(parts)
    assert budget.total_w == pytest.approx(PAPER_TOTAL_W, abs=2.0)
    by_id = {pid: total for pid, _q, _u, total in budget.items}
    assert by_id["computer"] == 40.0 and by_id["switch"] == 12.0  # the paper's two main consumers
    assert budget.items[0][0] == "computer" and budget.items[1][0] == "switch"
    runtimes = {p.capacity_ah: h for p, h in power.battery_runtimes(parts, budget.total_w)}
    assert runtimes[2.5] == pytest.approx(1.7, rel=0.05)
    assert runtimes[7.5] == pytest.approx(5.5, rel=0.05)
    # a lossy converter shortens the runtime proportionally
    assert power.runtime_h(2.5, 56, 79, efficiency=0.9) == pytest.approx(0.9 * 140 / 79)


def test_hw_bom_lists_every_rig_part() -> None:
    parts = {p.id: p for p in bom.load_bom()}
    numbers = " ".join(p.part_number for p in parts.values())
    for needle in ("a2A1920-51gcPRO", "VLP-16", "MTi-30", "Reach", "Jetson AGX Xavier", "TEG-S762", "XG-C100C",
                   "970 EVO Plus", "STM32F407", "ESP32", "NHD-0420H1Z-FSW-GBW-33V3", "PVA6", "BA1400T", "BA4200T",
                   "1510", "UAP-AC-M"):
        assert needle in numbers, needle
    assert parts["camera"].quantity == 2 and parts["button"].quantity == 2
    for p in parts.values():
        assert p.manufacturer and p.role and p.quantity >= 1


def test_hw_bom_bad_file(tmp_path: Path) -> None:
    bad = tmp_path / "bom.csv"
    bad.write_text("id,part\nx,y\n")
    with pytest.raises(BracketryError, match="missing column"):
        bom.load_bom(bad)
    with pytest.raises(BracketryError, match="cannot read"):
        bom.load_bom(tmp_path / "absent.csv")


def test_hw_cli(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["hw", "power"]) == 0
    out = capsys.readouterr().out
    assert "total" in out and "79.2 W" in out and "BA4200T" in out
    assert main(["hw", "bandwidth", "--fps", "22", "--width", "1920", "--height", "1200", "--pixel-format",
                 "BayerRG12", "--packet-size", "1500"]) == 0
    out = capsys.readouterr().out
    assert "852.0 Mbit/s" in out and "1GbE    does NOT fit" in out
    assert main(["hw", "bandwidth", "--pixel-format", "BayerRG12p", "--packet-size", "9000"]) == 0
    assert main(["hw", "bandwidth", "--extended-ids", "--cameras", "1", "--extra-mbps", "8"]) == 0
    out = capsys.readouterr().out
    assert "1GbE    fits" in out
    assert main(["hw", "bandwidth", "--packet-size", "12"]) == 2
    err = capsys.readouterr().err
    assert err.strip().startswith("error:") and "Traceback" not in err
