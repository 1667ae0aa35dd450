"""A peer's lives, damped over time: route-flap damping (RFC 2439) for restarts and returns.

A *life* here is a peer's new start as the others see it: a restart we honour (its signed
boot epoch rose: ``PeerRestarted``) or a return we honour after its own signed dispose (a
``PeerLost`` then a ``PeerDiscovered``). Each costs every drone work: the data plane's pair
session reset, the ROS 2 relay's dispose and re-announcement of the peer's nodes to every
local node, log lines. ``receive.RESTART_MIN_INTERVAL_S`` spaces a peer's lives by 0.25 s,
faster than any daemon starts, but a captured member (its key signs any epoch and any
dispose) can keep that pace forever: 4 lives a second at every drone (docs/security.md, "A
captured member's lives").

So, as a BGP speaker damps a flapping route (RFC 2439, section 4.2), each peer carries a
penalty: +1 (``FLAP_PENALTY``) per life honoured, halved every ``FLAP_HALF_LIFE_S``. A life
is honoured only while the decayed penalty is at most ``FLAP_PENALTY_LIMIT`` (the RFC's
reuse threshold; one threshold, so the hold is the shortest that gives the same long-run
rate); above it the peer's next restart or return is held (counted, as the interval's holds
are) until the penalty has decayed back to the limit, and honoured by its first datagram
past that. A held datagram adds nothing: the peer's renewals go on while it waits, and an
honest peer's must not prolong its own hold. So the penalty never exceeds the limit + 1, and
the hold is capped at ``FLAP_HOLD_MAX_S`` = half-life * log2((limit + 1) / limit): the RFC's
maximum suppress time, here a consequence rather than a ceiling applied.

What that gives: the first 4 lives at any pace past the interval (penalties 0, 1, 2, 3
before them), then at most one per ``FLAP_HOLD_MAX_S`` (24.9 s) for as long as the churn
lasts. A captured member churning for a minute at its whole budget gets 6 restarts, or 7
losses and 6 finds, at each drone instead of 240, or 200 and 200 (``python -m
bench.lives_cost``). An honest peer: one restart, one stop and start, or a few an hour are
honoured at once, as before; a fly-out and back is no life (a lease loss, not the peer's own
dispose) and is never held; a crash loop (systemd's ``RestartSec=2s``) has its first life
and 4 restarts seen at once and the next ones late, by at most ``FLAP_HOLD_MAX_S``
(docs/security.md, "A captured member's lives").

Pure: time is the ``now`` argument, the state is three floats per bundle peer that had a
life (a stranger adds no row: only a bundle peer's verified DATA(p) or dispose reaches
``honoured``).
"""

from __future__ import annotations

import math
from typing import Final

# One life's penalty (RFC 2439's per-flap figure of merit, as a unit).
FLAP_PENALTY: Final = 1.0
# A life is honoured while the peer's decayed penalty is at most this: the first 4 are
# free. The first one it holds of an honest crash loop is its 5th restart, at least 11.4 s
# after its first life (5 x (RestartSec=2s + a 0.288 s start-up)).
FLAP_PENALTY_LIMIT: Final = 3.0
# The penalty halves every this many seconds (RFC 2439's half-life): with the limit, a
# churning peer gets one life per FLAP_HOLD_MAX_S once the free ones are spent.
FLAP_HALF_LIFE_S: Final = 60.0
# The longest a life is held: the penalty at its peak (limit + 1) decaying to the limit.
FLAP_HOLD_MAX_S: Final = FLAP_HALF_LIFE_S * math.log2(
    (FLAP_PENALTY_LIMIT + FLAP_PENALTY) / FLAP_PENALTY_LIMIT
)

_NEVER: Final = -math.inf


class LifeDamping:
    """Per bundle peer that ever had a life honoured (a row only then, at most the bundle's
    size; none in an honest swarm that never restarts, so a 1000-engine simulation carries
    no table of 1000 rows each): its penalty, when that was set, and until when its next
    life is held."""

    __slots__ = ("_rows",)

    def __init__(self) -> None:
        # bundle index -> (penalty, when set, held until): written only by ``honoured``
        self._rows: dict[int, tuple[float, float, float]] = {}

    def penalty(self, index: int, now: float) -> float:
        """The peer's penalty decayed to ``now`` (RFC 2439, section 4.1: exponential decay)."""
        row = self._rows.get(index)
        if row is None:
            return 0.0
        penalty, at, _ = row
        elapsed = max(0.0, now - at)  # a driver never goes back; be safe anyway
        return penalty * math.exp2(-elapsed / FLAP_HALF_LIFE_S)

    def reuse_at(self, index: int) -> float:
        """When the peer's next life may be honoured (-inf: at once)."""
        row = self._rows.get(index)
        return _NEVER if row is None else row[2]

    def held(self, index: int, now: float) -> bool:
        """True while the peer's next life must wait: its penalty is above the limit."""
        return now < self.reuse_at(index)

    def honoured(self, index: int, now: float) -> None:
        """The peer's life was honoured at ``now``: its penalty grows by one, and past the
        limit its next life waits until the penalty has decayed back to it."""
        penalty = self.penalty(index, now) + FLAP_PENALTY
        until = (
            now + FLAP_HALF_LIFE_S * math.log2(penalty / FLAP_PENALTY_LIMIT)
            if penalty > FLAP_PENALTY_LIMIT
            else _NEVER
        )
        self._rows[index] = (penalty, now, until)
