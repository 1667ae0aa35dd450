"""Datagrams that arrive before their sender's discovery: held briefly, verified later.

Discovery is asymmetric. After the commander's blackout (issue 20) every member hears the
commander's multicast first and re-discovers it at once, while the commander re-discovers
each member only when that member's answer arrives, a rejoin delay U(0, N / 50 s) later
(docs/discovery.md). A member pulls its readiness report in at its re-discovery
(docs/dataplane.md), so that report reaches a commander whose data plane still has the
member down, and the rule that only peers discovery reported up move anything dropped it
(``peer_not_up``): in the six blackout runs on the ns-3 channel one report per member
that found the commander first, 74 of 75 such (member, return) pairs, most of the readiness
the blackout lost (docs/flight-history.md, "Where the blackout's missing readiness goes").

``EarlyDatagrams`` keeps the last few such datagrams of a bundle participant for
``EARLY_HOLD_S`` and hands them back when discovery reports it up; the plane then runs
every check on them as on any datagram (verify, then change state: style rule 16), so a
held datagram moves nothing until its authenticator checks again at release.

Who may take a slot (session 10 network review, docs/security-history.md "Network paths end
to end"): the plane holds a datagram only once its tag verified for this life of ours and
its freshness is not one the sender's replay window already has (``PairChannels.may_hold``),
so an outsider's forgery, or a captured member's under another member's prefix, is
refused on arrival and never displaces a genuine held datagram. What is left is a
replayer holding genuine datagrams of the sender's current life that we never took; past
the cap the hold therefore drops the *stalest freshness* (epoch, sequence), not the
oldest arrival, so an older capture never pushes out a newer report, and an exact copy of
a held datagram is not held twice. Pure, keyed by ``now``; no clock.
"""

from __future__ import annotations

from collections import deque
from typing import Final

from swarmd.auth.freshness import Freshness
from swarmd.rtps.types import GuidPrefix

# (arrival ``now``, the datagram, its source, its trailer's freshness)
Held = tuple[float, bytes, tuple[str, int], Freshness]

# One readiness period (1 Hz, the paper's workload): the commander's re-discovery of a
# member follows the member's within the rejoin delay, U(0, N / 50 s) = 0.4 s at N = 20
# (0.004-0.40 s measured on the channel); after a period the member's next report is on its
# way and a held one is stale. Held longer, a report would also date commands worse: it is
# taken at release, so its echo's age is short by the time held (which only makes a member's
# deadline earlier, docs/dataplane.md, "Validity").
EARLY_HOLD_S: Final = 1.0
# Per participant: what one peer_up can release. A re-discovery queues at most a readiness
# report and a reliable writer's hand-over (DATA + HEARTBEAT, one datagram or two). Only
# datagrams whose tag verified take a slot, and past the cap the stalest freshness leaves:
# a forger cannot cycle these slots, a replayer of older captures cannot either.
MAX_EARLY_PER_PEER: Final = 4


class EarlyDatagrams:
    """Held datagrams per sender prefix: at most ``per_peer`` each, for ``hold_s``.

    The caller holds only datagrams whose prefix is a bundle participant's (so the table
    has at most one queue per participant), of at most its datagram bound and whose tag
    verified, and counts what ``hold`` and ``release`` say was dropped."""

    def __init__(self, hold_s: float = EARLY_HOLD_S, per_peer: int = MAX_EARLY_PER_PEER) -> None:
        self.hold_s = hold_s
        self.per_peer = per_peer
        self._held: dict[GuidPrefix, deque[Held]] = {}

    def __len__(self) -> int:
        return sum(len(q) for q in self._held.values())

    def hold(
        self,
        prefix: GuidPrefix,
        data: bytes,
        source: tuple[str, int],
        freshness: Freshness,
        now: float,
    ) -> list[tuple[bytes, tuple[str, int]]]:
        """Keep ``data`` (whose trailer says ``freshness``) from ``prefix``; returns what
        left the queue unreleased: expired, the stalest freshness past the cap (``data``
        itself when it is the stalest), or ``data`` when the very datagram is held."""
        queue = self._held.setdefault(prefix, deque())
        gone = self._expire(queue, now)
        if any(held[1] == data for held in queue):
            gone.append((data, source))  # a copy adds nothing: it would only take a slot
            return gone
        queue.append((now, data, source, freshness))
        if len(queue) > self.per_peer:
            stalest = min(queue, key=lambda held: (held[3].epoch, held[3].seq))
            queue.remove(stalest)
            gone.append((stalest[1], stalest[2]))
        return gone

    def release(
        self, prefix: GuidPrefix, now: float
    ) -> tuple[list[tuple[bytes, tuple[str, int]]], list[tuple[bytes, tuple[str, int]]]]:
        """Everything held from ``prefix``: (still fresh, in freshness order, the order
        the sender made them; expired)."""
        queue = self._held.pop(prefix, None)
        if queue is None:
            return [], []
        gone = self._expire(queue, now)
        ordered = sorted(queue, key=lambda held: (held[3].epoch, held[3].seq))
        return [(data, source) for _, data, source, _ in ordered], gone

    def _expire(self, queue: deque[Held], now: float) -> list[tuple[bytes, tuple[str, int]]]:
        # Arrival order is kept in the deque (eviction by freshness removes from the middle),
        # so the expired ones are still at its left.
        gone: list[tuple[bytes, tuple[str, int]]] = []
        while queue and now - queue[0][0] > self.hold_s:
            _, data, source, _ = queue.popleft()
            gone.append((data, source))
        return gone
