"""Pulling our next multicast in: after a rejoin, a lease's end, or a change to carry.

Why (docs/discovery.md, issue 20): after an outage both sides of a returning link would
otherwise wait out a renewal period (or a backed-off retry) before a frame crosses. One
DATA(p) listing whom we hear, pulled in to ``Debts.rejoin_delay`` (U(0, N / budget)), lets
every missing peer hear us and answer at once (DDSI-RTPS 8.5.3 SPDP; our heard digest omits
them). Never sooner than ``retransmit_min_gap_s`` after our last multicast, so a swarm's
rejoin frames spread at the announce budget: no storm.

Split out of ``engine.DiscoveryEngine`` (which keeps the phases and the sending) with its
state: whether the pending renewal was pulled in, the renewal's own deadline to resume after
a lease's end pulled an extra multicast in, and when a lease's end last did. Pure and keyed
by ``now`` (style rule 6): it moves the renewal timer's deadline; the engine sends.
"""

from __future__ import annotations

import random

from swarmd.discovery.config import EngineConfig
from swarmd.discovery.debts import Debts
from swarmd.discovery.leases import Leases
from swarmd.discovery.renewals import Renewals


class PullIn:
    """When our next multicast is pulled in ahead of the renewal (adaptive mode only: paper
    mode keeps the paper's schedule)."""

    __slots__ = (
        "_adaptive",
        "_debts",
        "_gap_s",
        "_leases",
        "_peer_count",
        "_renewals",
        "lease_end_sent",
        "pulled_in",
        "resume_renewal",
    )

    def __init__(
        self,
        config: EngineConfig,
        *,
        debts: Debts,
        leases: Leases,
        renewals: Renewals,
        peer_count: int,
    ) -> None:
        self._adaptive = config.mode == "adaptive"
        self._gap_s = config.retransmit_min_gap_s
        self._debts = debts
        self._leases = leases
        self._renewals = renewals
        self._peer_count = peer_count  # N - 1: the bundle peers
        self.pulled_in = False  # the pending renewal was pulled in to announce us (rejoin)
        # the renewal's own deadline while a lease's end pulled an extra multicast in
        # (lease_ended): the multicast does not move the renewal's phase
        self.resume_renewal: float | None = None
        self.lease_end_sent: float | None = None  # when a lease's end last pulled one in

    def rejoined(self, now: float, *, announcing: bool) -> bool:
        """A peer we had lost was heard again: its link is back, and so, likely, are those of
        the others still missing (a heal, the commander's return). Pull our next multicast in
        to ``Debts.rejoin_delay`` (U(0, N / budget), whatever our Q still says about the
        outage): one DATA(p) listing whom we hear lets every missing peer hear us and answer
        at once, instead of each side waiting out a renewal period or a backed-off retry.
        Adaptive mode only, as the probe (``leases.PROBE_AT``), and only while
        ``announcing`` (ANNOUNCE or STEADY).

        True if a multicast is due by then (pulled in, or a renewal already sooner): it
        answers the rejoined peer too. False: the caller answers that peer alone."""
        if not self._adaptive or not announcing:
            return False  # paper mode: the paper's schedule, nothing pulled in
        if self._leases.heard.count >= self._peer_count:
            return False  # nobody else is missing
        self.pull_in(now, self._debts.rejoin_delay())
        return True

    def lease_ended(self, now: float) -> None:
        """One or more leases just ended (the peers are lost): pull our next multicast in to
        ``Debts.rejoin_delay``, as a rejoin does. A lease that ends while the link is back
        (issue 20's fade: the fading drone in range of the group ~1.5-2.5 s of every 8 s,
        its last-chance probes all spent in the gap before) would otherwise be followed by
        silence on both sides (the group's members are vouched and do not renew) until a
        renewal happens to fall in a window. Our DATA(p) omits the lost peers from its heard
        digest, so each one that hears it finds itself no longer listed and answers within
        the rejoin delay (``receive.py``), which rediscovers it here. At most one such frame
        per renewal period (a split's leases end one after another), and an extra frame: the
        renewal keeps its deadline (``sent``), or a split's drones would all renew in
        lock-step from the loss on. A peer really gone costs each observer one multicast on
        top of its four probes. Adaptive mode only, in ANNOUNCE or STEADY (the caller checks)."""
        if not self._adaptive:
            return  # paper mode: the paper's schedule, nothing pulled in
        renewal = self._renewals.timer
        last = self.lease_end_sent
        if last is not None and now - last < renewal.period_s:
            return  # one such frame per renewal period: leases ending one after another
        self.lease_end_sent = now
        before = renewal.due
        self.pull_in(now, self._debts.rejoin_delay())
        if renewal.due != before:
            self.resume_renewal = before

    def answer_seek(self, now: float, delay: float) -> float:
        """A peer that lost us seeks us (the receive path's lost_us rule): our answer goes as
        a multicast at ``now + delay`` (or ``retransmit_min_gap_s`` after our last one), so
        every drone that held its own seek back for that seeker's (``seek.Seek.heard``, the
        suppression's assumption: mDNS answers by multicast, RFC 6762 section 6) hears it
        too. A directed answer reached the seeker alone, and a drone that held back found us
        seconds later, after its window had closed (docs/flight-history.md, "The fade's slow
        return at N = 20 (session 11)"). Returns when the multicast is due. Adaptive mode,
        ANNOUNCE or STEADY (the caller checks)."""
        self.pull_in(now, delay)
        due = self._renewals.timer.due
        assert due is not None  # noqa: S101 - pull_in set it, or one sooner stands
        return due

    def pull_in(self, now: float, delay: float) -> None:
        """Our next multicast at now + ``delay``, never sooner than ``retransmit_min_gap_s``
        after our last one (a renewal already sooner stays)."""
        at = now + delay
        last = self._renewals.last_multicast
        if last is not None:
            # one multicast per re-ack gap: a commander regaining 19 members one after the
            # other sends one every gap while some are missing, not one per member
            at = max(at, last + self._gap_s)
        renewal = self._renewals.timer
        if renewal.due is None or at < renewal.due:
            renewal.due = at
            self.pulled_in = True

    def sent(self, now: float, rng: random.Random, *, announcing: bool) -> None:
        """We multicast: nothing is pulled in any more, and the renewal runs on, from its own
        deadline if a lease's end had pulled this one in, else a period from now."""
        self.pulled_in = False
        if announcing:
            renewal = self._renewals.timer
            resume = self.resume_renewal
            if resume is not None and resume > now:
                renewal.due = resume
            else:
                renewal.restart(now, rng)
        self.resume_renewal = None
