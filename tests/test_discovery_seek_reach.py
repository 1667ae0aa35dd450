"""A seek put off by a frame that cannot reach the peer sought (``seek.Seek.heard``; issue 20).

The suppression rule (seek.py, RFC 6762 section 7.4's duplicate-answer suppression) puts our
seek off when we hear a peer's multicast whose heard digest omits every peer we seek: that
frame "seeks them as well as ours would". On one link it does; in a swarm strung out over
more than one radio range it need not: the peer we hear may be out of range of the peers we
seek. In the fly-out replay at N = 20 (seed 71, docs/discovery.md, "A seek put off by a frame
that cannot reach") uav9 and uav15 came back into range while uav5's seeks (out of uav15's
range) put off uav9's and uav20's (out of uav9's range) put off uav15's: neither sent a frame
the other could hear, and the pair waited for a seek to win the race.

The shape on MemNet, virtual time: two sides of ``SIDE`` drones, formed together, then cut
apart at ``T_CUT``; at ``T_BACK`` only the edge pair (``EDGE_L``, ``EDGE_R``) is back in range.
Every other drone of a side still seeks the whole other side, out of range, so every frame
each edge drone hears from its own side omits every peer it seeks. Times asserted are
virtual, never the host's.
"""

from __future__ import annotations

import random

import pytest
from swarmd_lab.testing import Swarm, build_swarm, make_bundle

from swarmd.bundle.model import Bundle
from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.seek import (
    SEEK_MAX_S,
    SEEK_MIN_S,
    SEEK_PUT_OFF_FOR_S,
    SEEK_PUT_OFF_MAX_S,
    SEEK_PUT_OFF_RANK_MAX,
    SEEK_PUT_OFF_SEEKERS_MAX,
    SEEK_SEEKERS_WINDOW_S,
    Seek,
    _pair_rank,
)
from swarmd.discovery.timers import MinInterval, RetrySchedule
from tests.seek_scenarios import formed_swarm, found_again_s

SEEDS = (1, 2, 3, 4, 5, 6, 7, 8)
# On the engine before seek.SEEK_PUT_OFF_MAX_S (42902ec: the suppression had no bound) the
# first two tests failed: the edge pair was found 2.2-6.1 s after its return in seeds 2, 5,
# 6, 8 (0.4-1.7 s in the others), and in every seed an edge drone fell silent for 5.3-9.6 s at
# a time while the cut lasted.
SIDE = 6
N = 2 * SIDE
EDGE_L, EDGE_R = SIDE - 1, SIDE  # the pair that comes back
T_CUT = 30.0
T_BACK = 60.0  # every lease across the cut has ended by then (and the seeks have started)
REDISCOVERY_TARGET_S = 2.0  # issue 20


def _strung_out_swarm(seed: int, side: int = SIDE) -> Swarm:
    """Two sides of ``side`` drones; only the edge pair (``side - 1``, ``side``) comes back."""
    edge_pair = {side - 1, side}

    def loss(now: float, a: int, b: int) -> float:
        if (a < side) == (b < side) or now < T_CUT:
            return 0.0
        back = now >= T_BACK and {a, b} == edge_pair
        return 0.0 if back else 1.0

    return formed_swarm(2 * side, seed, loss, T_CUT)


def _found_again_s(swarm: Swarm, observer: int, peer: int) -> float:
    return found_again_s(swarm, observer, peer, T_CUT, T_BACK)


def test_an_edge_pair_whose_sides_seek_out_of_its_range_is_found_within_2_s() -> None:
    """Every seed's edge pair (one test over all seeds: the race is won in some)."""
    latencies: dict[int, float] = {}
    for seed in SEEDS:
        swarm = _strung_out_swarm(seed)
        swarm.run_until(T_BACK + 10.0)
        latencies[seed] = max(
            _found_again_s(swarm, EDGE_L, EDGE_R), _found_again_s(swarm, EDGE_R, EDGE_L)
        )
    assert max(latencies.values()) <= REDISCOVERY_TARGET_S, latencies


