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
import xml.etree.ElementTree as ET  # noqa: S405 - parses tshark's own PDML
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.rtps import SpdpDisposed, SpdpSample
from swarmd.rtps.spdp import (
    PID_SWARMD_AUTHENTICATOR,
    PID_SWARMD_BUNDLE_DIGEST,
    PID_SWARMD_HEARD,
    PID_SWARMD_LINK_QUALITY,
    STATUS_INFO_DISPOSED,
    STATUS_INFO_UNREGISTERED,
)

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


# --- the dissection tree (PDML), reduced to what an SPDP check needs -------------------

FieldMap = dict[str, list[str]]


@dataclass(frozen=True, slots=True)
class TsharkParam:
    """One parameter as Wireshark dissected it; ``section`` is "inline" or "payload"."""

    pid: int
    section: str
    fields: FieldMap  # every descendant field: name -> "show" values in document order


@dataclass(frozen=True, slots=True)
class TsharkSubmessage:
    kind: str  # Wireshark's name: DATA, INFO_TS, INFO_DST, ...
    fields: FieldMap  # descendant fields outside parameters
    params: tuple[TsharkParam, ...]


@dataclass(frozen=True, slots=True)
class TsharkPacket:
    """One frame's RTPS layer; ``header`` holds the message header's fields."""

    header: FieldMap
    submessages: tuple[TsharkSubmessage, ...]


def _add(fields: FieldMap, name: str, show: str) -> None:
    fields.setdefault(name, []).append(show)


def _collect(elem: ET.Element, fields: FieldMap, params: list[TsharkParam], section: str) -> None:
    for child in elem.findall("field"):
        name = child.get("name", "")
        show = child.get("show", "")
        if name == "" and any(g.get("name") == "rtps.param.id" for g in child.findall("field")):
            pfields: FieldMap = {}
            _collect(child, pfields, [], section)
            # parameter_data's "show" is colon-separated hex; keep it as plain hex
            if "rtps.parameter_data" in pfields:
                pfields["rtps.parameter_data"] = [
                    v.replace(":", "") for v in pfields["rtps.parameter_data"]
                ]
            params.append(TsharkParam(int(pfields["rtps.param.id"][0], 16), section, pfields))
            continue
        if name == "" and show.startswith("inlineQos"):
            _collect(child, fields, params, "inline")
            continue
        if name:
            if name == "rtps.parameter_data":
                show = show.replace(":", "")
            _add(fields, name, show)
        _collect(child, fields, params, section)


def _submessage_kind(showname: str) -> str:
    # "submessageId: DATA (0x15)" -> "DATA"
    text = showname.split(":", 1)[-1].strip()
    return text.rsplit(" (", 1)[0]


def dissect_tree(pcap: Path) -> list[TsharkPacket]:
    """Wireshark's RTPS dissection of each frame (``tshark -T pdml``), as a small tree."""
    exe = tshark_path()
    if exe is None:
        raise RuntimeError("tshark is not installed (apt-get install tshark)")
    proc = subprocess.run(  # noqa: S603 - argv list, no shell
        [exe, "-n", "-r", str(pcap), "-T", "pdml"],
        capture_output=True,
        text=True,
        timeout=TSHARK_TIMEOUT_S,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"tshark failed ({proc.returncode}): {proc.stderr.strip()}")
    root = ET.fromstring(proc.stdout)  # noqa: S314 - tshark's own output, not untrusted XML
    packets = []
    for packet in root.findall("packet"):
        header: FieldMap = {}
        submessages = []
        for proto in packet.findall("proto"):
            if proto.get("name") != "rtps":
                continue
            for child in proto.findall("field"):
                name = child.get("name", "")
                if name == "rtps.sm.id":
                    fields: FieldMap = {}
                    params: list[TsharkParam] = []
                    _collect(child, fields, params, "payload")
                    kind = _submessage_kind(child.get("showname", ""))
                    submessages.append(TsharkSubmessage(kind, fields, tuple(params)))
                elif name:
                    _add(header, name, child.get("show", ""))
                    sub: FieldMap = {}
                    _collect(child, sub, [], "header")
                    for key, values in sub.items():
                        header.setdefault(key, []).extend(values)
        packets.append(TsharkPacket(header, tuple(submessages)))
    return packets


# --- SPDP as Wireshark sees it: the same JSON-able shape the fixtures' sidecars hold ----

LOCATOR_PIDS: Final = {
    0x0032: "metatraffic_unicast_locators",
    0x0033: "metatraffic_multicast_locators",
    0x0031: "default_unicast_locators",
    0x0048: "default_multicast_locators",
}
PID_DOMAIN_ID: Final = 0x000F
PID_STATUS_INFO: Final = 0x0071
PID_KEY_HASH: Final = 0x0070
PID_SENTINEL: Final = 0x0001
SPDP_WRITER: Final = "0x000100c2"


def _vendor(show: str) -> str:
    # "0x0110" -> "01.10", the form swarmd's VendorId prints
    value = int(show, 16)
    return f"{value >> 8:02x}.{value & 0xFF:02x}"


def _version(show: str) -> str:
    value = int(show, 16)
    return f"{value >> 8}.{value & 0xFF}"


def _prefix_hex(show: str) -> str:
    return show.replace(":", "")[:24]


