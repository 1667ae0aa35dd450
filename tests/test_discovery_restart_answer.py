"""A peer that restarted mid-flight is answered within the rejoin delay (issue 20, reboot).

On the ns-3 channel (docs/flight-history.md, "The rebooted drone at N = 20") a rebooted drone
listed its 19 peers up to 3.8 s after its restart: each peer answered its first
announcement after the first-answer holdoff U(W, 2W) at the peer's own Q (W = N / (50 Q):
1.3 s at the grid's corners, Q 0.30), read before the restart. Now the answer comes within
the rejoin delay U(0, W1), W1 = N / 50 = 0.4 s at N = 20, as for a peer heard again after an
outage. Virtual time, authenticated engines on MemNet, every drone at Q = 0.3.
"""

from __future__ import annotations

import pytest
from swarmd_lab.testing import Swarm, build_swarm

from swarmd.discovery import LinkSample
from swarmd.discovery.events import PeerDiscovered, PeerRestarted

N = 20
Q_LOW = 0.3  # the grid's corners at N = 20 on the channel
W1 = N / 50  # the rejoin delay's bound: N / announce budget
NET_S = 0.05  # MemNet's delivery delays, with margin
KILL_S, BACK_S = 40.0, 45.0
NODE = N // 2


def _replies(swarm: Swarm) -> int:
    return sum(e.counters()["tx_kind"]["reply"] for e in swarm.engines)


def _restart(seed: int) -> tuple[Swarm, list[float], dict[int, float], int]:
    """The swarm steady at Q_LOW, NODE cut at 40 s and a new process of it (epoch 2) at 45 s;
    returns the swarm, each peer's PeerRestarted time, when the new life found each, and
    the directed replies sent by then."""
    swarm = build_swarm(N, seed=seed, authenticated=True)
    replies_before: list[int] = []

    def low_q(now: float) -> None:
        for i, engine in enumerate(swarm.engines):
            engine.update_link_quality(LinkSample(q=Q_LOW, source="static"), now)
            swarm.net.poke(i)

    def reboot(now: float) -> None:
        swarm.restart(NODE, now, seed=seed * 1000 + NODE, q=Q_LOW)

    swarm.net.call_at(1.0, low_q)
    swarm.net.call_at(KILL_S, lambda now: swarm.net.isolate(NODE))
    swarm.net.call_at(BACK_S - 0.001, lambda now: replies_before.append(_replies(swarm)))
    swarm.net.call_at(BACK_S, reboot)
    swarm.run_until(BACK_S + 15.0)
    seen = [
        t
        for i, events in enumerate(swarm.events)
        for t, e in events
        if i != NODE and t >= BACK_S and isinstance(e, PeerRestarted)
    ]
    finds: dict[int, float] = {}
    for t, e in swarm.events[NODE]:
        if t >= BACK_S and isinstance(e, PeerDiscovered):
            finds.setdefault(swarm.index_of[e.name], t)
    return swarm, seen, finds, replies_before[0]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_peer_answers_a_restarted_drone_within_the_rejoin_delay(seed: int) -> None:
    _, seen, finds, _ = _restart(seed)
    assert len(seen) == N - 1, "every peer saw the new life"
    assert sorted(finds) == [i for i in range(N) if i != NODE], "and the new life found it"
    announced = min(seen)
    # before: U(W, 2W) at Q 0.3, W = 1.33 s: the slowest answer 1.4-2.6 s after it
    assert max(finds.values()) - announced <= W1 + NET_S, finds
    assert max(finds.values()) - BACK_S <= 2.0


def test_a_restart_costs_one_directed_answer_per_peer_not_a_storm() -> None:
    """The answers are the same directed frames, sooner: one per surviving peer (once per
    re-ack gap), and the restarted drone's own replies to the peers that announce to it."""
    swarm, _, finds, before = _restart(4)
    assert len(finds) == N - 1
    assert _replies(swarm) - before <= 2 * (N - 1), (_replies(swarm), before)