def _edge_pair_found_s(side: int) -> dict[int, float]:
    """Per seed, from ``T_BACK`` until each edge drone has found the other again."""
    latencies: dict[int, float] = {}
    for seed in SEEDS:
        swarm = _strung_out_swarm(seed, side)
        swarm.run_until(T_BACK + 10.0)
        latencies[seed] = max(
            _found_again_s(swarm, side - 1, side), _found_again_s(swarm, side, side - 1)
        )
    return latencies


def test_a_side_as_large_as_the_cap_allows_finds_its_edge_pair_within_2_s() -> None:
    """Sides of SEEK_PUT_OFF_SEEKERS_MAX + 1 drones: each edge drone hears that many seekers of
    its own side, the most that keep the put-off bound (with 5 as the cap, sides of 8 waited
    up to 7.52 s in 3 of 8 seeds: `python -m bench.seek_sides --seekers-max 5`)."""
    latencies = _edge_pair_found_s(SEEK_PUT_OFF_SEEKERS_MAX + 1)
    assert max(latencies.values()) <= REDISCOVERY_TARGET_S, latencies


def test_a_side_denser_than_the_cap_finds_its_edge_pair_within_2_s() -> None:
    """Sides of SEEK_PUT_OFF_SEEKERS_MAX + 2 drones, each edge drone hearing one seeker too
    many for the count: the rank keeps the bound for the first SEEK_PUT_OFF_RANK_MAX of a
    side per sought peer, and the edge drones are among them for one of the other side's
    peers (docs/discovery.md, "The put-off bound at scale"). With the count alone (h-seek-
    scale) this was a strict xfail: up to 6.83 s in 6 of 8 seeds (`python -m
    bench.seek_sides --sides 10 --rank-max 0`)."""
    latencies = _edge_pair_found_s(SEEK_PUT_OFF_SEEKERS_MAX + 2)
    assert max(latencies.values()) <= REDISCOVERY_TARGET_S, latencies


@pytest.mark.parametrize("seed", SEEDS)
def test_each_edge_drone_keeps_seeking_while_its_side_seeks_out_of_range(seed: int) -> None:
    """Cut for good (no return): each edge drone still sends a frame the other side could
    hear at least every SEEK_PUT_OFF_MAX_S (2 x SEEK_MAX_S), whatever its side's frames
    (they cannot reach)."""
    swarm = _strung_out_swarm(seed)
    swarm.run_until(T_BACK)  # the cut's seeks are under way; the edge pair is not back yet
    for edge in (EDGE_L, EDGE_R):
        sent = [
            x.time
            for x in swarm.net.transmissions
            if x.node == edge and x.multicast and T_BACK - 20.0 <= x.time < T_BACK
        ]
        gaps = [b - a for a, b in zip([T_BACK - 20.0, *sent], [*sent, T_BACK], strict=True)]
        assert max(gaps) <= SEEK_PUT_OFF_MAX_S + 1e-9, (edge, [round(g, 2) for g in gaps])


COMMANDER_SEEDS = (1, 2, 3)
T_DIE = 40.0


@pytest.mark.parametrize("seed", COMMANDER_SEEDS)
def test_a_dead_commander_draws_one_seek_per_period_once_the_loss_is_stale(seed: int) -> None:
    """The fix's cost (a drone gone for good): the put-off bound holds only while the loss is
    fresh. The commander of 10 dies at 40 s; from SEEK_PUT_OFF_FOR_S after its last frame the
    9 members seek it about once per period among them all, not each every few seconds
    (`python -m bench.seek_cost`: 52-59 per minute from the second minute on, seeds 1-3, as
    before the bound; the bound everywhere made it ~9 x 60 / 2.4 = 225)."""
    swarm = build_swarm(10, seed=seed)
    swarm.run_until(T_DIE)
    last_frame = max(x.time for x in swarm.net.transmissions if x.node == 0)
    swarm.net.isolate(0)
    stale = last_frame + SEEK_PUT_OFF_FOR_S + SEEK_MAX_S

    def members_seeks() -> int:
        return sum(e.counters()["tx_kind"]["seek"] for e in swarm.engines[1:])

    swarm.run_until(stale)
    assert members_seeks() > 0, "the members did not lose the commander"
    before = members_seeks()
    window = 60.0
    swarm.run_until(stale + window)
    assert window / SEEK_MAX_S - 1 <= members_seeks() - before <= window / SEEK_MIN_S + 1


