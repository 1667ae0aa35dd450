"""Who is alive here: the peers' leases, the heard digest, and the commander's vouches.

A discovered peer's lease restarts on every DATA(p) it sends (and, in adaptive mode, on its
verified user data: ``DiscoveryEngine.peer_traffic``); when it runs out the peer is lost
(DDSI-RTPS 8.5.3.2 leaseDuration). The leases sit in ``timers.LeaseQueue``, O(1) per renewal:
the receive path renews a lease ~3M times in a simulated 1000-drone minute.

Vouching (adaptive mode, one commander in the bundle; docs/discovery.md, "Vouching"): the
commander's renewals carry the members it heard directly in the last ``vouch_window_s``; only
the commander's (signed) vouch is believed. A vouch is kept, not applied: it is consulted
only when a peer reaches its probe point (``expire``), when the newest vouch listing the peer
may hold it a while longer (``vouched_lease_s``).

Probing (docs/discovery.md, "Probing before a lease ends"): the queue is keyed at each peer's
probe point (``PROBE_AT`` of its lease); a peer past it waits in the hold heap, and is probed in
the last quarter of its lease or vouch, then lost when both ran out.

The heard digest we send (bit i: we hear bundle index i) and the count of peers whose
latest DATA(p) lists us are kept here too, incrementally, on discovery and loss.
"""

from __future__ import annotations

import heapq
from collections import deque
from typing import Final

from swarmd.bundle.model import Bundle, Role
from swarmd.discovery.awareness import vouched_lease_s
from swarmd.discovery.config import EngineConfig, Timing
from swarmd.discovery.digest import HeardBitmap
from swarmd.discovery.peers import MAX_PEER_LEASE_S, Peer, PeerState
from swarmd.discovery.renewals import MAX_RATE_SAMPLES, RATE_WINDOW_S
from swarmd.discovery.timers import LeaseQueue, WindowRate
from swarmd.rtps.spdp import Vouch

# The last-chance probe (docs/discovery.md, "Probing before a lease ends"): a discovered peer
# not heard for PROBE_AT of its lease (and held by no vouch) is sent a directed DATA(p) whose
# heard digest omits it, so it answers at once; up to PROBE_ATTEMPTS of them, spread evenly
# over the lease's last quarter. Renewals come at least twice per lease (n(Q) >= 2,
# awareness.py), so a peer we hear normally never reaches its probe point. Adaptive mode
# only: paper mode keeps the paper's liveliness (a lease ends unrenewed, nothing asked).
PROBE_AT: Final = 0.75
PROBE_ATTEMPTS: Final = 4

# The commander's vouches kept (one every few seconds; older than any lease are dropped):
# bounds what a commander flooding frames can make a member hold.
MAX_VOUCHES: Final = 64

_DISCOVERED: Final = PeerState.DISCOVERED


