"""Loopback addresses, and UDP sockets as ``/proc/net/udp{,6}`` prints them: one reading of
each for the three places that need it (a leaf, sans-IO: text in, values out).

- ``swarmd.senderuid`` asks which local user sent a loopback datagram (``loopback_host``,
  ``udp_table_rows``, ``proc_address``);
- ``swarmd.px4.portowner`` names who holds the PX4 link's port (``udp_table_rows``);
- ``swarmd.xrce.keycheck`` counts every loopback address as one origin (``plain_address``).

A v4-mapped address (``::ffff:127.0.0.1``) is read as its IPv4 form everywhere: a dual-stack
socket receives IPv4 datagrams with such a source (ipv6(7)), and it is the same sender.
"""

from __future__ import annotations

import ipaddress
import re
import sys
from collections.abc import Hashable
from typing import Final

# One socket's line of /proc/net/udp{,6} (net/ipv4/udp.c udp4_format_sock, net/ipv6
# datagram.c __ip6_dgram_sock_seq_show): "sl: local_address rem_address st tx:rx tr:when
# retrnsmt uid timeout inode ...". Groups: local address (hex), local port (hex), uid, inode.
UDP_TABLE_ROW: Final = re.compile(
    r"^ *\d+: ([0-9A-Fa-f]{8}|[0-9A-Fa-f]{32}):([0-9A-Fa-f]{4}) \S+ \S+ \S+ \S+ \S+ +(\d+) "
    r"+\d+ +(\d+)",
    re.M,
)

IpAddress = ipaddress.IPv4Address | ipaddress.IPv6Address


def udp_table_rows(text: str) -> list[tuple[str, int, int, int]]:
    """``(hex address, port, uid, inode)`` of each socket line of a ``/proc/net/udp{,6}``
    table (one C scan: a table can hold tens of thousands); other lines are skipped.
    ``proc_address`` turns the hex address into text."""
    return [
        (address, int(port, 16), int(uid), int(inode))
        for address, port, uid, inode in UDP_TABLE_ROW.findall(text)
    ]


def proc_address(text: str) -> str:
    """The address of a ``/proc/net/udp{,6}`` line: each 32-bit word of it is printed in
    host byte order. Raises ValueError on what is not 4 or 16 octets of hex."""
    raw = bytes.fromhex(text)
    if sys.byteorder == "little":
        raw = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    return str(ipaddress.ip_address(raw))


def plain_address(host: str) -> IpAddress | None:
    """``host`` as an address, without an IPv6 scope (``%lo``) and a v4-mapped address as
    its IPv4 form; None when it is not an address."""
    try:
        ip = ipaddress.ip_address(host.partition("%")[0])
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def loopback_host(source: Hashable) -> str | None:
    """The loopback address of a datagram's source (``"127.0.0.1"``, ``"::1"``; a v4-mapped
    address as its IPv4 form), or None when it is not a loopback ``(host, port, ...)``."""
    if not isinstance(source, tuple) or len(source) < 2 or not isinstance(source[0], str):
        return None
    ip = plain_address(source[0])
    return str(ip) if ip is not None and ip.is_loopback else None