UNIT_N = 16  # the unit tests' bundle: the sought peer, us, and up to 14 seekers
SOUGHT = 1


def _peers(bundle: Bundle) -> list[Peer | None]:
    return [Peer(p, p.index, None, RetrySchedule(4), MinInterval(0.5)) for p in bundle.participants]


def _by_rank(bundle: Bundle) -> list[int]:
    """Every participant but the sought peer, in the rank order for ``SOUGHT``."""
    key = bundle.participants[SOUGHT].guid_prefix.value
    return sorted(
        (p.index for p in bundle.participants if p.index != SOUGHT),
        key=lambda i: _pair_rank(bundle.participants[i].guid_prefix.value, key),
    )


def _seek_as(me: int, seed: int, *, last_heard: float, now: float) -> tuple[Seek, list[int]]:
    """A ``Seek`` of participant ``me`` of a ``UNIT_N`` bundle that lost ``SOUGHT`` (last
    heard at ``last_heard``) at ``now``; the other participants (seekers to be), best rank
    first."""
    bundle = make_bundle(UNIT_N)
    peer_at = _peers(bundle)
    peer_at[me] = None
    seek = Seek(
        enabled=True,
        rng=random.Random(seed),
        peer_at=peer_at,
        my_guid_prefix=bundle.participants[me].guid_prefix.value,
    )
    lost = peer_at[SOUGHT]
    assert lost is not None
    lost.state = PeerState.LOST
    lost.last_heard = last_heard
    seek.start([lost], now=now)
    return seek, [i for i in _by_rank(bundle) if i != me]


def test_the_put_off_bound_holds_while_the_loss_is_fresh_and_again_after_a_return() -> None:
    """``Seek`` alone, hand-set time: a frame that omits the sought peer puts our seek off by
    a period, but while the loss is fresh no later than SEEK_PUT_OFF_MAX_S after our own
    last multicast; once it is stale, a full period from the frame; a lost peer's return
    makes it fresh again."""
    seek, others = _seek_as(2, 1, last_heard=10.0, now=30.0)
    omits = bytes(1)  # a heard digest that lists nobody

    def put_off_at(now: float) -> float:
        seek.sent(now)  # our own multicast
        assert seek.due is not None
        seek.due = now + SEEK_MIN_S  # whatever its draw: a put-off moves it
        for k in range(1, 6):  # a seek heard every 0.9 s puts ours off each time
            seek.heard(omits, now + 0.9 * k, others[0])  # one seeker
        return seek.due - now

    assert put_off_at(31.0) <= SEEK_PUT_OFF_MAX_S + 1e-9  # fresh: 21 s after its last frame
    stale = 10.0 + SEEK_PUT_OFF_FOR_S + 1.0
    assert put_off_at(stale) >= 4.5 + SEEK_MIN_S  # stale: each frame puts it off a period
    seek.returned(stale + 10.0)  # another lost peer was heard again
    assert put_off_at(stale + 10.0) <= SEEK_PUT_OFF_MAX_S + 1e-9


def test_the_put_off_bound_holds_for_a_drone_that_hears_few_seekers_only() -> None:
    """``Seek`` alone, hand-set time, the loss fresh: frames from up to
    SEEK_PUT_OFF_SEEKERS_MAX distinct seekers (one of them over and over) leave the bound on;
    one more seeker within SEEK_SEEKERS_WINDOW_S lifts it (a dense neighbourhood: each frame
    puts our seek a full period off); once the window has passed without them, the few that
    remain keep it again."""
    last = _by_rank(make_bundle(UNIT_N))[-1]  # ranked last: only the count keeps its bound
    seek, others = _seek_as(last, 2, last_heard=10.0, now=20.0)
    omits = bytes(2)
    few = SEEK_PUT_OFF_SEEKERS_MAX

    def put_off_by(seekers: list[int], now: float) -> float:
        seek.sent(now)
        assert seek.due is not None
        seek.due = now + SEEK_MIN_S
        for k, seeker in enumerate(seekers, start=1):
            seek.heard(omits, now + 0.2 * k, others[seeker])
        return seek.due - now

    many_frames_few_seekers = [k % few for k in range(3 * few)]  # 0.2 s apart: 3 s
    assert put_off_by(many_frames_few_seekers, 21.0) <= SEEK_PUT_OFF_MAX_S + 1e-9
    one_more = [*range(few), few, 0, 1, 0, 1, 0, 1, 0, 1]
    assert put_off_by(one_more, 30.0) >= 0.2 * len(one_more) + SEEK_MIN_S  # lifted
    later = 30.0 + SEEK_SEEKERS_WINDOW_S + 1.0
    assert put_off_by([0, 1] * 10, later) <= SEEK_PUT_OFF_MAX_S + 1e-9  # two seekers now


