"""Which SPDP datagrams about one participant reached one port, in which order: read from a
capture with tshark's RTPS dissector (``ros2_lab.rtps_fields``). Written to find why a
node back after its own lease reached its sibling on the same drone only some of the time
(docs/ros2.md, "A node back after its own lease"): whether the relay's datagram or the
node's own landed first, and which of the node's DATA(p)s listed its static endpoints.

``python -m swarmd_lab.rtps_timeline CAPTURE PORT PREFIX [--last-life]`` prints one
line per datagram: seconds from the first, who sent it (relay or node), its sequence
number, dispose or alive, and how many static EDP endpoints it lists.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd_lab.ros2_lab import rtps_fields

SPDP_WRITER: Final = "0x000100c2"
STATIC_EDP_PREFIX: Final = "eProsimaEDPStatic_"
DEFAULT_RELAY_PORT: Final = 7399
FIELDS: Final = (
    "frame.time_epoch",
    "icmp.type",
    "icmpv6.type",
    "udp.srcport",
    "udp.dstport",
    "rtps.guidPrefix.src",
    "rtps.sm.wrEntityId",
    "rtps.sm.seqNumber",
    "rtps.param.status_info",
    "rtps.property_name",
)


@dataclass(frozen=True, slots=True)
class SpdpArrival:
    at: float  # capture time, seconds
    from_relay: bool
    sequence_number: int
    disposed: bool  # a DATA(p[UD]) (PID_STATUS_INFO set)
    static_endpoints: int  # eProsimaEDPStatic_* properties listed


def spdp_arrivals(
    rows: Sequence[Sequence[str]], port: int, prefix: str, relay_port: int = DEFAULT_RELAY_PORT
) -> list[SpdpArrival]:
    """The SPDP datagrams of participant ``prefix`` (hex, as tshark prints it) to ``port``,
    from ``rows`` of ``FIELDS``; datagrams quoted back in ICMP errors are left out."""
    out = []
    for at, icmp, icmpv6, src, dst, guid_prefix, writers, sns, status, names in rows:
        if icmp or icmpv6 or dst != str(port) or guid_prefix.replace(":", "") != prefix:
            continue
        if writers.split(",")[0] != SPDP_WRITER or not sns:
            continue
        out.append(
            SpdpArrival(
                float(at),
                src == str(relay_port),
                int(sns.split(",")[0]),
                status not in ("", "0x00000000"),
                sum(n.startswith(STATIC_EDP_PREFIX) for n in names.split(",")),
            )
        )
    return out


def last_life(arrivals: Sequence[SpdpArrival], before_s: float = 0.05) -> list[SpdpArrival]:
    """The arrivals from the node's last first DATA(p) (sequence number 1) on, and the
    relay's from ``before_s`` earlier (it may pass the node's own on first)."""
    starts = [a.at for a in arrivals if not a.from_relay and a.sequence_number == 1]
    if not starts:
        return list(arrivals)
    return [a for a in arrivals if a.at >= starts[-1] - before_s]


def read_arrivals(
    pcap: Path, port: int, prefix: str, relay_port: int = DEFAULT_RELAY_PORT
) -> list[SpdpArrival]:
    return spdp_arrivals(rtps_fields(pcap, *FIELDS), port, prefix, relay_port)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture", type=Path)
    parser.add_argument("port", type=int, help="the receiving participant's discovery port")
    parser.add_argument("prefix", help="the sending participant's GUID prefix, 24 hex digits")
    parser.add_argument("--relay-port", type=int, default=DEFAULT_RELAY_PORT)
    parser.add_argument("--last-life", action="store_true", help="from its last restart on")
    args = parser.parse_args(argv)
    arrivals = read_arrivals(args.capture, args.port, args.prefix.lower(), args.relay_port)
    if args.last_life:
        arrivals = last_life(arrivals)
    start = arrivals[0].at if arrivals else 0.0
    for a in arrivals:
        kind = "dispose" if a.disposed else f"alive, {a.static_endpoints} static endpoints"
        who = "relay" if a.from_relay else "node"
        print(f"{a.at - start:+9.3f} s  {who:5}  sn {a.sequence_number}  {kind}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
