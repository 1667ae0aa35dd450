"""What a received SPDP datagram says, derived once for every receiver.

Decoding is pure and nothing decoded is ever mutated, so the engines of one process share
it: a simulator running N engines hands the same multicast (the same bytes object) to N - 1
of them back to back, and each reads one flat slotted record (``Alive``) instead of chains
of dataclass attributes. Also here: the per-bundle prefix -> index table every engine of a
bundle shares, and the address helpers the locator checks use. The receive path that
consumes all this is ``receive.py``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from swarmd.bundle.model import Bundle, Participant
from swarmd.discovery.peers import clamp_lease
from swarmd.rtps.locator import Locator, LOCATOR_KIND_UDPv4
from swarmd.rtps.spdp import SpdpAlive, SpdpDisposed, SpdpParticipant, Vouch, decode_spdp


@dataclass(frozen=True, slots=True)
class Alive:
    """A received DATA(p) with what every receiver derives from it alike, computed once.

    The fields after ``lease_s`` copy (or pre-chew) the sample's so that the receive path,
    which runs once per datagram per engine (~3M times in a 1000-drone simulation), reads
    one flat slotted record instead of chains of dataclass attributes."""

    sample: SpdpAlive
    prefix: bytes  # the participant's GUID prefix octets
    is_swarmd: bool  # vendor id
    target: tuple[str, int] | None  # its first usable unicast metatraffic locator
    lease_s: float  # its advertised lease, clamped (peers.clamp_lease)
    sn: int
    destination: bytes | None  # INFO_DST's prefix octets, None when sent to everyone
    domain_id: int | None
    plain_tag: bool  # no domain tag (None or empty)
    bundle_digest: bytes | None
    heard: bytes | None
    link_quality_permille: int | None
    vouched: Vouch | None
    metatraffic_locators: tuple[Locator, ...]
    default_locators: tuple[Locator, ...]
    locators: LocatorFacts
    ros2_alive: bytes | None  # PID 0x8A06: the sender's relay's alive ROS 2 participants


@dataclass(frozen=True, slots=True)
class LocatorFacts:
    """Whether a bundle peer's unicast locators (metatraffic: SPDP replies; default: user
    data) are all addresses we may send to (issue 10, attack 7), split into what the datagram
    alone decides (computed once per payload) and what the receiver adds (``usable``).

    Refused: multicast (224/4), unspecified and broadcast; loopback (127/8) unless the
    datagram itself came over loopback (co-hosted daemons: tests, a ground station running
    several participants); and the receiver's own address unless the datagram came from it
    (co-hosted participants): a captured member announcing the receiver's own address would
    make the receiver send that member's traffic to itself, into any UDP service on it.
    Other locator kinds (shared memory, TCP) are never used for sending, so they pass."""

    octets: frozenset[bytes]  # every UDPv4 unicast locator's address
    refused: bool  # one is multicast, unspecified or broadcast
    loopback: bool  # one is in 127/8

    def usable(self, source_host: str, own_octets: bytes, own_dotted: str) -> bool:
        """For a receiver whose address is ``own_octets`` (b"" if unknown), dotted
        ``own_dotted``, of a datagram from ``source_host``."""
        if self.refused or (self.loopback and not source_host.startswith("127.")):
            return False
        return not (own_octets in self.octets and source_host != own_dotted)


def locator_facts(part: SpdpParticipant) -> LocatorFacts:
    octets: set[bytes] = set()
    refused = loopback = False
    for loc in (*part.metatraffic_unicast_locators, *part.default_unicast_locators):
        if loc.kind != LOCATOR_KIND_UDPv4:
            continue
        addr = loc.address[12:]
        octets.add(addr)
        first = addr[0]
        if 224 <= first <= 239 or addr in (b"\x00\x00\x00\x00", b"\xff\xff\xff\xff"):
            refused = True
        elif first == 127:
            loopback = True
    return LocatorFacts(frozenset(octets), refused, loopback)


# (the RTPS header's GUID prefix octets, its DATA(p)s and DATA(p[UD])s)
Decoded = tuple[bytes, tuple[Alive | SpdpDisposed, ...]]

# Decoded datagrams kept for reuse, oldest evicted first. Decoding is pure and nothing
# decoded is ever mutated, so engines may share it: a simulator running N engines in one
# process hands the same multicast (the same bytes object) to N - 1 of them back to back.
# A daemon sees each datagram once; the memo then costs one dict lookup.
DECODE_MEMO_ENTRIES: Final = 256
# ... and in octets (session 16, h-insider16): a decode holds up to ~27 times its datagram's
# octets (a stock-vendor DATA(p) of empty parameters keeps each as an object: 64 KiB held
# ~1.8 MB), and entries alone let a forger's one decode a second fill 256 of them, 452 MB
# of a Jetson Nano's 4 GB (``bench/decode_memo_memory.py``, tracemalloc). A datagram
# over DECODE_MEMO_MAX_DATAGRAM is not kept (swarmd's and stock DATA(p)s are 300-700
# octets; nothing re-reads a large one), and the kept ones total at most
# DECODE_MEMO_OCTETS (256 of a simulator's ~400-octet multicasts fit).
DECODE_MEMO_MAX_DATAGRAM: Final = 4096
DECODE_MEMO_OCTETS: Final = 128 * 1024
_memo: dict[bytes, Decoded] = {}
_memo_octets = 0  # the kept datagrams' octets


def clear_memo() -> None:
    """Forget every memoised decode (benchmarks and tests: each datagram new to the decoder)."""
    global _memo_octets
    _memo.clear()
    _memo_octets = 0


def decode(data: bytes) -> Decoded:
    """``decode_fresh``, memoised. Errors are not cached: garbage costs a full decode each
    time, as it should."""
    global _memo_octets
    hit = _memo.get(data)
    if hit is None:
        hit = decode_fresh(data)
        size = len(data)
        if size <= DECODE_MEMO_MAX_DATAGRAM:
            while _memo and (
                len(_memo) >= DECODE_MEMO_ENTRIES or _memo_octets + size > DECODE_MEMO_OCTETS
            ):
                oldest = next(iter(_memo))
                _memo_octets -= len(oldest)
                del _memo[oldest]
            _memo[data] = hit
            _memo_octets += size
    return hit


def decode_fresh(data: bytes) -> Decoded:
    """``decode_spdp`` plus the per-datagram facts of each DATA(p)."""
    header, samples = decode_spdp(data)
    out: list[Alive | SpdpDisposed] = []
    for sample in samples:
        if isinstance(sample, SpdpAlive):
            part = sample.participant
            destination = sample.destination
            meta = interned(part.metatraffic_unicast_locators)
            default = interned(part.default_unicast_locators)
            out.append(
                Alive(
                    sample,
                    part.guid_prefix.value,
                    part.is_swarmd,
                    unicast_target(part.metatraffic_unicast_locators),
                    clamp_lease(part.lease_duration.total_seconds()),
                    sample.sequence_number,
                    None if destination is None else destination.value,
                    part.domain_id,
                    part.domain_tag in (None, ""),
                    part.bundle_digest,
                    part.heard,
                    part.link_quality_permille,
                    part.vouched,
                    meta,
                    default,
                    locator_facts(part),
                    part.ros2_alive,
                )
            )
        else:
            out.append(sample)
    return header.guid_prefix.value, tuple(out)


# Locator lists seen lately, so that a peer's unchanged lists are the same tuple object from
# one of its datagrams to the next and the receive path's "did it move?" test is an identity
# check in C (equal Locators compare through their dataclass __eq__, in Python). Bounded: a
# flood of invented locators only clears it. A list longer than MAX_INTERNED_LIST_LOCATORS is
# not kept (a swarmd peer announces one locator a list, a stock node one an interface): 500
# forged DATA(p)s of two distinct 1,100-locator lists held 199 MB with the memo's entries
# (``bench/decode_memo_memory.py``; such a list is compared by value instead).
MAX_INTERNED_LOCATOR_LISTS: Final = 1024
MAX_INTERNED_LIST_LOCATORS: Final = 4
_locator_lists: dict[tuple[Locator, ...], tuple[Locator, ...]] = {}


def interned(locators: tuple[Locator, ...]) -> tuple[Locator, ...]:
    if len(locators) > MAX_INTERNED_LIST_LOCATORS:
        return locators
    found = _locator_lists.get(locators)
    if found is None:
        if len(_locator_lists) >= MAX_INTERNED_LOCATOR_LISTS:
            _locator_lists.clear()
        found = _locator_lists[locators] = locators
    return found


# Bundle index by GUID prefix octets, one table per bundle participant list (keyed by it),
# shared by every engine of that bundle; read-only. A process holds one bundle (a daemon)
# or a few (tests), so the bound only guards against a caller building endless bundles.
MAX_INDEX_MAPS: Final = 16
_index_maps: dict[tuple[tuple[bytes, int], ...], dict[bytes, int]] = {}


# The last participant tuple seen and its table: the same (immutable) tuple object needs no
# key built from its N prefixes (a simulator builds N engines of one bundle in a row). The
# reference held here keeps the tuple alive, so its identity cannot be reused.
_last_index_map: tuple[tuple[Participant, ...], dict[bytes, int]] | None = None


def index_map(bundle: Bundle) -> Mapping[bytes, int]:
    global _last_index_map  # a one-entry cache in front of _index_maps
    participants = bundle.participants
    last = _last_index_map
    if last is not None and last[0] is participants:
        return last[1]
    key = tuple((p.guid_prefix.value, p.index) for p in participants)
    found = _index_maps.get(key)
    if found is None:
        if len(_index_maps) >= MAX_INDEX_MAPS:
            _index_maps.clear()
        found = _index_maps[key] = dict(key)
    _last_index_map = (participants, found)
    return found


# Each participant's pinned address (the mission's ``ipv4``), by bundle index, as the one
# octet set its unicast locators must stay within; None where the bundle pins none (DHCP).
# One read-only table per bundle participant list, shared like ``index_map`` (same bound).
_pin_tables: dict[tuple[tuple[int, str | None], ...], tuple[frozenset[bytes] | None, ...]] = {}
_last_pin_table: tuple[tuple[Participant, ...], tuple[frozenset[bytes] | None, ...]] | None = None


def pin_table(bundle: Bundle) -> tuple[frozenset[bytes] | None, ...]:
    """By bundle index: the address a DATA(p) of that participant may name in its unicast
    locators (any port), if the bundle pins one (``ReceivePath._on_alive``)."""
    global _last_pin_table  # a one-entry cache in front of _pin_tables
    participants = bundle.participants
    last = _last_pin_table
    if last is not None and last[0] is participants:
        return last[1]
    key = tuple((p.index, p.ipv4) for p in participants)
    found = _pin_tables.get(key)
    if found is None:
        size = max((p.index for p in participants), default=-1) + 1
        table: list[frozenset[bytes] | None] = [None] * size
        for index, ipv4 in key:
            if ipv4 is not None:
                table[index] = frozenset((ipv4_octets(ipv4),))
        if len(_pin_tables) >= MAX_INDEX_MAPS:
            _pin_tables.clear()
        found = _pin_tables[key] = tuple(table)
    _last_pin_table = (participants, found)
    return found


def unicast_target(locators: tuple[Locator, ...]) -> tuple[str, int] | None:
    """The first usable UDPv4 unicast locator (DDSI-RTPS 8.5.3.1 metatrafficUnicastLocatorList)."""
    for loc in locators:
        if loc.kind != LOCATOR_KIND_UDPv4 or not 0 < loc.port <= 0xFFFF:
            continue
        octets = loc.address[12:]
        # 224.0.0.0/4 is multicast (RFC 5771); 0.0.0.0 and the broadcast address name no peer.
        # Plain bytes tests: this runs per datagram, and ipaddress objects cost ~10 us here
        if 224 <= octets[0] <= 239 or octets in (b"\x00\x00\x00\x00", b"\xff\xff\xff\xff"):
            continue
        return ".".join(map(str, octets)), loc.port
    return None


def ipv4_octets(host: str) -> bytes:
    """Four octets of a dotted IPv4 address; empty (matches nothing) if it is not one."""
    parts = host.split(".")
    if len(parts) != 4 or not all(p.isdigit() and int(p) < 256 for p in parts):
        return b""
    return bytes(int(p) for p in parts)
