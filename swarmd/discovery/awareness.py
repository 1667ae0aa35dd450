"""Network awareness (paper section 4.1): from link quality Q to discovery timing.

Q itself comes from the link monitor (``swarmd.link.quality``: eq. 1 ``Q = LQ / LQmax``,
eq. 2 the SNR normalised over 25-40 dB). Here Q becomes

* the passive window, the upper bound of the passive timer (eq. 3; ``passive_window_s``),
* the lease-renewal period during flight (continuous awareness; ``renewal_period_s``).

Pure functions: no clock, randomness only through the ``random.Random`` passed in.
"""

from __future__ import annotations

import math
import random
from typing import Final

from swarmd.discovery.config import Mode


def normalise_q(q: float) -> float:
    """Q clamped to [0, 1]; NaN (a broken reading) counts as the worst link."""
    if math.isnan(q):
        return 0.0
    return min(1.0, max(0.0, q))


def passive_window_s(
    mode: Mode,
    q: float,
    *,
    swarm_size: int,
    t_min_s: float,
    t_max_s: float,
    announce_budget_fps: float,
    q_floor: float,
) -> float:
    """The upper bound W of the passive timer T_passive ~ U(0, W).

    paper (eq. 3):  W = Tmin + (Tmax - Tmin) * (1 - Q)
    adaptive:       W = min(eq. 3, N / (budget * max(Q, q_floor)))

    The adaptive bound spreads the swarm's N first announcements at no more than
    ``budget * Q`` frames per second, so the channel load at start is the same for any N
    and a 10-drone swarm does not sit 8-20 s in silence waiting for nothing. It never
    exceeds the paper's window: adaptive only ever shortens the wait.
    """
    q = normalise_q(q)
    paper = t_min_s + (t_max_s - t_min_s) * (1.0 - q)
    if mode == "paper":
        return paper
    return min(paper, max(1, swarm_size) / (announce_budget_fps * max(q, q_floor)))


def draw_passive_timer_s(rng: random.Random, window_s: float) -> float:
    """Paper eq. 3: T_passive(i) ~ U(0, W)."""
    return rng.uniform(0.0, window_s)


def renewal_period_s(
    q: float,
    *,
    lease_s: float,
    per_lease_min: float,
    per_lease_max: float,
    swarm_size: int = 1,
    renewal_budget_fps: float | None = None,
) -> float:
    """Seconds between lease renewals: lease / n(Q), n = min + (max - min) * (1 - Q).

    On a clean link two renewals per lease suffice (one may be lost); as Q drops the
    renewals get denser, so a peer misses all of them within one lease with probability
    about p_loss ** n. This is the paper's "continuous awareness" (section 4.1, Network
    Monitor feeding RTPS) applied after start-up, not only to the first announcement.

    With ``renewal_budget_fps`` (adaptive mode) the period is at least N / budget: N
    drones renewing every P seconds put N / P frames per second on the shared channel, so
    a large swarm renews less often rather than loading the channel with its own
    renewals (``advertised_lease_s`` then stretches the lease to keep n(Q) per lease).
    """
    q = normalise_q(q)
    period = lease_s / renewals_per_lease(
        q, per_lease_min=per_lease_min, per_lease_max=per_lease_max
    )
    if renewal_budget_fps is not None:
        period = max(period, max(1, swarm_size) / renewal_budget_fps)
    return period


def renewals_per_lease(q: float, *, per_lease_min: float, per_lease_max: float) -> float:
    """n(Q) = min + (max - min) * (1 - Q): how many renewals a peer gets per lease."""
    return per_lease_min + (per_lease_max - per_lease_min) * (1.0 - normalise_q(q))


def advertised_lease_s(
    q: float, *, lease_s: float, renewal_period_s: float, per_lease_min: float, per_lease_max: float
) -> float:
    """The lease we announce: the bundle's, or longer when the renewal budget stretched the
    period, so that a peer still gets n(Q) renewals per lease and losing a few of them in a
    row is as unlikely as at small N. A peer is never declared lost for our silence while
    we are alive on a clean channel: the lease always spans n(Q) >= 2 renewal periods."""
    n = renewals_per_lease(q, per_lease_min=per_lease_min, per_lease_max=per_lease_max)
    return max(lease_s, n * renewal_period_s)


# What a vouch's receiver adds to the commander's window for the frame's own way there (MAC
# queue and retries: milliseconds on an idle channel, well under this).
VOUCH_TRANSIT_S: Final = 0.5


def vouched_lease_s(peer_lease_s: float, window_s: float) -> float:
    """How long a vouch keeps a member alive from the moment it is received.

    The commander heard the member at most ``window_s`` before it sent the vouch, and the
    vouch took at most ``VOUCH_TRANSIT_S`` to arrive, so the member's last frame was no more
    than ``window_s + VOUCH_TRANSIT_S`` ago: a lease counted from there never ends later than
    one counted from that last frame. A dead member is lost no later than it is today,
    ``lease`` after its last frame (docs/discovery.md, "Vouching"). <= 0: no extension.
    """
    return peer_lease_s - window_s - VOUCH_TRANSIT_S


def vouch_period_s(
    q: float, *, lease_s: float, window_s: float, per_lease_min: float, per_lease_max: float
) -> float:
    """The commander's renewal period while it vouches: n(Q) + 1 vouches per vouched lease.

    A member's lease at another member now rests on the commander's vouches alone, each
    worth ``vouched_lease_s``; one more vouch per lease than the n(Q) renewals a peer's own
    lease gets, so a receiver must miss n(Q) + 1 vouches in a row (p_loss ** (n + 1)) before
    a live member lapses. One node sends them, so the swarm pays ~1 frame per period.
    """
    n = renewals_per_lease(q, per_lease_min=per_lease_min, per_lease_max=per_lease_max)
    return max(0.5, vouched_lease_s(lease_s, window_s) / (n + 1.0))
