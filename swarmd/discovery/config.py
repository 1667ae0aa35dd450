"""The discovery engine's tunables, with the paper's values as defaults.

``EngineConfig`` is what the daemon builds from its config file (``discovery.mode`` and
``discovery.overrides``: every field below may be overridden by name). The three timing
values the whole swarm must agree on (Tmin, Tmax, lease) also live in the signed bundle
(``DiscoveryParams``); ``resolve_timing`` decides which one applies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Final, Literal

from swarmd.bundle.model import DiscoveryParams

Mode = Literal["paper", "adaptive"]
MODES: Final = ("paper", "adaptive")


@dataclass(frozen=True, slots=True)
class EngineConfig:
    """Tunables of one discovery engine. Construction raises ``ValueError`` with one line
    naming the field and the fix for a value the engine cannot work with."""

    # "paper": passive timer exactly as paper eq. 3; "adaptive": also scaled by swarm size
    mode: Mode = "adaptive"
    # paper section 4.1 (the bundle's DiscoveryParams take precedence, see resolve_timing)
    t_min_s: float = 8.0
    t_max_s: float = 20.0
    lease_s: float = 20.0
    # adaptive mode: announcement frames per second the whole swarm may put on the channel
    # at Q = 1; the passive window is N / (budget * Q) (docs/discovery.md, "adaptive mode")
    announce_budget_fps: float = 50.0
    # adaptive mode: Q below this counts as this, so a dead link still gets a finite window
    q_floor: float = 0.1
    # paper mode: a directed reply leaves within U(0, reply_delay_max_s) of the DATA(p) heard
    reply_delay_max_s: float = 0.1
    # staged announcements and repeated answers: base * 2^k, capped, at most max_attempts
    retry_base_s: float = 1.0
    retry_max_s: float = 8.0
    max_attempts: int = 6
    # owing a frame to this many peers at once: send one multicast instead of directed ones
    multicast_threshold: int = 2
    # lease renewals per lease period: min at Q = 1, max at Q = 0 (continuous awareness)
    renewals_per_lease_min: float = 2.0
    renewals_per_lease_max: float = 4.0
    renewal_jitter: float = 0.1  # each renewal period is shortened by U(0, jitter)
    # adaptive mode: lease-renewal frames per second the whole swarm may put on the channel;
    # a swarm larger than budget * lease / n(Q) renews every N / budget seconds and
    # advertises a lease n(Q) times that (docs/discovery.md, "renewal budget")
    renewal_budget_fps: float = 50.0
    # adaptive mode: the commander (the bundle's one Role.COMMANDER) vouches in its renewals
    # for the members it heard directly (SPDP or authenticated user data) within
    # ``vouch_window_s``; a vouched member's renewals wait (docs/discovery.md, "Vouching")
    vouch: bool = True
    vouch_window_s: float = 2.5
    # BOOT waits this long for a link sample, then assumes default_link_quality
    boot_link_timeout_s: float = 2.0
    default_link_quality: float = 0.5
    # a repeated directed DATA(p) (same SN) closer than this to the last one is a duplicate
    retransmit_min_gap_s: float = 0.5
    # the advertised link quality changes (and with it our SN) only by at least this much
    link_report_step: float = 0.1

    def __post_init__(self) -> None:
        def need(ok: bool, name: str, fix: str) -> None:
            if not ok:
                value = getattr(self, name)
                raise ValueError(f"discovery.{name} = {value!r} is invalid; fix: {fix}")

        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float):
                need(math.isfinite(v), f.name, "use a finite number")
        need(self.mode in MODES, "mode", "use 'paper' or 'adaptive'")
        need(self.t_min_s >= 0, "t_min_s", "use a value >= 0 seconds")
        # t_max_s >= t_min_s is checked by resolve_timing, once the bundle's values are in
        need(self.t_max_s >= 0, "t_max_s", "use a value >= 0 seconds")
        need(self.lease_s > 0, "lease_s", "use a positive number of seconds")
        need(self.announce_budget_fps > 0, "announce_budget_fps", "use a positive frame rate")
        need(0 < self.q_floor <= 1, "q_floor", "use a value in (0, 1]")
        need(self.reply_delay_max_s >= 0, "reply_delay_max_s", "use a value >= 0 seconds")
        need(self.retry_base_s > 0, "retry_base_s", "use a positive number of seconds")
        need(self.retry_max_s >= self.retry_base_s, "retry_max_s", "use a value >= retry_base_s")
        need(self.max_attempts >= 1, "max_attempts", "use an integer >= 1")
        need(self.multicast_threshold >= 1, "multicast_threshold", "use an integer >= 1")
        need(self.renewals_per_lease_min > 1, "renewals_per_lease_min", "use a value > 1")
        need(
            self.renewals_per_lease_max >= self.renewals_per_lease_min,
            "renewals_per_lease_max",
            "use a value >= renewals_per_lease_min",
        )
        need(0 <= self.renewal_jitter < 1, "renewal_jitter", "use a fraction in [0, 1)")
        need(self.renewal_budget_fps > 0, "renewal_budget_fps", "use a positive frame rate")
        need(
            0 < self.vouch_window_s <= 10,
            "vouch_window_s",
            "use a window in (0, 10] seconds, well under the lease",
        )
        need(self.boot_link_timeout_s >= 0, "boot_link_timeout_s", "use a value >= 0 seconds")
        need(0 <= self.default_link_quality <= 1, "default_link_quality", "use a value in [0, 1]")
        need(self.retransmit_min_gap_s >= 0, "retransmit_min_gap_s", "use a value >= 0")
        need(0 <= self.link_report_step <= 1, "link_report_step", "use a value in [0, 1]")


@dataclass(frozen=True, slots=True)
class Timing:
    """The effective Tmin, Tmax and lease, and where each came from ("bundle" | "config")."""

    t_min_s: float
    t_max_s: float
    lease_s: float
    sources: tuple[tuple[str, str], ...]


_TIMING_FIELDS: Final = ("t_min_s", "t_max_s", "lease_s")


def resolve_timing(bundle: DiscoveryParams, config: EngineConfig) -> Timing:
    """Precedence, lowest first: built-in defaults < bundle < explicit config override.

    The bundle is the swarm-wide agreement, so it replaces the daemon's defaults. A config
    value that differs from the built-in default is an operator's deliberate override (a
    bench, a test flight) and wins; ``status()`` shows which source each value came from.
    """
    defaults = EngineConfig()
    values: dict[str, float] = {}
    sources: list[tuple[str, str]] = []
    for name in _TIMING_FIELDS:
        configured = float(getattr(config, name))
        if configured != getattr(defaults, name):
            values[name], source = configured, "config"
        else:
            values[name], source = float(getattr(bundle, name)), "bundle"
        sources.append((name, source))
    if not (0 <= values["t_min_s"] <= values["t_max_s"]) or values["lease_s"] <= 0:
        raise ValueError(
            f"discovery timing t_min_s={values['t_min_s']} t_max_s={values['t_max_s']} "
            f"lease_s={values['lease_s']} (from {dict(sources)}) is inconsistent; "
            "fix: 0 <= t_min_s <= t_max_s and lease_s > 0"
        )
    return Timing(values["t_min_s"], values["t_max_s"], values["lease_s"], tuple(sources))
