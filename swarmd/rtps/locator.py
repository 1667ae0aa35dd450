"""Locator_t (spec 9.3.2.2): kind, port and a 16-byte address.

UDPv4 and UDPv6 are understood; other kinds (shared memory, TCP, vendor transports) are
kept as opaque ``Locator`` values so a decoder can skip them without failing.
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from typing import Final

LOCATOR_KIND_INVALID: Final = -1
LOCATOR_KIND_RESERVED: Final = 0
LOCATOR_KIND_UDPv4: Final = 1
LOCATOR_KIND_UDPv6: Final = 2
LOCATOR_KIND_TCPv4: Final = 4
LOCATOR_KIND_TCPv6: Final = 8

LOCATOR_SIZE: Final = 24


@dataclass(frozen=True, slots=True)
class Locator:
    kind: int
    port: int
    address: bytes  # 16 octets, network order

    def __post_init__(self) -> None:
        if len(self.address) != 16:
            raise ValueError(f"locator address must be 16 bytes, got {len(self.address)}")

    @classmethod
    def udpv4(cls, host: str, port: int) -> Locator:
        return cls(LOCATOR_KIND_UDPv4, port, bytes(12) + ipaddress.IPv4Address(host).packed)

    @classmethod
    def udpv6(cls, host: str, port: int) -> Locator:
        return cls(LOCATOR_KIND_UDPv6, port, ipaddress.IPv6Address(host).packed)

    @property
    def is_udp(self) -> bool:
        return self.kind in (LOCATOR_KIND_UDPv4, LOCATOR_KIND_UDPv6)

    @property
    def host(self) -> str:
        """The address as text; empty for kinds that carry no IP address."""
        if self.kind == LOCATOR_KIND_UDPv4 or self.kind == LOCATOR_KIND_TCPv4:
            return str(ipaddress.IPv4Address(self.address[12:]))
        if self.kind == LOCATOR_KIND_UDPv6 or self.kind == LOCATOR_KIND_TCPv6:
            return str(ipaddress.IPv6Address(self.address))
        return ""

    @property
    def is_multicast(self) -> bool:
        if self.kind == LOCATOR_KIND_UDPv4:
            return ipaddress.IPv4Address(self.address[12:]).is_multicast
        if self.kind == LOCATOR_KIND_UDPv6:
            return ipaddress.IPv6Address(self.address).is_multicast
        return False

    def sockaddr(self) -> tuple[str, int]:
        return self.host, self.port

    def __str__(self) -> str:
        if self.kind == LOCATOR_KIND_UDPv4:
            return f"udp/{self.host}:{self.port}"
        if self.kind == LOCATOR_KIND_UDPv6:
            return f"udp/[{self.host}]:{self.port}"
        return f"kind{self.kind}/{self.address.hex()}:{self.port}"
