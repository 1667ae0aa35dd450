"""Lease renewals and the link quality that steers them (paper section 4.1: continuous
network awareness; docs/discovery.md, "Continuous awareness" and "The renewal budget").

The engine's renewal is one jittered ``Periodic``: a multicast DATA(p) every
``renewal_period_s`` (denser when Q is low; in adaptive mode within the swarm's renewal
budget; for the vouching commander, ``vouch_period_s``). Any multicast we send restarts it.
The lease we advertise is ``advertised_lease_s``: n(Q) such periods. Q moves both only in
steps of ``link_report_step`` (hysteresis), so a jittery reading does not change our DATA(p)
(and bump its sequence number) on every poll.
"""

from __future__ import annotations

import random
from typing import Final

from swarmd.discovery.awareness import (
    advertised_lease_s,
    normalise_q,
    renewal_period_s,
    vouch_period_s,
)
from swarmd.discovery.config import EngineConfig, Timing
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.timers import Periodic, WindowRate

# The window the send and receive rates are read over (status()["rates"]): a minute holds
# 6-18 renewals at the periods Q gives with a 20 s lease (3.4-10 s), enough for a rate to
# follow Q without being one frame's noise.
RATE_WINDOW_S: Final = 60.0
# The times kept per rate: far above what we send (one renewal per re-ack gap at most) or a
# live commander's vouches (one every few seconds), so only a flood reaches it.
MAX_RATE_SAMPLES: Final = 1024


class Renewals:
    """Our link quality (``q``, the advertised ``permille``) and the renewal timer."""

    __slots__ = (
        "_config",
        "_swarm_size",
        "_timing",
        "_vouching",
        "last_multicast",
        "link",
        "permille",
        "q",
        "sent",
        "timer",
    )

    def __init__(
        self,
        config: EngineConfig,
        timing: Timing,
        *,
        swarm_size: int,
        vouching: bool,
        now: float,
    ) -> None:
        self._config = config
        self._timing = timing
        self._swarm_size = swarm_size
        self._vouching = vouching  # we are the commander, and vouch (leases.py)
        self.link: LinkSample | None = None  # the latest reading, None before the first
        self.q = normalise_q(config.default_link_quality)
        self.permille = round(self.q * 1000)  # the Q we advertise (and plan with), in 1/1000
        self.timer = Periodic(self.period_s(), config.renewal_jitter)
        self.last_multicast: float | None = None  # when we last sent any multicast
        self.sent = WindowRate(RATE_WINDOW_S, MAX_RATE_SAMPLES, now)  # plain renewals sent

    def on_link(self, sample: LinkSample, now: float, rng: random.Random) -> None:
        """A new reading: Q follows it; the advertised Q and the renewal period follow Q
        only when it moved by ``link_report_step`` or more."""
        self.link = sample
        self.q = normalise_q(sample.q)
        permille = round(self.q * 1000)
        step = round(self._config.link_report_step * 1000)
        if abs(permille - self.permille) >= max(1, step):
            # hysteresis: a jittery reading must not bump our SN on every poll
            self.permille = permille
            period = self.period_s()
            timer = self.timer
            if timer.deadline() is not None and period != timer.period_s:
                last = self.last_multicast if self.last_multicast is not None else now
                timer.reschedule(period, last, rng)
            else:
                timer.period_s = period

    def period_s(self) -> float:
        """The renewal period at the advertised Q (awareness.renewal_period_s, or
        awareness.vouch_period_s for the vouching commander)."""
        config = self._config
        if self._vouching:
            return vouch_period_s(
                self.permille / 1000,
                lease_s=self._timing.lease_s,
                window_s=config.vouch_window_s,
                per_lease_min=config.renewals_per_lease_min,
                per_lease_max=config.renewals_per_lease_max,
            )
        return renewal_period_s(
            self.permille / 1000,
            lease_s=self._timing.lease_s,
            per_lease_min=config.renewals_per_lease_min,
            per_lease_max=config.renewals_per_lease_max,
            # paper mode keeps the bundle's lease and the plain n(Q) density
            swarm_size=self._swarm_size,
            renewal_budget_fps=config.renewal_budget_fps if config.mode == "adaptive" else None,
        )

    def lease_s(self) -> float:
        """The lease we advertise (awareness.advertised_lease_s)."""
        return advertised_lease_s(
            self.permille / 1000,
            lease_s=self._timing.lease_s,
            renewal_period_s=self.timer.period_s,
            per_lease_min=self._config.renewals_per_lease_min,
            per_lease_max=self._config.renewals_per_lease_max,
        )
