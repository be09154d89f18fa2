"""GigE Vision (GVSP) stream bandwidth per camera and for a shared uplink, headers included.

Model of one frame on the wire: the image payload (``width * height * bits_per_pixel / 8`` bytes) is cut into data
packets of ``packet_size - IP - UDP - GVSP`` bytes (``packet_size`` is the camera's GevSCPSPacketSize: the IP packet
size, i.e. the MTU it fits), plus one leader and one trailer packet. Every packet also costs the Ethernet header and
FCS (18 bytes) and, on the wire, the preamble/SFD and inter-frame gap (20 bytes). Three levels are reported:
``payload`` (pixels only), ``ip`` (what an IP-level counter such as iftop shows) and ``wire`` (the line occupancy that
must stay below the link rate).
"""

from __future__ import annotations

from dataclasses import dataclass

#: bits per pixel on the wire, per PFNC pixel format name
PIXEL_FORMAT_BITS: dict[str, int] = {
    "Mono8": 8, "BayerRG8": 8, "Mono10": 16, "BayerRG10": 16, "Mono10p": 10, "BayerRG10p": 10,
    "Mono12": 16, "BayerRG12": 16, "Mono12p": 12, "BayerRG12p": 12, "Mono16": 16, "RGB8": 24,
}
IP_HEADER_BYTES = 20
UDP_HEADER_BYTES = 8
GVSP_HEADER_BYTES = 8  # standard ids (20 with GVSP 2.0 extended ids)
GVSP_EXTENDED_HEADER_BYTES = 20
ETH_HEADER_FCS_BYTES = 18  # 14 header + 4 FCS
ETH_PREAMBLE_IFG_BYTES = 20  # 8 preamble/SFD + 12 inter-frame gap
LEADER_PAYLOAD_BYTES = 36  # image leader: payload type, timestamp, pixel format, size/offset/padding
TRAILER_PAYLOAD_BYTES = 8  # image trailer: payload type, size y
LINK_RATES_MBPS: dict[str, float] = {"1GbE": 1000.0, "2.5GbE": 2500.0, "10GbE": 10000.0}


@dataclass(frozen=True)
class StreamBandwidth:
    """Bandwidth of one camera stream. Rates in Mbit/s (10^6 bit/s); sizes in bytes."""

    fps: float
    width: int
    height: int
    pixel_format: str
    packet_size: int
    payload_bytes_per_frame: int
    data_packets_per_frame: int
    ip_bytes_per_frame: int
    wire_bytes_per_frame: int

    @property
    def payload_mbps(self) -> float:
        return self.payload_bytes_per_frame * 8 * self.fps / 1e6

    @property
    def ip_mbps(self) -> float:
        return self.ip_bytes_per_frame * 8 * self.fps / 1e6

    @property
    def wire_mbps(self) -> float:
        return self.wire_bytes_per_frame * 8 * self.fps / 1e6

    @property
    def overhead_fraction(self) -> float:
        """Wire bytes over payload bytes, minus 1 (0.05 = 5 % overhead)."""
        return self.wire_bytes_per_frame / self.payload_bytes_per_frame - 1.0


def stream_bandwidth(fps: float, width: int, height: int, pixel_format: str, packet_size: int = 1500,
                     extended_ids: bool = False) -> StreamBandwidth:
    """Bandwidth of one GVSP image stream (see the module docstring for the packet model).

    ``packet_size`` is GevSCPSPacketSize in bytes (576..9000: 1500 standard MTU, 9000 jumbo frames).
    Raises ValueError on an unknown pixel format or out-of-range sizes.
    """
    if pixel_format not in PIXEL_FORMAT_BITS:
        raise ValueError(f"unknown pixel format {pixel_format!r} (known: {', '.join(PIXEL_FORMAT_BITS)})")
    if not 576 <= packet_size <= 16000:
        raise ValueError(f"packet size {packet_size} outside 576..16000 bytes")
    if width <= 0 or height <= 0 or fps <= 0:
        raise ValueError("width, height and fps must be positive")
    gvsp = GVSP_EXTENDED_HEADER_BYTES if extended_ids else GVSP_HEADER_BYTES
    headers = IP_HEADER_BYTES + UDP_HEADER_BYTES + gvsp
    data_per_packet = packet_size - headers
    payload = (width * height * PIXEL_FORMAT_BITS[pixel_format] + 7) // 8
    n_data = -(-payload // data_per_packet)
    ip_bytes = payload + n_data * headers + (headers + LEADER_PAYLOAD_BYTES) + (headers + TRAILER_PAYLOAD_BYTES)
    n_packets = n_data + 2
    wire_bytes = ip_bytes + n_packets * (ETH_HEADER_FCS_BYTES + ETH_PREAMBLE_IFG_BYTES)
    return StreamBandwidth(fps, width, height, pixel_format, packet_size, payload, n_data, ip_bytes, wire_bytes)


@dataclass(frozen=True)
class UplinkVerdict:
    """Whether ``n_cameras`` streams (+ other traffic) fit a link. Rates in Mbit/s at wire level."""

    link: str
    link_mbps: float
    load_mbps: float

    @property
    def utilisation(self) -> float:
        return self.load_mbps / self.link_mbps

    @property
    def fits(self) -> bool:
        return self.load_mbps <= self.link_mbps


def uplink_verdicts(stream: StreamBandwidth, n_cameras: int = 2, extra_mbps: float = 0.0) -> list[UplinkVerdict]:
    """Verdict per standard link rate for ``n_cameras`` identical streams plus ``extra_mbps`` (e.g. lidar ~8)."""
    load = stream.wire_mbps * n_cameras + extra_mbps
    return [UplinkVerdict(name, rate, load) for name, rate in LINK_RATES_MBPS.items()]