def _participant_view(params: Sequence[TsharkParam], header: FieldMap) -> dict[str, object]:
    view: dict[str, object] = {name: [] for name in LOCATOR_PIDS.values()}
    view["properties"] = []
    vendor_pids: list[str] = []
    for p in params:
        f = p.fields
        if p.pid in LOCATOR_PIDS:
            kind = int(f["rtps.locator.kind"][0], 16)
            text = (
                f"udp/{f['rtps.locator.ipv4'][0]}:{f['rtps.locator.port'][0]}"
                if kind == 1
                else f"kind{kind}"
            )
            locators = view[LOCATOR_PIDS[p.pid]]
            assert isinstance(locators, list)
            locators.append(text)
        elif "rtps.param.participant_guid" in f:
            view["guid_prefix"] = _prefix_hex(f["rtps.param.participant_guid"][0])
        elif p.pid == 0x0015:
            view["protocol_version"] = _version(f["rtps.version"][0])
        elif p.pid == 0x0016:
            view["vendor_id"] = _vendor(f["rtps.vendorId"][0])
        elif p.pid == PID_DOMAIN_ID:
            view["domain_id"] = int.from_bytes(bytes.fromhex(f["rtps.parameter_data"][0]), "little")
        elif "rtps.param.ntpTime.sec" in f:
            view["lease_duration"] = [
                int(f["rtps.param.ntpTime.sec"][0]),
                int(f["rtps.param.ntpTime.fraction"][0]),
            ]
        elif "rtps.param.builtin_endpoint_set" in f:
            view["builtin_endpoints"] = int(f["rtps.param.builtin_endpoint_set"][0], 16)
        elif "rtps.param.entityName" in f:
            view["entity_name"] = f["rtps.param.entityName"][0]
        elif "rtps.property_name" in f:
            view["properties"] = [
                [n, v]
                for n, v in zip(
                    f["rtps.property_name"], f.get("rtps.property_value", []), strict=True
                )
            ]
        elif p.pid & 0x8000:
            vendor_pids.append(f"0x{p.pid:04x}")
    view["vendor_pids"] = vendor_pids
    view.setdefault("vendor_id", _vendor(header["rtps.vendorId"][0]))
    return view


def spdp_view(packet: TsharkPacket) -> list[dict[str, object]]:
    """Every SPDP sample in ``packet``, as Wireshark decoded it (JSON-able dicts).

    Alive: ``{"kind": "alive", "sequence_number", "destination", "participant": {...}}``;
    disposed: ``{"kind": "disposed", "sequence_number", "destination", "guid_prefix",
    "status_info"}``. ``destination`` is the INFO_DST prefix in hex, None for none/unknown.
    """
    samples: list[dict[str, object]] = []
    destination: str | None = None
    for sm in packet.submessages:
        if sm.kind == "INFO_DST":
            dst = _prefix_hex(sm.fields["rtps.guidPrefix.dst"][0])
            destination = None if dst == "0" * 24 else dst
            continue
        if sm.kind != "DATA" or sm.fields.get("rtps.sm.wrEntityId", [""])[0] != SPDP_WRITER:
            continue
        sample: dict[str, object] = {
            "sequence_number": int(sm.fields["rtps.sm.seqNumber"][0]),
            "destination": destination,
        }
        status = 0
        for p in sm.params:
            if p.section == "inline" and p.pid == PID_STATUS_INFO:
                status = int(p.fields["rtps.param.status_info"][0], 16)
        payload = [p for p in sm.params if p.section == "payload"]
        if status & 0x3:
            sample["kind"] = "disposed"
            sample["status_info"] = status
            for p in payload:
                if "rtps.param.participant_guid" in p.fields:
                    sample["guid_prefix"] = _prefix_hex(p.fields["rtps.param.participant_guid"][0])
        else:
            sample["kind"] = "alive"
            sample["participant"] = _participant_view(payload, packet.header)
        samples.append(sample)
    return samples


def decoded_view(sample: SpdpSample) -> dict[str, object]:
    """``sample`` as swarmd decoded it, in ``spdp_view``'s shape (for direct comparison)."""
    view: dict[str, object] = {
        "sequence_number": sample.sequence_number,
        "destination": None if sample.destination is None else sample.destination.hex(),
    }
    if isinstance(sample, SpdpDisposed):
        view["kind"] = "disposed"
        view["status_info"] = STATUS_INFO_DISPOSED | STATUS_INFO_UNREGISTERED
        view["guid_prefix"] = sample.guid_prefix.hex()
        return view
    p = sample.participant
    part: dict[str, object] = {
        "guid_prefix": p.guid_prefix.hex(),
        "protocol_version": str(p.protocol_version),
        "vendor_id": str(p.vendor_id),
        "lease_duration": [p.lease_duration.seconds, p.lease_duration.fraction],
        "builtin_endpoints": p.builtin_endpoints,
        "properties": [[name, value] for name, value in p.properties],
    }
    if p.domain_id is not None:
        part["domain_id"] = p.domain_id
    if p.entity_name is not None:
        part["entity_name"] = p.entity_name
    for name in LOCATOR_PIDS.values():
        part[name] = [str(loc) for loc in getattr(p, name)]
    vendor_pids = [f"0x{x.pid:04x}" for x in p.extra_parameters if x.pid & 0x8000]
    for pid, value in (
        (PID_SWARMD_BUNDLE_DIGEST, p.bundle_digest),
        (PID_SWARMD_HEARD, p.heard),
        (PID_SWARMD_LINK_QUALITY, p.link_quality_permille),
        (PID_SWARMD_AUTHENTICATOR, p.authenticator),
    ):
        if value is not None:
            vendor_pids.append(f"0x{pid:04x}")
    part["vendor_pids"] = vendor_pids
    view["kind"] = "alive"
    view["participant"] = part
    return view
