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
held datagram moves nothing until its authenticator checks. Nothing here is trusted: a
forgery held is a forgery refused at release (``auth_failed``), a capture held is refused
by the replay window (``auth_replayed``). What a forger gains is displacing a genuine held
datagram, which jamming the channel gains too. Pure, keyed by ``now``; no clock.
"""

from __future__ import annotations

from collections import deque
from typing import Final

from swarmd.rtps.types import GuidPrefix

# One readiness period (1 Hz, the paper's workload): the commander's re-discovery of a
# member follows the member's within the rejoin delay, U(0, N / 50 s) = 0.4 s at N = 20
# (0.004-0.40 s measured on the channel); after a period the member's next report is on its
# way and a held one is stale. Held longer, a report would also date commands worse: it is
# taken at release, so its echo's age is short by the time held (which only makes a member's
# deadline earlier, docs/dataplane.md, "Validity").
EARLY_HOLD_S: Final = 1.0
# Per participant: what one peer_up can release. A re-discovery queues at most a readiness
# report and a reliable writer's hand-over (DATA + HEARTBEAT, one datagram or two); a forger
# flooding one participant's prefix only cycles these slots.
MAX_EARLY_PER_PEER: Final = 4


class EarlyDatagrams:
    """Held datagrams per sender prefix: at most ``per_peer`` each, for ``hold_s``.

    The caller holds only datagrams whose prefix is a bundle participant's (so the table
    has at most one queue per participant) and of at most its datagram bound, and counts
    what ``hold`` and ``release`` say was dropped."""

    def __init__(self, hold_s: float = EARLY_HOLD_S, per_peer: int = MAX_EARLY_PER_PEER) -> None:
        self.hold_s = hold_s
        self.per_peer = per_peer
        self._held: dict[GuidPrefix, deque[tuple[float, bytes, tuple[str, int]]]] = {}

    def __len__(self) -> int:
        return sum(len(q) for q in self._held.values())

    def hold(
        self, prefix: GuidPrefix, data: bytes, source: tuple[str, int], now: float
    ) -> list[tuple[bytes, tuple[str, int]]]:
        """Keep ``data`` from ``prefix``; returns what left the queue unreleased (expired,
        or the oldest past the cap)."""
        queue = self._held.setdefault(prefix, deque())
        gone = self._expire(queue, now)
        queue.append((now, data, source))
        while len(queue) > self.per_peer:
            _, old, src = queue.popleft()
            gone.append((old, src))
        return gone

    def release(
        self, prefix: GuidPrefix, now: float
    ) -> tuple[list[tuple[bytes, tuple[str, int]]], list[tuple[bytes, tuple[str, int]]]]:
        """Everything held from ``prefix``, oldest first: (still fresh, expired)."""
        queue = self._held.pop(prefix, None)
        if queue is None:
            return [], []
        gone = self._expire(queue, now)
        return [(data, source) for _, data, source in queue], gone

    def _expire(
        self, queue: deque[tuple[float, bytes, tuple[str, int]]], now: float
    ) -> list[tuple[bytes, tuple[str, int]]]:
        gone: list[tuple[bytes, tuple[str, int]]] = []
        while queue and now - queue[0][0] > self.hold_s:
            _, data, source = queue.popleft()
            gone.append((data, source))
        return gone
