"""``bracketry hw``: power budget and battery runtime from hw/bom.csv, GigE bandwidth, wiring diagram and checks."""

from __future__ import annotations

from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import (
    EXIT_OK,
    EXIT_PROBLEMS,
    Integer,
    Number,
    count,
    input_file,
    non_negative,
    output_file,
    overwrite_option,
)
from bracketry_rig.hwcalc import bandwidth as bw
from bracketry_rig.hwcalc import bom, diagram, power, wiring


@click.group()
def command() -> None:
    """Hardware calculators: power budget and GigE bandwidth; wiring diagram and pin checks."""


@command.command("power")
@click.option("--bom", "bom_path", type=input_file(), default=None, help="BOM CSV (default hw/bom.csv).")
@click.option("--efficiency", type=Number(0.0, 1.0, min_open=True), default=1.0, show_default=True,
              help="DC-DC efficiency (load / battery power), in (0, 1]; 1.0 reproduces the paper's estimate.")
@click.option("--usable", "usable_fraction", type=Number(0.0, 1.0, min_open=True), default=1.0, show_default=True,
              help="Usable fraction of the packs' nominal energy, in (0, 1].")
def power_cmd(bom_path: Path | None, efficiency: float, usable_fraction: float) -> None:
    """Sum the nominal power of every part and print the runtime of each battery pack."""
    parts = bom.load_bom(bom_path)
    budget = power.power_budget(parts)
    click.echo(f"{'part':<12} {'qty':>3} {'W/unit':>7} {'W':>6}")
    for pid, qty, per_unit, total in budget.items:
        click.echo(f"{pid:<12} {qty:>3} {per_unit:>7.1f} {total:>6.1f}")
    click.echo(f"{'total':<12} {'':>3} {'':>7} {budget.total_w:>6.1f} W")
    try:
        runtimes = power.battery_runtimes(parts, budget.total_w, efficiency, usable_fraction)
    except ValueError as exc:
        raise BracketryError(str(exc)) from None
    for part, hours in runtimes:
        click.echo(f"battery {part.part_number} {part.capacity_ah:g} Ah at {part.voltage_v:g} V "
                   f"({power.battery_energy_wh(part.capacity_ah or 0, part.voltage_v or 0):.0f} Wh): "
                   f"{hours:.2f} h at {budget.total_w:.1f} W")


@command.command("bandwidth")
@click.option("--fps", type=Number(0.0, 10000.0, min_open=True), default=22.0, show_default=True,
              help="Frames per second per camera (0 to 10000).")
@click.option("--width", type=Integer(1, 65535), default=1920, show_default=True, help="Image width in pixels.")
@click.option("--height", type=Integer(1, 65535), default=1200, show_default=True, help="Image height in pixels.")
@click.option("--pixel-format", type=click.Choice(sorted(bw.PIXEL_FORMAT_BITS)), default="BayerRG12",
              show_default=True, help="GenICam pixel format (sets the bits per pixel).")
@click.option("--packet-size", type=Integer(576, 16000), default=1500, show_default=True,
              help="GevSCPSPacketSize in bytes (1500 standard MTU, 9000 jumbo frames).")
@click.option("--extended-ids", is_flag=True, help="GVSP 2.0 extended ids (20-byte GVSP header instead of 8).")
@click.option("--cameras", type=count(1, 64), default=2, show_default=True, help="Cameras sharing the uplink.")
@click.option("--extra-mbps", type=non_negative(1e6), default=0.0, show_default=True,
              help="Other traffic on the uplink in Mbit/s (e.g. 8 for a VLP-16 on the same switch).")
def bandwidth_cmd(fps: float, width: int, height: int, pixel_format: str, packet_size: int, extended_ids: bool,
                  cameras: int, extra_mbps: float) -> int:
    """GVSP bandwidth per camera (headers included) and whether a shared uplink fits (exit 0 either way)."""
    try:
        s = bw.stream_bandwidth(fps, width, height, pixel_format, packet_size, extended_ids)
    except ValueError as exc:
        raise BracketryError(str(exc)) from None
    click.echo(f"camera: {width}x{height} {pixel_format} at {fps:g} fps, packet size {packet_size} B: "
               f"{s.data_packets_per_frame} data packets/frame")
    click.echo(f"  payload {s.payload_mbps:8.1f} Mbit/s")
    click.echo(f"  IP      {s.ip_mbps:8.1f} Mbit/s (IP/UDP/GVSP headers, leader, trailer)")
    click.echo(f"  wire    {s.wire_mbps:8.1f} Mbit/s (+ Ethernet header, FCS, preamble, gap): "
               f"{100 * s.overhead_fraction:.1f} % over payload")
    one = "fits" if s.wire_mbps <= bw.LINK_RATES_MBPS["1GbE"] else "does NOT fit"
    click.echo(f"  one camera on its own 1 GbE port: {one} ({s.wire_mbps / 10:.0f} % of the link)")
    extra = f" + {extra_mbps:g} Mbit/s other" if extra_mbps else ""
    click.echo(f"uplink shared by {cameras} camera(s){extra}: {s.wire_mbps * cameras + extra_mbps:.1f} Mbit/s")
    for v in bw.uplink_verdicts(s, cameras, extra_mbps):
        click.echo(f"  {v.link:<7} {'fits' if v.fits else 'does NOT fit':<13} ({100 * v.utilisation:.0f} % of "
                   f"{v.link_mbps:g} Mbit/s)")
    return EXIT_OK


@command.command("diagram")
@click.option("--out", type=output_file(suffixes=(".svg", ".dot")), default=None,
              help="Output file: .svg (SVG) or .dot (Graphviz DOT); default: print SVG to stdout.")
@overwrite_option()
@click.option("--wiring", "wiring_path", type=input_file(), default=None,
              help="Wiring description YAML (default hw/wiring.yaml).")
def diagram_cmd(out: Path | None, overwrite: bool, wiring_path: Path | None) -> None:
    """Render hw/wiring.yaml as an SVG block diagram (or Graphviz DOT with --out FILE.dot)."""
    w = wiring.load_wiring(wiring_path)
    text = diagram.to_dot(w) if out is not None and out.suffix == ".dot" else diagram.to_svg(w)
    if out is None:
        click.echo(text, nl=False)
    else:
        try:
            out.write_text(text)
        except OSError as exc:
            raise BracketryError(f"cannot write {out}: {exc.strerror}") from None
        click.echo(f"wrote {out}")


@command.command("check")
def check_cmd() -> int:
    """Check that the firmware pin files agree with hw/wiring.yaml (exit 1 on any disagreement)."""
    problems = wiring.check_all()
    for p in problems:
        click.echo(p)
    if not problems:
        click.echo("hw/wiring.yaml, pins.h and pins.py agree")
    return EXIT_PROBLEMS if problems else EXIT_OK
