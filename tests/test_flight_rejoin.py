"""Issue 20's heal and blackout with the link reading a drone really has after an outage.

On the emulated 802.11 channel (docs/benchmarks.md, "Flight") re-discovery after a split took
up to 4.8 s (N = 20) and after a commander blackout 3.3-4.6 s, against the <= 2 s target,
while ``tests/test_flight_scenarios.py`` (every engine's Q fixed at 1) met it. The run files
say why: a drone cut off hears nobody, so its link monitor reads Q near 0 (the flight link
file reads 0 before any frame is heard; eq. 2's Q from the SNR of what it hears) and still
reads it low for seconds after the return. Its rejoin pull-in waited adaptive mode's reply
holdoff U(W, 2W), with W = N / (B * max(Q, q_floor)): U(2, 4) s at N = 10 and U(4, 8) s at
N = 20 for Q <= 0.1. Uav15 at N = 20 heard the west group from 107.7 s but was heard by it
only at 111.05 s, its pulled-in multicast; the commander heard uav8 at 66.56 s after the
blackout and the members heard it at 67.89 s.

Here every drone cut off reads Q = ``Q_CUT`` (0: it hears nobody; 0.15 for the group that
flew away, as uav15 read) until ``Q_LAG_S`` after the link's return, then 1 again. Times
asserted are virtual (MemNet), never the host's.
"""

from __future__ import annotations

from collections.abc import Iterable

import pytest
from swarmd_lab.testing import Swarm, build_swarm

from swarmd.discovery import DiscoveryEngine, LinkSample
from swarmd.discovery.events import PeerDiscovered, PeerLost

SEEDS = (1, 2, 3, 4, 5)
REDISCOVERY_TARGET_S = 2.0  # issue 20
FRAMES_PER_PAIR_TARGET = 4  # issue 20: no storm at the heal
Q_LAG_S = 3.0  # the link monitor's reading catches up this long after the return


class Cut:
    """The pairs whose frames are lost; which nodes are cut off (and read a low Q)."""

    def __init__(self) -> None:
        self.apart: set[int] = set()  # one side of the cut; the rest is the other
        self.active = False

    def loss(self, src: int, dst: int) -> float:
        return 1.0 if self.active and (src in self.apart) != (dst in self.apart) else 0.0


def _read_q(swarm: Swarm, nodes: Iterable[int], q: float, now: float) -> None:
    for i in nodes:
        swarm.engines[i].update_link_quality(LinkSample(q=q, source="static"), now)
        swarm.net.poke(i)


def _discovery_frames(engines: Iterable[DiscoveryEngine]) -> int:
    kinds = ("announce", "reply", "probe")
    return sum(e.counters()["tx_kind"][k] for e in engines for k in kinds)


def _run(
    n: int, seed: int, apart: set[int], readers: dict[int, float], t_cut: float, t_back: float
) -> tuple[Swarm, dict[tuple[int, int], float], int]:
    """Cut ``apart`` from the rest at ``t_cut``, restore at ``t_back``; each node in
    ``readers`` reads its Q from the cut to ``Q_LAG_S`` after the return. Returns the swarm,
    the re-discovery time of every crossing pair and the discovery frames sent from the
    return on."""
    cut = Cut()
    cut.apart = apart
    swarm = build_swarm(n, seed=seed)
    swarm.net.link_loss = cut.loss
    swarm.run_until(30.0)
    assert swarm.all_discovered(), "the swarm did not form before the scenario"

    def go(now: float) -> None:
        cut.active = True
        for node, q in readers.items():
            _read_q(swarm, [node], q, now)

    def back(now: float) -> None:
        cut.active = False

    swarm.net.call_at(t_cut, go)
    swarm.net.call_at(t_back, back)
    swarm.net.call_at(t_back + Q_LAG_S, lambda now: _read_q(swarm, readers, 1.0, now))
    swarm.run_until(t_back)
    frames_at_return = _discovery_frames(swarm.engines)
    swarm.run_until(t_back + 25.0)
    back_at: dict[tuple[int, int], float] = {}
    for i, events in enumerate(swarm.events):
        for t, e in events:
            if t >= t_back and isinstance(e, PeerDiscovered):
                back_at.setdefault((i, swarm.index_of[e.name]), t)
    lost = {
        (i, swarm.index_of[e.name])
        for i, events in enumerate(swarm.events)
        for t, e in events
        if t >= t_cut and isinstance(e, PeerLost)
    }
    crossing = {(a, b) for a in range(n) for b in range(n) if (a in apart) != (b in apart)}
    assert lost == crossing, "only the pairs across the cut are lost"
    assert set(back_at) == crossing
    return swarm, back_at, _discovery_frames(swarm.engines) - frames_at_return


@pytest.mark.parametrize("n", [10, 20])
@pytest.mark.parametrize("seed", SEEDS)
def test_heal_with_the_returning_half_reading_a_poor_link(n: int, seed: int) -> None:
    """The second half flies away for 60 s (each of its drones reads Q = 0.15 from the
    cut until 3 s after the heal, as uav15 did on the channel): every crossing pair is
    re-discovered within 2 s of the heal, at most 4 discovery frames per rejoining pair."""
    away = set(range(n // 2, n))
    t_cut, t_heal = 30.0, 90.0
    swarm, back_at, frames = _run(n, seed, away, dict.fromkeys(away, 0.15), t_cut, t_heal)
    assert max(back_at.values()) - t_heal <= REDISCOVERY_TARGET_S
    pairs = len(back_at) // 2
    assert frames <= FRAMES_PER_PAIR_TARGET * pairs
    assert swarm.all_discovered()


@pytest.mark.parametrize("n", [10, 20])
@pytest.mark.parametrize("seed", SEEDS)
def test_blackout_with_the_commander_reading_no_link(n: int, seed: int) -> None:
    """The commander hears nobody for 30 s (Q = 0, until 3 s after its return): every
    member and the commander find each other again within 2 s of the return, at most 4
    discovery frames per rejoining pair."""
    commander = 0
    t_cut, t_back = 30.0, 60.0
    swarm, back_at, frames = _run(n, seed, {commander}, {commander: 0.0}, t_cut, t_back)
    assert max(back_at.values()) - t_back <= REDISCOVERY_TARGET_S
    assert frames <= FRAMES_PER_PAIR_TARGET * (n - 1)
    assert swarm.all_discovered()
