"""The renewal and vouch rate counters (issue 20: "the renewal/vouch rate following the link
quality" measured): ``timers.WindowRate`` by hand, then the engines' ``status()["rates"]`` in
a swarm on MemNet (virtual time), and their rendering in ``swarmctl status``."""

from __future__ import annotations

import pytest
from swarmd_lab.testing import build_swarm

from swarmd.cli.status_cmd import render_status
from swarmd.discovery import EngineConfig
from swarmd.discovery.renewals import MAX_RATE_SAMPLES, RATE_WINDOW_S
from swarmd.discovery.timers import WindowRate


def test_a_window_rate_counts_the_last_window_and_keeps_the_total() -> None:
    rate = WindowRate(10.0, 100, start=0.0)
    assert rate.per_s(0.0) == 0.0
    for t in (1.0, 2.0, 3.0, 4.0):
        rate.mark(t)
    assert rate.per_s(4.0) == pytest.approx(4 / 4.0)  # before a whole window: over 4 s
    assert rate.per_s(10.0) == pytest.approx(4 / 10.0)
    assert rate.per_s(12.5) == pytest.approx(2 / 10.0)  # 1 and 2 left the window
    rate.mark(20.0)
    assert rate.per_s(20.0) == pytest.approx(1 / 10.0)
    assert rate.total == 5
    assert rate.per_s(20.0) == rate.per_s(20.0)  # reading changes nothing


def test_a_flood_cannot_grow_a_window_rate() -> None:
    rate = WindowRate(10.0, 8, start=0.0)
    for k in range(1000):
        rate.mark(5.0 + k * 1e-4)
    assert rate.total == 1000
    assert rate.per_s(5.1) == pytest.approx(8 / 5.1)  # at most cap per window
    assert len(rate._times) == 8  # noqa: SLF001 - the cap is what is asserted


def _rates(q: float, vouch: bool, until: float = 150.0) -> list[dict[str, float]]:
    swarm = build_swarm(10, seed=3, q=q, config=EngineConfig(vouch=vouch))
    swarm.run_until(until)
    return [e.status(until)["rates"] for e in swarm.engines]


def test_the_renewal_rate_follows_the_link_quality() -> None:
    """n(Q) = 2 + 2(1 - Q) renewals per 20 s lease: every 10 s at Q = 1, every 5 s at
    Q = 0 (docs/discovery.md, "Continuous awareness"); the window's rate shows it."""
    good, poor = _rates(1.0, vouch=False), _rates(0.0, vouch=False)
    for g, p in zip(good, poor, strict=True):
        assert g["window_s"] == RATE_WINDOW_S
        assert 0.08 <= g["renewals_sent_per_s"] <= 0.12  # ~1/10 s (jitter 10 %)
        assert 0.17 <= p["renewals_sent_per_s"] <= 0.23  # ~1/5 s
        assert g["vouches_sent_per_s"] == g["vouches_received_per_s"] == 0.0


def test_the_vouch_rates_at_the_commander_and_the_members() -> None:
    """The commander sends its vouch on every frame (one every few seconds, denser at a
    lower Q: n(Q) + 1 per vouched lease); the members take them. (With no user data the
    commander hears a member only in its renewals, so its vouches rarely name one within
    their 2.5 s window and the members keep renewing: tests/test_discovery_vouch.py has
    the silent members, with readiness flowing.)"""
    good, poor = _rates(1.0, vouch=True), _rates(0.0, vouch=True)
    commander_good, commander_poor = good[0], poor[0]
    assert commander_good["vouches_received_per_s"] == 0.0
    assert 0.0 < commander_good["vouches_sent_per_s"] < commander_poor["vouches_sent_per_s"]
    for member in good[1:]:
        assert member["vouches_sent_per_s"] == 0.0
        # each multicast vouch reaches every member on a clean channel; a directed one
        # only the member it answers
        assert 0.0 < member["vouches_received_per_s"] <= commander_good["vouches_sent_per_s"]
        assert member["vouches_received"] > 0


def test_status_counts_the_totals_and_swarmctl_shows_the_rates() -> None:
    swarm = build_swarm(4, seed=1)
    swarm.run_until(60.0)
    st = swarm.engines[0].status(60.0)
    assert st["counters"]["vouches_sent"] == st["rates"]["vouches_sent"] > 0
    assert st["rates"]["renewals_sent"] == st["counters"]["tx_kind"]["renewal"]
    line = next(ln for ln in render_status(st, wall_now=0.0) if ln.startswith("per s over"))
    assert line.split()[3] == "60"
    assert "vouches sent" in line and f"{st['rates']['vouches_sent_per_s']:.3f}" in line
    assert MAX_RATE_SAMPLES >= 2 * RATE_WINDOW_S  # a renewal per re-ack gap stays under it