class Leases:
    """The lease queue, the vouches that may outlast a lease, the heard digest."""

    __slots__ = (
        "_my_index",
        "_own_end",
        "_probes_sent",
        "probe_at",
        "_peers",
        "_size",
        "_vouch_window_ms",
        "_vouch_window_s",
        "commander",
        "heard",
        "listed_by",
        "queue",
        "hold_heap",
        "held_until",
        "vouches",
        "vouches_received",
        "vouches_sent",
        "vouching",
    )

    def __init__(
        self,
        bundle: Bundle,
        my_index: int,
        peers: dict[int, Peer],
        *,
        config: EngineConfig,
        timing: Timing,
        size: int,
        now: float,
    ) -> None:
        self._my_index = my_index
        self._peers = peers  # the engine's table, by bundle index
        self._size = size
        # keyed at each peer's probe point (last heard + probe_at * lease), not its end
        self.queue = LeaseQueue()
        self.probe_at = PROBE_AT if config.mode == "adaptive" else 1.0
        # the heard digest we send, kept up to date on discovery and loss rather than
        # rebuilt from all N peers on every send
        self.heard = HeardBitmap(size)
        self.listed_by = 0  # discovered peers whose latest DATA(p) lists us
        commander_role = Role.COMMANDER
        commanders = [p.index for p in bundle.participants if p.role == commander_role]
        # A vouch must be worth most of a lease, or vouched members (who stop renewing)
        # would lapse between vouches: with a 3 s lease and a 2.5 s window a vouch holds a
        # member for no time at all. Short leases (tests, fast-failover missions) keep plain
        # renewals.
        worthwhile = vouched_lease_s(timing.lease_s, config.vouch_window_s) >= timing.lease_s / 2
        self.commander: int | None = (
            commanders[0]
            if config.mode == "adaptive" and config.vouch and len(commanders) == 1 and worthwhile
            else None
        )
        self.vouching = self.commander == my_index  # we are the commander: we vouch
        self._vouch_window_s = config.vouch_window_s
        self._vouch_window_ms = round(config.vouch_window_s * 1000)
        # the commander's recent vouches (arrival, bitmap as an int, window s), oldest first
        self.vouches: deque[tuple[float, int, float]] = deque()
        # the vouch rate (issue 20): frames we sent carrying one (the commander), and the
        # commander's vouches we took (a member)
        self.vouches_sent = WindowRate(RATE_WINDOW_S, MAX_RATE_SAMPLES, now)
        self.vouches_received = WindowRate(RATE_WINDOW_S, MAX_RATE_SAMPLES, now)
        # the peers past their probe point, to be looked at again (a probe, a vouch's end,
        # the lease's end): when, in a lazy heap (entries whose time no longer matches
        # ``held_until`` are stale; hearing the peer drops its entry), with their own lease's
        # end and the probes sent since they were last heard
        self.held_until: dict[int, float] = {}
        self.hold_heap: list[tuple[float, int]] = []
        self._own_end: dict[int, float] = {}
        self._probes_sent: dict[int, int] = {}

    def renew(self, peer: Peer, now: float) -> None:
        """``peer`` was heard (its own traffic) at ``now``: its own lease runs again."""
        self.queue.renew(peer, peer.lease_s * self.probe_at, now)
        if self.held_until:
            self.held_until.pop(peer.index, None)

    def apply_vouch(self, vouch: Vouch, now: float) -> bool:
        """The commander heard the members in ``vouch`` directly within its window: their
        leases here may run ``vouched_lease_s`` from ``now`` (never shortened, never past
        their last frame + lease). True if it vouched for us while every peer lists us:
        then our own renewal may wait a period (the caller restarts it).

        Lazily: the vouch is kept (arrival, bitmap as an int, window) and consulted only
        when a lease runs out (``expire``), so a vouch costs O(1) here instead of a lease
        update per vouched member (10^6 per vouch across a 1000-drone simulation). The
        newest vouch listing a peer gives its latest vouched deadline, which is what
        renewing every vouched lease at once would have left.

        Trusted only from the commander's prefix (signed, when authenticated), never passed
        on: a vouch moves leases only, never ``last_heard``, and the commander's bitmap is
        built from ``last_heard`` (its own direct hearing), so no vouch feeds another."""
        bits = int.from_bytes(vouch.bitmap, "little")  # bit i = index i (docs/wire.md)
        vouches = self.vouches
        vouches.append((now, bits, vouch.window_ms / 1000))
        while len(vouches) > MAX_VOUCHES or vouches[0][0] < now - MAX_PEER_LEASE_S:
            vouches.popleft()  # older than any lease: it can extend nothing
        # Only while every peer lists us: a peer that has not discovered us gets nothing
        # from a vouch, and our renewal multicast is what repairs its missed announcement.
        return bool(bits >> self._my_index & 1) and self.listed_by == len(self._peers)

    def expire(self, now: float, probes: list[Peer]) -> list[Peer]:
        """The peers whose lease (and any vouch holding them) ran out by ``now``, in bundle
        order; their leases are stopped, the caller loses them. The peers to probe now are
        appended to ``probes``."""
        expired: list[Peer] = []
        queue = self.queue
        while (earliest := queue.earliest()) is not None and now >= earliest[0]:
            peer = self._peers[earliest[1]]
            queue.remove(peer)
            # at its probe point: the lease itself runs the last quarter longer
            self._probes_sent[peer.index] = 0
            own_end = earliest[0] + (1.0 - self.probe_at) * peer.lease_s
            self._examine(peer, now, own_end, expired, probes)
        heap = self.hold_heap
        while heap and heap[0][0] <= now:
            at, index = heapq.heappop(heap)
            if self.held_until.get(index) == at:
                del self.held_until[index]
                peer = self._peers[index]
                self._examine(peer, now, self._own_end[index], expired, probes)
        return sorted(expired, key=lambda p: p.index)  # events in bundle order

    def _examine(
        self, peer: Peer, now: float, own_end: float, expired: list[Peer], probes: list[Peer]
    ) -> None:
        """``peer`` was not heard since its probe point: lost when its lease and any vouch
        holding it ran out; else probed in the last quarter of whichever ends later (a vouch
        well ahead of that: looked at again then)."""
        index = peer.index
        end = own_end
        if self.vouches:
            vouched = self._vouched_deadline(peer, now)
            if vouched is not None and vouched > end:
                end = vouched
        if end <= now:
            expired.append(peer)
            self._own_end.pop(index, None)
            self._probes_sent.pop(index, None)
            return
        last_quarter = (1.0 - self.probe_at) * peer.lease_s  # 0 in paper mode: no probe
        if now < end - last_quarter:
            self._hold(index, end - last_quarter, own_end)  # a vouch holds it: not yet
            return
        sent = self._probes_sent.get(index, 0)
        if sent < PROBE_ATTEMPTS:
            self._probes_sent[index] = sent + 1
            probes.append(peer)
        self._hold(index, min(now + last_quarter / PROBE_ATTEMPTS, end), own_end)

    def _hold(self, index: int, until: float, own_end: float) -> None:
        self.held_until[index] = until
        self._own_end[index] = own_end
        heapq.heappush(self.hold_heap, (until, index))

    def _vouched_deadline(self, peer: Peer, now: float) -> float | None:
        """When the newest vouch listing ``peer`` stops holding it, if after ``now``."""
        index = peer.index
        for received, bits, window_s in reversed(self.vouches):
            if bits >> index & 1:
                until = received + vouched_lease_s(peer.lease_s, window_s)
                return until if until > now else None
        return None

    def next_held(self) -> float | None:
        """The earliest vouched deadline; stale heap entries are dropped."""
        heap = self.hold_heap
        while heap:
            at, index = heap[0]
            if self.held_until.get(index) == at:
                return at
            heapq.heappop(heap)
        return None

    def forget(self, peer: Peer) -> None:
        """``peer`` is lost: no lease, no vouch, not heard, not listing us."""
        self.queue.remove(peer)
        self.held_until.pop(peer.index, None)
        self._own_end.pop(peer.index, None)
        self._probes_sent.pop(peer.index, None)
        self.heard.unmark(peer.index)
        if peer.lists_me:
            peer.lists_me = False
            self.listed_by -= 1

    def vouch(self, now: float) -> Vouch | None:
        """The commander's vouch: the discovered members heard directly (their DATA(p) or
        verified user data; never a vouch) within the window. O(N), once per frame sent."""
        if not self.vouching:
            return None
        since = now - self._vouch_window_s
        bitmap = HeardBitmap(self._size)
        for p in self._peers.values():
            if p.state is _DISCOVERED and p.last_heard is not None and p.last_heard >= since:
                bitmap.mark(p.index)
        return Vouch(self._vouch_window_ms, bitmap.to_bytes())
