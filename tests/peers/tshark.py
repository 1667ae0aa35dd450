"""tshark as an independent RTPS implementation: write datagrams to a pcap, dissect them.

The pcap is built by hand (Ethernet + IPv4 + UDP with correct checksums, RFC 791/768), so
Wireshark sees exactly what a capture on the wire would show and no checksum or length
expert info can come from the framing. Wireshark's RTPS heuristic dissector is enabled on
every UDP port by default (reference section 1.15), so any port works.
"""

from __future__ import annotations

import ipaddress
import json
import shutil
import struct
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

PCAP_MAGIC: Final = 0xA1B2C3D4
LINKTYPE_ETHERNET: Final = 1
ETHERTYPE_IPV4: Final = 0x0800
IPPROTO_UDP: Final = 17
SNAPLEN: Final = 65535
TSHARK_TIMEOUT_S: Final = 60.0


@dataclass(frozen=True, slots=True)
class Datagram:
    """One UDP datagram between two IPv4 endpoints."""

    payload: bytes
    source: tuple[str, int]
    destination: tuple[str, int]


def tshark_path() -> str | None:
    return shutil.which("tshark")


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\x00"
    total: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def _mac_for(address: ipaddress.IPv4Address, index: int) -> bytes:
    if address.is_multicast:
        # RFC 1112 section 6.4: 01:00:5e + low 23 bits of the group
        low = int(address) & 0x7FFFFF
        return bytes((0x01, 0x00, 0x5E)) + low.to_bytes(3, "big")
    return bytes((0x02, 0x00)) + address.packed[:3] + bytes((index & 0xFF,))


def udp_frame(datagram: Datagram, ident: int = 0) -> bytes:
    """An Ethernet II frame carrying ``datagram`` in IPv4/UDP, both checksums correct."""
    src = ipaddress.IPv4Address(datagram.source[0])
    dst = ipaddress.IPv4Address(datagram.destination[0])
    udp_len = 8 + len(datagram.payload)
    pseudo = src.packed + dst.packed + struct.pack("!BBH", 0, IPPROTO_UDP, udp_len)
    udp_head = struct.pack("!HHHH", datagram.source[1], datagram.destination[1], udp_len, 0)
    udp_sum = _checksum(pseudo + udp_head + datagram.payload) or 0xFFFF  # 0 means "none"
    udp = struct.pack("!HHHH", datagram.source[1], datagram.destination[1], udp_len, udp_sum)
    ttl = 1 if dst.is_multicast else 64
    ip_head = struct.pack(
        "!BBHHHBBH4s4s",
        0x45,
        0,
        20 + udp_len,
        ident & 0xFFFF,
        0x4000,
        ttl,
        IPPROTO_UDP,
        0,
        src.packed,
        dst.packed,
    )
    ip_head = ip_head[:10] + struct.pack("!H", _checksum(ip_head)) + ip_head[12:]
    eth = _mac_for(dst, 0) + _mac_for(src, int(src) & 0xFF) + struct.pack("!H", ETHERTYPE_IPV4)
    return eth + ip_head + udp + datagram.payload


def write_pcap(path: Path, datagrams: Sequence[Datagram], start_s: int = 1_700_000_000) -> None:
    """A classic pcap (microsecond timestamps, one frame per datagram, 1 ms apart)."""
    out = [struct.pack("<IHHiIII", PCAP_MAGIC, 2, 4, 0, 0, SNAPLEN, LINKTYPE_ETHERNET)]
    for i, dgram in enumerate(datagrams):
        frame = udp_frame(dgram, ident=i + 1)
        out.append(struct.pack("<IIII", start_s, i * 1000, len(frame), len(frame)))
        out.append(frame)
    path.write_bytes(b"".join(out))


def dissect_fields(pcap: Path, fields: Sequence[str]) -> list[dict[str, list[str]]]:
    """For each frame, every occurrence of each field (``tshark -T json -e ...``).

    Fields absent from a frame map to an empty list. Raises ``RuntimeError`` with tshark's
    stderr if tshark fails.
    """
    exe = tshark_path()
    if exe is None:
        raise RuntimeError("tshark is not installed (apt-get install tshark)")
    argv = [exe, "-n", "-r", str(pcap), "-T", "json"]
    for name in fields:
        argv += ["-e", name]
    proc = subprocess.run(  # noqa: S603 - argv list, no shell
        argv, capture_output=True, text=True, timeout=TSHARK_TIMEOUT_S, check=False
    )
    if proc.returncode != 0:
        raise RuntimeError(f"tshark failed ({proc.returncode}): {proc.stderr.strip()}")
    frames = json.loads(proc.stdout)
    result = []
    for frame in frames:
        layers = frame["_source"]["layers"]
        result.append({name: [str(v) for v in layers.get(name, [])] for name in fields})
    return result


def dissect_verbose(pcap: Path) -> list[str]:
    """``tshark -V`` text, one string per frame (for humans and substring checks)."""
    exe = tshark_path()
    if exe is None:
        raise RuntimeError("tshark is not installed (apt-get install tshark)")
    proc = subprocess.run(  # noqa: S603 - argv list, no shell
        [exe, "-n", "-r", str(pcap), "-V"],
        capture_output=True,
        text=True,
        timeout=TSHARK_TIMEOUT_S,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"tshark failed ({proc.returncode}): {proc.stderr.strip()}")
    return [block for block in proc.stdout.split("\n\n") if block.startswith("Frame ")]


def dissect_datagrams(
    tmp_dir: Path, datagrams: Sequence[Datagram], fields: Sequence[str], name: str = "dissect"
) -> list[dict[str, list[str]]]:
    """``write_pcap`` into ``tmp_dir`` then ``dissect_fields``."""
    pcap = tmp_dir / f"{name}.pcap"
    write_pcap(pcap, datagrams)
    return dissect_fields(pcap, fields)