@pytest.mark.parametrize("place", range(SEEK_PUT_OFF_RANK_MAX + 2))
def test_in_a_dense_neighbourhood_the_first_ranked_keep_the_put_off_bound(place: int) -> None:
    """``Seek`` alone, hand-set time, the loss fresh, every other participant of the bundle
    (14, more than SEEK_PUT_OFF_SEEKERS_MAX) heard seeking: the drone whose keyed hash for
    the sought peer ranks among the first SEEK_PUT_OFF_RANK_MAX keeps the bound, the next
    ones do not (each frame puts their seek a full period off)."""
    by_rank = _by_rank(make_bundle(UNIT_N))
    seek, others = _seek_as(by_rank[place], 3, last_heard=10.0, now=20.0)
    assert len(others) > SEEK_PUT_OFF_SEEKERS_MAX
    seek.sent(21.0)
    assert seek.due is not None
    seek.due = 21.0 + SEEK_MIN_S
    frames = others * 2  # every seeker twice, 0.1 s apart: 2.8 s
    for k, seeker in enumerate(frames, start=1):
        seek.heard(bytes(2), 21.0 + 0.1 * k, seeker)
    if place < SEEK_PUT_OFF_RANK_MAX:
        assert seek.due - 21.0 <= SEEK_PUT_OFF_MAX_S + 1e-9
    else:
        assert seek.due - 21.0 >= 0.1 * len(frames) + SEEK_MIN_S


def test_the_rank_orders_the_drones_differently_for_each_sought_peer() -> None:
    """``_pair_rank`` (a function of the two GUID prefixes, which every drone reads from the
    same bundle) orders the participants differently for each sought peer, and puts
    different drones first: a side that lost many peers spreads the bound over many of its
    drones, not always the same few."""
    bundle = make_bundle(UNIT_N)
    prefixes = [p.guid_prefix.value for p in bundle.participants]

    def order(key: bytes) -> tuple[int, ...]:
        return tuple(sorted(range(UNIT_N), key=lambda i: _pair_rank(prefixes[i], key)))

    orders = {order(key) for key in prefixes}
    assert len(orders) == UNIT_N
    firsts = {ranked[0] for ranked in orders}
    assert len(firsts) > 1


def test_a_member_gone_from_a_dense_swarm_draws_about_one_seek_per_period_while_fresh() -> None:
    """The bound's cost no longer grows with N: at N = 20 every drone hears the 18 others that
    lost the same peer, more than SEEK_PUT_OFF_SEEKERS_MAX, so the suppression is whole from
    the start (about one seek per period among them all), where the bound everywhere drew
    ~N / SEEK_PUT_OFF_MAX_S a second while the loss was fresh (`python -m bench.seek_cost
    --n 20`: 309 seeks in the commander's first minute on the engine before, 25 unbounded)."""
    n, gone = 20, 19
    swarm = build_swarm(n, seed=1)

    def loss(a: int, b: int) -> float:
        return 1.0 if gone in (a, b) and a != b and swarm.net.now >= T_CUT else 0.0

    swarm.net.link_loss = loss
    swarm.run_until(T_CUT)
    assert swarm.all_discovered(), "the swarm did not form before the scenario"

    def seeks() -> int:
        return sum(e.counters()["tx_kind"]["seek"] for e in swarm.engines[:gone])

    window = SEEK_PUT_OFF_FOR_S  # fresh from the gone peer's last frame (before T_CUT)
    swarm.run_until(T_CUT + window)
    assert seeks() > 0, "nobody lost the gone drone"
    assert seeks() <= window / SEEK_MIN_S + 1, seeks()
