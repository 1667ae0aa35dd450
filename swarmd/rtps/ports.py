"""The standard RTPS port mapping (spec 9.6.1.1) and the SPDP multicast group.

port = PB + DG * domain + offset (+ PG * participant index for unicast ports).
"""

from __future__ import annotations

from typing import Final

PORT_BASE: Final = 7400  # PB
DOMAIN_GAIN: Final = 250  # DG
PARTICIPANT_GAIN: Final = 2  # PG
OFFSET_D0: Final = 0  # metatraffic multicast (SPDP)
OFFSET_D1: Final = 10  # metatraffic unicast
OFFSET_D2: Final = 1  # user multicast
OFFSET_D3: Final = 11  # user unicast

SPDP_MULTICAST_GROUP: Final = "239.255.0.1"
MAX_PORT: Final = 65535
# Cyclone's DDSI_MAX_DOMAIN_ID-equivalent: the largest domain whose d0 port still fits
MAX_DOMAIN_ID: Final = (MAX_PORT - PORT_BASE - OFFSET_D3) // DOMAIN_GAIN


def _check(port: int, what: str) -> int:
    if not 0 < port <= MAX_PORT:
        raise ValueError(f"{what} port {port} is outside 1..{MAX_PORT}")
    return port


def _check_domain(domain_id: int) -> None:
    if not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"domain id {domain_id} is outside 0..{MAX_DOMAIN_ID}")


def spdp_multicast_port(domain_id: int) -> int:
    _check_domain(domain_id)
    return _check(PORT_BASE + DOMAIN_GAIN * domain_id + OFFSET_D0, "SPDP multicast")


def user_multicast_port(domain_id: int) -> int:
    _check_domain(domain_id)
    return _check(PORT_BASE + DOMAIN_GAIN * domain_id + OFFSET_D2, "user multicast")


def metatraffic_unicast_port(domain_id: int, participant_index: int) -> int:
    _check_domain(domain_id)
    if participant_index < 0:
        raise ValueError(f"participant index {participant_index} is negative")
    port = PORT_BASE + DOMAIN_GAIN * domain_id + OFFSET_D1 + PARTICIPANT_GAIN * participant_index
    return _check(port, "metatraffic unicast")


def user_unicast_port(domain_id: int, participant_index: int) -> int:
    _check_domain(domain_id)
    if participant_index < 0:
        raise ValueError(f"participant index {participant_index} is negative")
    port = PORT_BASE + DOMAIN_GAIN * domain_id + OFFSET_D3 + PARTICIPANT_GAIN * participant_index
    return _check(port, "user unicast")


def max_participant_index(domain_id: int) -> int:
    """The largest participant index whose unicast ports still fit in 16 bits."""
    _check_domain(domain_id)
    return (MAX_PORT - PORT_BASE - DOMAIN_GAIN * domain_id - OFFSET_D3) // PARTICIPANT_GAIN
