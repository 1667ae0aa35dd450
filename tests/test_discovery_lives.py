"""A peer's lives damped over time (swarmd/lives.py; RFC 2439 route-flap damping).

The pure class on hand-set time first, then what it does to an honest peer through the
engine: a crash loop, a fly-out and back, and one restart after the penalty decayed. The
captured member's churn is ``tests/test_discovery_epoch_churn.py``. Virtual time only.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from swarmd_lab.testing import auth_for, leave_or_return_datagram, peer_datagram

from swarmd.auth.spdp import SpdpAuth
from swarmd.discovery import DiscoveryEngine, PeerDiscovered, PeerLost, PeerRestarted
from swarmd.lives import (
    FLAP_HALF_LIFE_S,
    FLAP_HOLD_MAX_S,
    FLAP_PENALTY,
    FLAP_PENALTY_LIMIT,
    LifeDamping,
)
from tests.test_discovery_auth import A1, BUNDLE, drain, receiver

FREE_LIVES = int(FLAP_PENALTY_LIMIT) + 1
# a crash loop's lives as the others hear them, at the fastest: systemd's RestartSec=2s,
# then the fastest start-up to the first SPDP (0.288 s of 60: docs/benchmarks.md, "Daemon
# start-up"); each life dies right after its first DATA(p)
CRASH_LOOP_S = 2.0 + 0.288


def test_the_first_lives_are_free_at_any_pace_and_the_next_waits_for_the_decay() -> None:
    d = LifeDamping()
    for k in range(FREE_LIVES):
        assert not d.held(1, k * 0.25)
        d.honoured(1, k * 0.25)
    now = (FREE_LIVES - 1) * 0.25
    assert d.held(1, now)
    # held exactly until the penalty has decayed back to the limit
    until = d.reuse_at(1)
    assert math.isclose(d.penalty(1, until), FLAP_PENALTY_LIMIT)
    assert d.held(1, until - 0.001)
    assert not d.held(1, until)
    assert until - now <= FLAP_HOLD_MAX_S
    # the other peers are not touched
    assert not d.held(0, now)
    assert not d.held(2, now)
    assert d.penalty(2, now) == 0.0


def test_the_penalty_halves_every_half_life() -> None:
    d = LifeDamping()
    d.honoured(1, 10.0)
    assert d.penalty(1, 10.0) == FLAP_PENALTY
    assert math.isclose(d.penalty(1, 10.0 + FLAP_HALF_LIFE_S), FLAP_PENALTY / 2)
    assert math.isclose(d.penalty(1, 10.0 + 3 * FLAP_HALF_LIFE_S), FLAP_PENALTY / 8)
    # a time before the last update (a driver never goes back) does not grow it
    assert d.penalty(1, 0.0) == FLAP_PENALTY


def test_a_peer_honoured_as_soon_as_allowed_forever_gets_one_life_per_hold_max() -> None:
    """The steady state of a churn at the fastest pace the damping allows: every hold is
    ``FLAP_HOLD_MAX_S`` (the penalty peaks at limit + 1), never longer."""
    d = LifeDamping()
    now = 0.0
    honoured = []
    while now < 3600.0:
        if not d.held(1, now):
            d.honoured(1, now)
            honoured.append(now)
        now = max(now + 0.25, d.reuse_at(1))
    assert d.penalty(1, now) <= FLAP_PENALTY_LIMIT + FLAP_PENALTY
    gaps = [b - a for a, b in zip(honoured[FREE_LIVES - 1 :], honoured[FREE_LIVES:], strict=False)]
    assert gaps
    assert all(g <= FLAP_HOLD_MAX_S + 1e-9 for g in gaps)
    assert all(g >= FLAP_HOLD_MAX_S - 0.25 for g in gaps[1:])
    assert len(honoured) <= FREE_LIVES + math.ceil(3600.0 / FLAP_HOLD_MAX_S)


def test_lives_an_hour_apart_are_never_held() -> None:
    d = LifeDamping()
    for k in range(24):
        assert not d.held(1, k * 3600.0)
        d.honoured(1, k * 3600.0)


def _restarting(
    lives: int, spacing: float
) -> tuple[DiscoveryEngine, list[tuple[int, float]], SpdpAuth]:
    """A receiver that found uav1 and hears ``lives`` more lives of it ``spacing`` apart,
    one DATA(p) each (an honest crash loop: no dispose). (epoch, when) of each restart, and
    the last life's authenticator (its counter runs on)."""
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=1)), A1, 0.0)
    drain(e)
    seen = []
    auth = auth_for(BUNDLE, 1, epoch=1)
    for k in range(1, lives + 1):
        now = k * spacing
        auth = auth_for(BUNDLE, 1, epoch=1 + k, now=now)
        e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth), A1, now)
        seen += [(x.epoch, now) for x in drain(e) if isinstance(x, PeerRestarted)]
    return e, seen, auth


