"""What the engine knows about each bundle peer and about foreign participants.

Bundle peers live in a table sized by the bundle itself (a stranger cannot add rows);
foreign participants, which anyone on the channel can invent, sit in a capped LRU table.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

from swarmd.bundle.model import Match, Participant
from swarmd.discovery.events import DropReason
from swarmd.discovery.timers import MinInterval, RetrySchedule
from swarmd.rtps.locator import Locator
from swarmd.rtps.types import GuidPrefix

# A stranger spraying DATA(p) under random GUID prefixes (each one "a new participant")
# must not grow memory or the status output without bound: keep the most recent 64.
MAX_FOREIGN: Final = 64
# A peer advertising an infinite (or absurd) lease would pin its entry and matches long
# after it vanished; 5 minutes is 15x the paper's lease.
MAX_PEER_LEASE_S: Final = 300.0
# A lease near zero would make a peer flap between discovered and lost on every frame.
MIN_PEER_LEASE_S: Final = 1.0


class PeerState(StrEnum):
    UNDISCOVERED = "undiscovered"
    DISCOVERED = "discovered"
    LOST = "lost"


def clamp_lease(seconds: float) -> float:
    return min(MAX_PEER_LEASE_S, max(MIN_PEER_LEASE_S, seconds))


@dataclass(slots=True)
class Peer:
    """One bundle participant as this engine sees it.

    ``lists_me``: its latest DATA(p) has our bit in its heard digest (it knows us).
    ``told``: we sent a frame listing it since we (re)discovered it (it can know we know it).
    A frame is owed while the peer is discovered and either flag is false.
    """

    participant: Participant
    index: int  # participant.index, read on every DATA(p) (a plain field, not a property)
    bundle_locator: tuple[str, int] | None  # bundle ipv4 + metatraffic port, if known
    retry: RetrySchedule
    reack: MinInterval
    state: PeerState = PeerState.UNDISCOVERED
    locator: tuple[str, int] | None = None  # from its DATA(p), else the UDP source
    # its latest DATA(p)'s locator lists, as sent (PeerView, PeerDiscovered)
    metatraffic_locators: tuple[Locator, ...] = ()
    default_locators: tuple[Locator, ...] = ()
    last_heard: float | None = None
    lease_s: float = 0.0
    lists_me: bool = False
    told: bool = False
    told_at: float | None = None
    last_sn: int | None = None
    last_rx: float | None = None
    link_quality_permille: int | None = None
    times_discovered: int = 0
    # its boot epoch: the life whose restart we honoured last (receive.RESTART_MIN_INTERVAL_S:
    # a faster rise is fresh but waits), from its authenticated DATA(p)
    epoch: int | None = None
    # (when we last honoured its restart, when its own dispose lost it, its relay's alive
    # ROS 2 participants: rare, so in ReceivePath's side tables, not here)
    # matched endpoints, computed when first discovered: a bundle row per peer would cost
    # every engine O(N) ``Bundle.matches`` calls at start-up, mostly for nobody (sim at N=1000)
    matches: tuple[Match, ...] | None = None
    # its lease, kept by the engine's timers.LeaseQueue (timers.Leased)
    lease_until: float | None = None
    lease_queued: float | None = None

    @property
    def discovered(self) -> bool:
        return self.state == PeerState.DISCOVERED

    def target(self) -> tuple[str, int] | None:
        """Where a directed frame to this peer goes."""
        return self.locator if self.locator is not None else self.bundle_locator


@dataclass(slots=True)
class ForeignEntry:
    guid_prefix: GuidPrefix
    vendor: str
    name: str | None
    reason: DropReason
    first_seen: float
    last_seen: float
    lease_s: float
    frames: int = 1

    def alive(self, now: float) -> bool:
        return now <= self.last_seen + self.lease_s


@dataclass(slots=True)
class ForeignTable:
    """Participants seen but never matched, least recently heard evicted first."""

    cap: int = MAX_FOREIGN
    entries: OrderedDict[GuidPrefix, ForeignEntry] = field(default_factory=OrderedDict)
    evicted: int = 0

    def see(
        self,
        prefix: GuidPrefix,
        *,
        vendor: str,
        name: str | None,
        reason: DropReason,
        lease_s: float,
        now: float,
    ) -> bool:
        """Record a sighting; True when the prefix is new to the table."""
        entry = self.entries.get(prefix)
        if entry is not None:
            entry.last_seen, entry.lease_s, entry.name = now, lease_s, name
            entry.reason, entry.vendor = reason, vendor
            entry.frames += 1
            self.entries.move_to_end(prefix)
            return False
        self.prune(now)  # the silent go first (status() only reads the table)
        while len(self.entries) >= self.cap:
            self.entries.popitem(last=False)
            self.evicted += 1
        self.entries[prefix] = ForeignEntry(prefix, vendor, name, reason, now, now, lease_s)
        return True

    def remove(self, prefix: GuidPrefix) -> bool:
        return self.entries.pop(prefix, None) is not None

    def prune(self, now: float) -> None:
        """Forget participants silent past their (clamped) lease."""
        stale = [p for p, e in self.entries.items() if not e.alive(now)]
        for p in stale:
            del self.entries[p]

    def alive(self, now: float) -> list[ForeignEntry]:
        """The entries not silent past their lease, least recently heard first (no change)."""
        return [e for e in self.entries.values() if e.alive(now)]
