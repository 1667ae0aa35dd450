"""Typed, read-only answers to "what does discovery know": the engine's query results.

``DiscoveryEngine.peer(...)`` and ``peers()`` return ``PeerView``; ``foreign(now)`` returns
``ForeignView``. They are snapshots (frozen, detached from the engine's tables), so a driver
may keep them; ``DiscoveryEngine.status(now)`` is the JSON form of the same facts, evaluated
only when someone asks (a control-socket request), never per datagram.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.bundle.model import Match
from swarmd.discovery.events import DropReason
from swarmd.discovery.peers import PeerState
from swarmd.rtps.locator import Locator
from swarmd.rtps.types import GuidPrefix


@dataclass(frozen=True, slots=True)
class PeerView:
    """One bundle peer as the engine sees it at the time of the query.

    ``locator`` is where a directed frame to it goes: the first usable UDPv4 unicast locator
    of its latest DATA(p) (``received.unicast_target``), else the UDP source it came from,
    else its bundle address; None only for a peer never heard and without a bundle address.
    ``metatraffic_unicast_locators`` and ``default_unicast_locators`` are its latest
    DATA(p)'s lists as sent (empty before it is heard). Times are on the engine's clock.
    """

    name: str
    index: int
    guid_prefix: GuidPrefix
    state: PeerState
    last_heard: float | None
    locator: tuple[str, int] | None
    metatraffic_unicast_locators: tuple[Locator, ...]
    default_unicast_locators: tuple[Locator, ...]
    matches: tuple[Match, ...]  # empty unless discovered
    lists_me: bool  # discovered, and its latest DATA(p) lists us in its heard digest
    lease_s: float
    link_quality_permille: int | None
    times_discovered: int
    epoch: int | None = None  # its boot epoch from its latest authenticated DATA(p)

    @property
    def discovered(self) -> bool:
        return self.state == PeerState.DISCOVERED


@dataclass(frozen=True, slots=True)
class ForeignView:
    """A participant heard but never matched (capped table, ``peers.MAX_FOREIGN``)."""

    guid_prefix: GuidPrefix
    vendor: str
    name: str | None  # as the participant sent it: data, escape before printing
    reason: DropReason
    first_seen: float
    last_seen: float
    frames: int