def test_an_honest_crash_loop_has_its_first_restarts_at_once_and_its_last_late_never_lost() -> None:
    """A crash loop at systemd's fastest: its first 4 restarts are each a ``PeerRestarted``
    at its first DATA(p), as on main; the 5th is held (docs/security.md: the cost); once
    the loop stops, its last life is taken within ``FLAP_HOLD_MAX_S``."""
    e, seen, _ = _restarting(FREE_LIVES + 1, CRASH_LOOP_S)
    assert seen == [(1 + k, k * CRASH_LOOP_S) for k in range(1, FREE_LIVES + 1)]
    assert e.counters()["lives_damped"] == 1
    stopped = (FREE_LIVES + 1) * CRASH_LOOP_S
    newest = FREE_LIVES + 2
    # the last life renews; its first DATA(p) past the hold (at most FLAP_HOLD_MAX_S after
    # the last restart honoured) is its restart, in its own epoch
    auth = auth_for(BUNDLE, 1, epoch=newest, now=stopped)
    now, sn = stopped, 2
    restarts: list[PeerRestarted] = []
    while not restarts and now < stopped + 2 * FLAP_HOLD_MAX_S:
        now += 1.0
        e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=sn, auth=auth), A1, now)
        sn += 1
        restarts = [x for x in drain(e) if isinstance(x, PeerRestarted)]
    assert [x.epoch for x in restarts] == [newest]
    assert now - FREE_LIVES * CRASH_LOOP_S <= FLAP_HOLD_MAX_S + 1.0
    assert e.peers()[0].discovered


def test_a_few_restarts_an_hour_apart_are_all_at_once() -> None:
    _, seen, _ = _restarting(12, 300.0)
    assert [when for _, when in seen] == [k * 300.0 for k in range(1, 13)]


def _run_until(e: DiscoveryEngine, end: float) -> list[object]:
    events: list[object] = []
    timer = e.get_timer()
    while timer is not None and timer < end:
        e.handle_timer(timer)
        events += drain(e)
        timer = e.get_timer()
    return events


def test_a_fly_out_and_back_is_never_held_even_past_the_free_lives() -> None:
    """A lease loss is no life (the peer did not say it left): its return is found at its
    first DATA(p) whatever its penalty, as on main."""
    e, seen, auth = _restarting(FREE_LIVES + 1, 0.5)
    assert len(seen) == FREE_LIVES
    last = (FREE_LIVES + 1) * 0.5
    events = _run_until(e, last + 60.0)
    assert [(x.name, x.reason) for x in events if isinstance(x, PeerLost)] == [("uav1", "lease")]
    back = last + 60.0  # the same life, back in range
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=9, auth=auth), A1, back)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
    assert e.counters()["returns_held"] == 0


@pytest.mark.parametrize("restart_sec", [0.0, 2.0])
def test_restarts_and_returns_share_one_penalty(restart_sec: float) -> None:
    """A captured member cannot spend its free lives twice by mixing epoch rises with
    leaving and returning: past 4 restarts, its stop-and-start (a start-up or RestartSec
    later) is held, counted, and found past the hold."""
    e, seen, auth = _restarting(FREE_LIVES, 0.5)
    assert len(seen) == FREE_LIVES
    epoch = 1 + FREE_LIVES
    e.receive_datagram(leave_or_return_datagram(BUNDLE, 1, sequence_number=3, auth=auth), A1, 3.0)
    assert [x.reason for x in drain(e) if isinstance(x, PeerLost)] == ["disposed"]
    now = 3.0 + restart_sec + 0.288
    auth = auth_for(BUNDLE, 1, epoch=epoch + 1, now=now)
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), A1, now)
    assert drain(e) == []
    assert e.counters()["returns_held"] == e.counters()["lives_damped"] == 1
    now = FREE_LIVES * 0.5 + FLAP_HOLD_MAX_S
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=4, auth=auth), A1, now)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]


def test_the_docs_state_the_damping_as_the_code_sets_it() -> None:
    """docs/discovery.md and docs/security.md give the half-life, the limit and the longest
    hold in figures; a change on either side fails here."""
    root = Path(__file__).resolve().parent.parent
    # whitespace folded: a sentence may wrap anywhere
    discovery = " ".join((root / "docs/discovery.md").read_text().split())
    security = " ".join((root / "docs/security.md").read_text().split())
    hold = f"{FLAP_HOLD_MAX_S:.1f} s"
    assert f"`FLAP_HALF_LIFE_S` ({FLAP_HALF_LIFE_S:g} s)" in discovery
    assert f"`FLAP_PENALTY_LIMIT` ({FLAP_PENALTY_LIMIT:g})" in discovery
    ratio = f"log2({FREE_LIVES}/{FREE_LIVES - 1})"
    assert f"`FLAP_HOLD_MAX_S` = {FLAP_HALF_LIFE_S:g} · {ratio} = {hold}" in discovery
    assert f"halved every {FLAP_HALF_LIFE_S:g} s (`FLAP_HALF_LIFE_S`)" in security
    assert f"`FLAP_HOLD_MAX_S` ({hold})" in security
