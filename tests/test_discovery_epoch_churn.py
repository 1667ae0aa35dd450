"""A captured member raising its boot epoch on every datagram (session 16, h-insider16),
or leaving and returning (h-leavereturn16).

Attacker 2 of docs/security.md: its ``node.key`` signs, so each datagram with a higher epoch
is genuine and fresh. Each rise was a restart to every drone (``PeerRestarted``): a
``peer_restarted`` log line and a peer-history row, the data plane's pair session reset
(``SwarmApp.peer_up`` in the new epoch: commands it never acknowledged voided for it, its
readiness re-reported), and the ROS 2 relay disposing and re-announcing the member's nodes
to every local node (``Ros2App.peer_up(restarted=True)``). Its verification budget (20 a
second, burst 40) was the only bound: 20 restarts a second, for as long as it likes.

A real drone cannot restart faster than its daemon starts (``RESTART_MIN_INTERVAL_S``,
receive.py), so a peer's restarts are honoured at most once per that interval; a faster
rise is still taken for freshness (the replay window moved with it) and counted
(``restarts_coalesced``), and honoured by the peer's first datagram after the interval.
Leaving (its signed DATA(p[UD])) and returning (its signed DATA(p)) did the same work
without a new epoch, 10 losses and 10 discoveries a second; its return is now held until
the same interval after its own dispose. Both still allowed 4 lives a second for as long
as the member liked; since session 17 (h-flap17) its lives are damped over time as well
(``lives.LifeDamping``, RFC 2439): 4 free, then one per ``FLAP_HOLD_MAX_S``. Virtual time
only.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import pytest
from swarmd_lab.testing import auth_for, leave_or_return_datagram, peer_datagram

from swarmd.auth.spdp import SpdpAuth
from swarmd.discovery import DiscoveryEngine, Event, PeerDiscovered, PeerLost, PeerRestarted
from swarmd.discovery.receive import RESTART_MIN_INTERVAL_S
from swarmd.lives import FLAP_HOLD_MAX_S, FLAP_PENALTY_LIMIT
from tests.test_discovery_auth import A1, BUNDLE, drain, receiver

RATE_PER_S = 20  # the member's verification budget (swarmd.auth.budget): all of it
SECONDS = 10
# the lives honoured at once, whatever the pace past the interval (lives.py: penalties 0, 1,
# 2, 3 before them)
FREE_LIVES = int(FLAP_PENALTY_LIMIT) + 1


def _restarts(events: Sequence[Event]) -> list[PeerRestarted]:
    return [x for x in events if isinstance(x, PeerRestarted)]


def test_a_captured_member_raising_its_epoch_on_every_datagram_restarts_at_a_bounded_rate() -> None:
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=10)), A1, 0.0)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
    restarts: list[PeerRestarted] = []
    count = RATE_PER_S * SECONDS
    auth = auth_for(BUNDLE, 1, epoch=10)
    for i in range(1, count + 1):
        now = i / RATE_PER_S
        auth = auth_for(BUNDLE, 1, epoch=10 + i, now=now)
        e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth), A1, now)
        restarts += _restarts(drain(e))
    # every datagram was genuine and fresh: none refused
    assert sum(e.counters()["dropped"].values()) == 0
    # before session 16: 200 restarts in 10 s (one a datagram); then at most one per
    # interval (40); now the free lives and at most one per FLAP_HOLD_MAX_S
    assert 1 <= len(restarts) <= FREE_LIVES + 1
    assert e.counters()["restarts_coalesced"] == count - len(restarts)
    # each honoured restart names the newest epoch heard, and epochs only rise
    epochs = [r.epoch for r in restarts]
    assert epochs == sorted(set(epochs))
    # the engine's view follows the honoured life; the last rise is honoured by the member's
    # first datagram after the hold, so nothing is lost once it stops churning
    now = SECONDS + FLAP_HOLD_MAX_S + 0.01
    last = 10 + count
    # (the last life's next datagram: the same epoch, its next freshness)
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), A1, now)
    events = drain(e)
    honoured = _restarts(events)
    if epochs[-1] != last:
        assert [r.epoch for r in honoured] == [last]
    assert e.peers()[0].epoch == last


def test_an_honest_restart_is_honoured_at_once() -> None:
    """The first restart we hear of a peer, and any one past the interval after the last,
    is a ``PeerRestarted`` at its first datagram, as before."""
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=1)), A1, 0.0)
    drain(e)
    for epoch, now in ((2, 1.0), (3, 1.0 + RESTART_MIN_INTERVAL_S)):
        auth = auth_for(BUNDLE, 1, epoch=epoch, now=now)
        e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth), A1, now)
        assert [(r.epoch, r.previous_epoch) for r in _restarts(drain(e))] == [(epoch, epoch - 1)]
    assert e.counters()["restarts_coalesced"] == 0


def test_a_captured_member_leaving_and_returning_loses_and_finds_it_at_a_bounded_rate() -> None:
    """Attacker 2 leaving and returning (docs/security.md, "A captured member's lives"): a
    signed dispose and a signed DATA(p) in turn, 20 a second, with or without a new epoch.
    On main each pair was a ``PeerLost`` and a ``PeerDiscovered`` at every drone (a relay
    dispose and announcement each, a log line each): 100 of each in 10 s. A return within
    ``RESTART_MIN_INTERVAL_S`` of the peer's own dispose is held (counted ``returns_held``)
    and honoured by its first datagram past the interval; session 16 left 33 of each in
    10 s. Past the free lives its returns wait for its penalty (``lives.py``) as well."""
    count = RATE_PER_S * SECONDS
    ceiling = 1 + FREE_LIVES + 1  # found once, then its lives
    for new_epoch in (False, True):
        e = receiver()
        auth = auth_for(BUNDLE, 1, epoch=10)
        lost = found = 0
        for i in range(2, 2 + count):
            now = i / RATE_PER_S
            if new_epoch:
                auth = auth_for(BUNDLE, 1, epoch=10 + i, now=now)
            e.receive_datagram(
                leave_or_return_datagram(BUNDLE, 1, sequence_number=i, auth=auth), A1, now
            )
            events = drain(e)
            lost += sum(isinstance(x, PeerLost) for x in events)
            found += sum(isinstance(x, PeerDiscovered) for x in events)
        # every datagram was genuine and fresh: none refused, each return held or honoured
        assert sum(e.counters()["dropped"].values()) == 0
        assert 1 <= found <= ceiling
        assert found <= lost <= found + 1
        assert e.counters()["returns_held"] == count // 2 - found
        assert e.counters()["restarts_coalesced"] == 0
        # once it stops churning (its last datagram a dispose), its next DATA(p) past the
        # hold finds it, in its newest life
        now = (2 + count) / RATE_PER_S + FLAP_HOLD_MAX_S
        if new_epoch:
            auth = auth_for(BUNDLE, 1, epoch=10 + 2 + count, now=now)
        e.receive_datagram(
            leave_or_return_datagram(BUNDLE, 1, sequence_number=2 + count, auth=auth), A1, now
        )
        assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
        assert e.peers()[0].discovered
        assert e.peers()[0].epoch == (10 + 2 + count if new_epoch else 10)


MINUTE_S = 60.0
SETTLE_S = 5.0  # "after the first few seconds": the free lives are spent by then


def _churn(seconds: float, *, leave: bool, new_epoch: bool) -> list[tuple[float, Event]]:
    """A receiver finds uav1, then hears RATE_PER_S of its genuine datagrams a second for
    ``seconds``: its DATA(p) in a new epoch each (``leave`` False), or its dispose and its
    DATA(p) in turn, in one epoch or a new one each. Its restarts, losses and finds after
    the first, with their times; every datagram must pass (none refused)."""
    e = receiver()
    auth = auth_for(BUNDLE, 1, epoch=10)
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), A1, 0.1)
    drain(e)
    seen: list[tuple[float, Event]] = []
    for i in range(3, 3 + int(seconds * RATE_PER_S)):
        now = i / RATE_PER_S
        if new_epoch or not leave:
            auth = auth_for(BUNDLE, 1, epoch=10 + i, now=now)
        if leave:
            data = leave_or_return_datagram(BUNDLE, 1, sequence_number=i, auth=auth)
        else:
            data = peer_datagram(BUNDLE, 1, sequence_number=i, auth=auth)
        e.receive_datagram(data, A1, now)
        seen += [
            (now, x) for x in drain(e) if isinstance(x, PeerRestarted | PeerLost | PeerDiscovered)
        ]
    assert sum(e.counters()["dropped"].values()) == 0
    return seen


@pytest.mark.parametrize(
    ("leave", "new_epoch"),
    [(False, True), (True, False), (True, True)],
    ids=["epoch", "leave", "leave-epoch"],
)
def test_a_captured_member_churning_for_a_minute_costs_each_drone_a_handful_of_lives(
    leave: bool, new_epoch: bool
) -> None:
    """Route-flap damping (``lives.LifeDamping``, RFC 2439): a minute of a captured member's
    churn at its whole budget, epoch rises or leaving and returning. Session 16's interval
    alone allowed 4 lives a second for as long as it liked: 240 restarts, or 200 losses and
    200 finds, in the minute at each drone (``python -m bench.lives_cost``). Now its first
    4 lives, then one per ``FLAP_HOLD_MAX_S``: at most 8 restarts or losses in the minute,
    3 after its first seconds."""
    seen = _churn(MINUTE_S, leave=leave, new_epoch=new_epoch)
    lives = [t for t, x in seen if isinstance(x, PeerRestarted | PeerDiscovered)]
    losses = [t for t, x in seen if isinstance(x, PeerLost)]
    damped = math.ceil(MINUTE_S / FLAP_HOLD_MAX_S)  # 3: one per hold, at most
    assert FREE_LIVES <= len(lives) <= FREE_LIVES + damped
    assert len(losses) <= len(lives) + 1 <= 8
    # the free lives come at once; after them at most one per hold
    assert sum(t > SETTLE_S for t in lives) <= damped
    assert sum(t > SETTLE_S for t in losses) <= damped
    late = [t for t in lives if t > SETTLE_S]
    assert all(b - a >= FLAP_HOLD_MAX_S - 1 / RATE_PER_S for a, b in itertools.pairwise(late))
    if not leave:
        assert losses == []  # a restart loses nothing


# an honest daemon's gap from its dispose to its next life's first DATA(p): ``systemctl
# restart`` starts it at once, a failure waits RestartSec=2s (systemd/swarmd.service); the
# start-up to the first SPDP is 0.288 s at the fastest of 60 (docs/benchmarks.md, "Daemon
# start-up"; bench/results/daemon_start/)
FASTEST_START_UP_S = 0.288


@pytest.mark.parametrize("restart_sec", [0.0, 2.0])
def test_an_honest_stop_and_start_is_found_at_once(restart_sec: float) -> None:
    """A daemon that stops disposes itself, and its next life sends no sooner than a
    start-up later: that first DATA(p), past ``RESTART_MIN_INTERVAL_S``, is a
    ``PeerDiscovered`` at once, in the new epoch, and nothing was held."""
    assert FASTEST_START_UP_S > RESTART_MIN_INTERVAL_S
    e = receiver()
    auth = auth_for(BUNDLE, 1, epoch=1)
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), A1, 0.0)
    drain(e)
    e.receive_datagram(leave_or_return_datagram(BUNDLE, 1, sequence_number=3, auth=auth), A1, 1.0)
    assert [(x.name, x.reason) for x in drain(e) if isinstance(x, PeerLost)] == [
        ("uav1", "disposed")
    ]
    now = 1.0 + restart_sec + FASTEST_START_UP_S
    auth = auth_for(BUNDLE, 1, epoch=2, now=now)
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=1, auth=auth), A1, now)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
    assert e.peers()[0].epoch == 2
    assert e.counters()["returns_held"] == 0


def _disposed_at_one_second(auth: SpdpAuth) -> DiscoveryEngine:
    """A receiver that found uav1 at 0 s and lost it to its signed dispose at 1 s."""
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), A1, 0.0)
    e.receive_datagram(leave_or_return_datagram(BUNDLE, 1, sequence_number=3, auth=auth), A1, 1.0)
    drain(e)
    return e


def _run_until(e: DiscoveryEngine, end: float) -> None:
    timer = e.get_timer()
    while timer is not None and timer < end:
        e.handle_timer(timer)
        timer = e.get_timer()


def test_a_return_within_the_interval_is_late_never_lost() -> None:
    """A DATA(p) within the interval after the peer's dispose moves nothing (no event, not
    listed, no answer owed: the receiver sends what a twin that never heard it sends); the
    peer's next one past the interval finds it."""
    auth = auth_for(BUNDLE, 1, epoch=1)
    e, twin = _disposed_at_one_second(auth), _disposed_at_one_second(auth_for(BUNDLE, 1, epoch=1))
    e.receive_datagram(
        peer_datagram(BUNDLE, 1, sequence_number=4, auth=auth), A1, 1.0 + RESTART_MIN_INTERVAL_S / 2
    )
    assert drain(e) == []
    assert not e.peers()[0].discovered
    assert e.counters()["returns_held"] == 1
    end = 1.0 + RESTART_MIN_INTERVAL_S
    _run_until(e, end)
    _run_until(twin, end)
    assert e.counters()["tx_kind"] == twin.counters()["tx_kind"]
    e.receive_datagram(peer_datagram(BUNDLE, 1, sequence_number=6, auth=auth), A1, end)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
    assert e.peers()[0].discovered
