"""A captured member raising its boot epoch on every datagram (session 16, h-insider16).

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
Virtual time only. The last test measures the residual: leaving and returning is not bounded here.
"""

from __future__ import annotations

from collections.abc import Sequence

from swarmd_lab.testing import auth_for, leave_or_return_datagram, peer_datagram

from swarmd.discovery import Event, PeerDiscovered, PeerLost, PeerRestarted
from swarmd.discovery.receive import RESTART_MIN_INTERVAL_S
from tests.test_discovery_auth import A1, BUNDLE, drain, receiver

RATE_PER_S = 20  # the member's verification budget (swarmd.auth.budget): all of it
SECONDS = 10


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
    # on main: 200 restarts in 10 s (one a datagram); now at most one per interval
    ceiling = int(SECONDS / RESTART_MIN_INTERVAL_S) + 1
    assert 1 <= len(restarts) <= ceiling
    assert e.counters()["restarts_coalesced"] == count - len(restarts)
    # each honoured restart names the newest epoch heard, and epochs only rise
    epochs = [r.epoch for r in restarts]
    assert epochs == sorted(set(epochs))
    # the engine's view follows the honoured life; the last rise is honoured by the member's
    # first datagram after the interval, so nothing is lost once it stops churning
    now = SECONDS + RESTART_MIN_INTERVAL_S + 0.01
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


def test_leaving_and_returning_is_not_bounded_by_the_restart_interval() -> None:
    """The residual (docs/security.md, "A captured member's lives"), measured: a signed
    dispose and a signed DATA(p) in turn, 20 a second, are a ``PeerLost`` and a
    ``PeerDiscovered`` per pair at the receiver (a relay dispose and announcement each, a
    log line each), with or without a new epoch. If this is ever bounded, change the doc."""
    for new_epoch in (False, True):
        e = receiver()
        auth = auth_for(BUNDLE, 1, epoch=10)
        lost = found = 0
        for i in range(2, 2 + RATE_PER_S * SECONDS):
            now = i / RATE_PER_S
            if new_epoch:
                auth = auth_for(BUNDLE, 1, epoch=10 + i, now=now)
            e.receive_datagram(
                leave_or_return_datagram(BUNDLE, 1, sequence_number=i, auth=auth), A1, now
            )
            events = drain(e)
            lost += sum(isinstance(x, PeerLost) for x in events)
            found += sum(isinstance(x, PeerDiscovered) for x in events)
        assert (lost, found) == (RATE_PER_S * SECONDS // 2, RATE_PER_S * SECONDS // 2)
        assert e.counters()["restarts_coalesced"] == 0
