"""``bracketry cameras probe|configure|grab --address IP``: GigE cameras through Aravis, opened by IP only."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import click

from bracketry_base.errors import BracketryError
from bracketry_base.options import Integer, IPv4, count, option, output_dir, overwrite_option, positive


def _open(address: str, side: str):  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.camera import GigECamera

    return GigECamera(address, side=side)


def _settings(profile: str, pixel_format: str | None, width: int | None, height: int | None, trigger_line: str,
              activation: str, packet_size: int | None, packet_delay: int | None):  # type: ignore[no-untyped-def]
    from bracketry_rig.cameras.profiles import CameraSettings

    default_format = "BayerRG12p" if profile == "basler_ace2" else "Mono16"
    return CameraSettings(profile=profile, pixel_format=pixel_format or default_format, width=width, height=height,
                          trigger_source=trigger_line, trigger_activation=activation,
                          packet_size_bytes=packet_size, packet_delay_ticks=packet_delay)


_profile_options = [
    click.option("--profile", type=click.Choice(["basler_ace2", "aravis_fake"]), default="basler_ace2",
                 show_default=True, help="Feature profile: the Basler ace 2 of the rig, or Aravis' fake camera."),
    click.option("--pixel-format", help="BayerRG12p (default, Basler), BayerRG12, Mono16 (default, fake), ..."),
    click.option("--width", type=Integer(16, 65535), help="Image width in pixels (default: the camera's maximum)."),
    click.option("--height", type=Integer(16, 65535), help="Image height in pixels (default: the camera's maximum)."),
    click.option("--trigger-line", default="Line3", show_default=True, help="TriggerSource: the trigger input line."),
    click.option("--trigger-activation", default="FallingEdge", show_default=True,
                 help="TriggerActivation: the edge that starts the exposure."),
    click.option("--packet-size", type=Integer(576, 16000), help="GevSCPSPacketSize in bytes."),
    click.option("--packet-delay", type=Integer(0, 2**31 - 1), help="GevSCPD, inter-packet delay in camera ticks."),
]
address_option = click.option("--address", required=True, type=IPv4(),
                              help="Camera IPv4 address (cameras are opened by IP only, never by discovery).")


def profile_options(f):  # type: ignore[no-untyped-def]
    for opt in reversed(_profile_options):
        f = opt(f)
    return f


@click.group("cameras")
def command() -> None:
    """GigE cameras through Aravis: probe, configure, grab. Cameras are opened by IP address (unicast only)."""


@command.command("probe")
@address_option
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def probe(address: str, as_json: bool) -> None:
    """Identity and the features the profiles use (present or not, value, allowed values)."""
    with _open(address, "camera") as cam:
        info = cam.probe()
    if as_json:
        click.echo(json.dumps(info, indent=1, default=str))
        return
    click.echo(f"{info['vendor']} {info['model']} serial {info['serial']} at {address}")
    click.echo(f"pixel formats: {', '.join(info['pixel_formats'])}")
    for name, feat in info["features"].items():
        if feat["available"]:
            values = f"  [{', '.join(feat.get('values', []))}]" if feat.get("values") else ""
            click.echo(f"  {name:28} {feat['value']}{values}")
        else:
            click.echo(f"  {name:28} (absent)")


@command.command("configure")
@address_option
@profile_options
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def configure(address: str, profile: str, pixel_format: str | None, width: int | None, height: int | None,
              trigger_line: str, trigger_activation: str, packet_size: int | None, packet_delay: int | None,
              as_json: bool) -> int:
    """Write a profile's features, read each back; exit 1 (and say why) when recording would be refused."""
    settings = _settings(profile, pixel_format, width, height, trigger_line, trigger_activation, packet_size,
                         packet_delay)
    with _open(address, "camera") as cam:
        report = cam.configure(settings)
    if as_json:
        click.echo(json.dumps({"ok": report.ok, "features": report.as_rows()}, indent=1, default=str))
    else:
        for r in report.results:
            flag = "" if r.status == "ok" else ("  <- REQUIRED" if r.required else "  (optional)")
            click.echo(f"  {r.name:28} {r.status:9} wanted {r.wanted!r} read {r.read!r}{flag}"
                       + (f" {r.detail}" if r.detail else ""))
    if not report.ok:
        try:
            report.raise_if_mismatch()
        except BracketryError as exc:
            click.echo(f"error: {exc}", err=True)
        return 1
    return 0


@command.command("grab")
@address_option
@profile_options
@click.option("--count", "n_frames", type=count(1, 100000), default=10, show_default=True,
              help="Frames to grab.")
@click.option("--software-trigger", is_flag=True, help="Fire TriggerSoftware for each frame (fake camera).")
@click.option("--exposure-us", type=positive(10_000_000), default=4000.0, show_default=True,
              help="With --software-trigger: exposure set before each trigger (us).")
@option("--timeout-s", "timeout_s", aliases=("--timeout",), type=positive(3600.0), default=10.0, show_default=True,
        help="Give up when the frames have not arrived within this many seconds (exit 1).")
@click.option("--out", type=output_dir(), help="Folder for 16-bit PNGs of the frames (new or empty).")
@overwrite_option()
def grab(address: str, profile: str, pixel_format: str | None, width: int | None, height: int | None,
         trigger_line: str, trigger_activation: str, packet_size: int | None, packet_delay: int | None,
         n_frames: int, software_trigger: bool, exposure_us: float, timeout_s: float, out: Path | None,
         overwrite: bool) -> int:
    """Configure, stream ``--count`` frames, print per-frame status and the stream statistics."""
    settings = _settings(profile, pixel_format, width, height, trigger_line, trigger_activation, packet_size,
                         packet_delay)
    frames = []
    done = threading.Event()

    def on_frame(frame):  # type: ignore[no-untyped-def]
        frames.append(frame)
        if len(frames) >= n_frames:
            done.set()

    with _open(address, "camera") as cam:
        cam.configure(settings).raise_if_mismatch()
        cam.start(on_frame)
        deadline = time.monotonic() + timeout_s
        try:
            while not done.is_set() and time.monotonic() < deadline:
                if software_trigger:
                    cam.set_exposure_us(exposure_us)
                    cam.software_trigger()
                done.wait(0.05)
        finally:
            cam.stop()
        stats = cam.stats().as_dict()
    if out is not None:
        import cv2

        out.mkdir(exist_ok=True)
    for f in frames[:n_frames]:
        mean = float(f.image.mean()) if f.image is not None else float("nan")
        click.echo(f"frame id {f.frame_id:5d} index {f.frame_index:4d} {f.status:16} {f.width}x{f.height} "
                   f"{f.pixel_format} mean {mean:.1f} missing packets {f.missing_packets}")
        if out is not None and f.image is not None:
            cv2.imwrite(str(out / f"{f.cam_timestamp_ns}.png"), f.image)
    click.echo("stream: " + ", ".join(f"{k} {v}" for k, v in stats.items()))
    if len(frames) < n_frames:
        click.echo(f"error: only {len(frames)} of {n_frames} frames within {timeout_s} s", err=True)
        return 1
    return 0
