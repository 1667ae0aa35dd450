"""Vouching and liveliness from authenticated traffic (docs/discovery.md, "Vouching").

Virtual time on MemNet: uav0 is the bundle's commander; every member's 1 Hz readiness
reaches it through ``peer_traffic`` (what the daemon feeds from verified user data), lost
independently with the same probability as the channel's datagrams.
"""

from __future__ import annotations

import random
from dataclasses import replace

import pytest
from swarmd_lab.memnet import Channel
from swarmd_lab.testing import Swarm, build_swarm, make_bundle, peer_datagram

from swarmd.discovery import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import PeerLost
from swarmd.discovery.seek import SEEK_PUT_OFF_MAX_S
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.spdp import Vouch, decode_spdp, encode_spdp
from swarmd.rtps.types import Duration

COMMANDER = 0
# MemNet's default one-way delay is 0.5 ms: a lease runs from a frame's arrival
ARRIVAL = 0.001


def feed_readiness(swarm: Swarm, *, loss: float, seed: int, until: float) -> dict[int, float]:
    """Each started member reports to the commander every second (its data plane's
    readiness), lost with probability ``loss``; an isolated node's reports never arrive.
    Returns the time of each member's last report taken, filled in as the run goes."""
    rng = random.Random(seed)  # noqa: S311 - seeded simulation
    net = swarm.net
    taken: dict[int, float] = {}

    def tick(now: float) -> None:
        nodes = len(swarm.engines)
        if nodes > COMMANDER and not net._nodes[COMMANDER].isolated:
            commander = swarm.engines[COMMANDER]
            for m in range(1, nodes):
                if net._nodes[m].isolated or rng.random() < loss:
                    continue
                commander.peer_traffic(swarm.bundle.participants[m].guid_prefix, now)
                taken[m] = now
            net.poke(COMMANDER)
        if now + 1.0 <= until:
            net.call_at(now + 1.0, tick)

    net.call_at(1.0, tick)
    return taken


def frames(swarm: Swarm, start: float = 0.0, end: float = float("inf")) -> int:
    return sum(1 for t in swarm.net.transmissions if start <= t.time < end)


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_ten_drones_send_at_most_50_discovery_frames_in_the_first_minute(seed: int) -> None:
    swarm = build_swarm(10, seed=seed, start_times=[0.1 * i for i in range(10)])
    feed_readiness(swarm, loss=0.0, seed=seed, until=60.0)
    swarm.run_until(60.0)
    assert swarm.all_discovered() and swarm.lost == 0
    # ~2N to meet, then the commander's vouches (one every ~5 s); members stay silent
    assert frames(swarm, 0.0, 60.0) <= 50
    members = [e.counters()["tx_kind"]["renewal"] for e in swarm.engines[1:]]
    assert sum(members) == 0


def test_authenticated_ten_drones_stay_within_50_frames() -> None:
    # the vouch rides inside the signed DATA(p): same count with Ed25519 on every frame
    swarm = build_swarm(10, seed=7, authenticated=True)
    feed_readiness(swarm, loss=0.0, seed=7, until=60.0)
    swarm.run_until(60.0)
    assert swarm.all_discovered() and swarm.lost == 0
    assert frames(swarm, 0.0, 60.0) <= 50
    dropped = sum(sum(e.counters()["dropped"].values()) for e in swarm.engines)
    assert dropped == sum(e.counters()["dropped"].get("own", 0) for e in swarm.engines)


def test_without_readiness_members_renew_as_before() -> None:
    # the same swarm with nobody feeding user data: the vouches list only members heard by
    # SPDP in the last 2.5 s, so members mostly renew themselves (the old count, ~80)
    swarm = build_swarm(10, seed=1)
    swarm.run_until(60.0)
    assert swarm.lost == 0
    assert frames(swarm, 0.0, 60.0) > 50


@pytest.mark.parametrize("seed", [11, 12, 13, 14, 15, 16])
def test_a_live_peer_is_never_lost_at_five_percent_loss(seed: int) -> None:
    # 5 % independent loss on every datagram and every readiness report, for 10 minutes
    # (renewals alone, vouch=False, lose 8 leases over these 6 runs: test below)
    swarm = build_swarm(10, seed=seed, channel=Channel(loss=0.05), q=0.5)
    feed_readiness(swarm, loss=0.05, seed=seed, until=600.0)
    swarm.run_until(600.0)
    assert swarm.lost == 0
    assert swarm.all_discovered()


def test_vouching_loses_fewer_live_peers_than_renewals_alone_at_ten_percent_loss() -> None:
    lost = {}
    for vouch in (True, False):
        lost[vouch] = 0
        for seed in (11, 12, 13):
            swarm = build_swarm(
                10, seed=seed, channel=Channel(loss=0.1), q=0.5, config=EngineConfig(vouch=vouch)
            )
            feed_readiness(swarm, loss=0.1, seed=seed, until=600.0)
            swarm.run_until(600.0)
            lost[vouch] += swarm.lost
    # renewals alone: n(Q = 0.5) = 3 per lease, p^3 per pair and lease; vouches: p^4
    assert lost[True] * 5 <= lost[False], lost


def _last_tx(swarm: Swarm, node: int, before: float) -> float:
    return max(t.time for t in swarm.net.transmissions if t.node == node and t.time < before)


def _kill_at_40(seed: int, node: int) -> tuple[Swarm, float, float]:
    """A settled 10-drone swarm whose ``node`` dies silently at 40 s, run to 120 s: the
    swarm, the death time and the node's last frame (SPDP sent or readiness taken)."""
    swarm = build_swarm(10, seed=seed)
    taken = feed_readiness(swarm, loss=0.0, seed=seed, until=120.0)
    swarm.run_until(40.0)
    assert swarm.all_discovered()
    swarm.net.isolate(node)  # dies without a word: no SPDP, no readiness from here on
    died = swarm.net.now
    last_frame = max(_last_tx(swarm, node, died), taken.get(node, 0.0))
    swarm.run_until(120.0)
    return swarm, died, last_frame


def _lost_after(swarm: Swarm, died: float, dead: int) -> dict[tuple[int, str], float]:
    """(observer, peer lost) -> when, after ``died``, among the survivors."""
    return {
        (i, e.name): t
        for i in range(swarm.size)
        if i != dead
        for t, e in swarm.events[i]
        if isinstance(e, PeerLost) and t > died
    }


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_a_dead_member_is_lost_at_most_one_lease_after_its_last_frame(seed: int) -> None:
    swarm, died, last_frame = _kill_at_40(seed, 5)
    lost = _lost_after(swarm, died, 5)
    assert sorted(lost) == [(i, "uav5") for i in range(10) if i != 5]  # everyone, only it
    # no later than before vouching: lease (20 s) after its last frame
    assert all(t <= last_frame + ARRIVAL + 20.0 for t in lost.values()), (last_frame, lost)
    # and not absurdly early: the vouch counts from window + transit before it arrived,
    # and the last vouch listing it left at most one vouch period (~5.7 s) before that
    assert all(t >= last_frame + 20.0 - 2.5 - 0.5 - 6.0 for t in lost.values()), lost


@pytest.mark.parametrize("seed", [31, 32, 33])
def test_members_fall_back_to_renewals_when_the_commander_dies(seed: int) -> None:
    swarm, died, last_frame = _kill_at_40(seed, COMMANDER)
    lost = _lost_after(swarm, died, COMMANDER)
    # the members lose the commander within a lease of its last frame, and nobody else
    assert sorted(lost) == [(i, "uav0") for i in range(1, 10)]
    assert all(t <= last_frame + ARRIVAL + 20.0 for t in lost.values()), (last_frame, lost)

    # silent while vouched, then they renew again, each about every 10 s (Q = 1) for 80 s,
    # and seek the lost commander (seek.py) from its loss on: while the loss is fresh (until
    # SEEK_PUT_OFF_FOR_S after its last frame) each member at least every
    # SEEK_PUT_OFF_MAX_S, suppressed in between (171-176 seeks in all, seeds 31-33), not one
    # per member per period (~9 x 63 / 1.0); after it, one per period among them all
    # (tests/test_discovery_seek_reach.py)
    def member_multicasts(start: float, end: float) -> int:
        return sum(
            1
            for t in swarm.net.transmissions
            if t.node != COMMANDER and t.multicast and start < t.time <= end
        )

    seeks = sum(e.counters()["tx_kind"]["seek"] for e in swarm.engines[1:])
    assert seeks <= 9 * ((120.0 - min(lost.values())) / SEEK_PUT_OFF_MAX_S + 1)
    assert member_multicasts(10.0, died) == 0
    # every multicast restarts the renewal: a member seeking every ~2.4 s renews by its seeks
    assert 9 * 6 <= member_multicasts(died, 120.0)
    assert member_multicasts(died, 120.0) - seeks <= 9 * 10


def test_paper_mode_neither_vouches_nor_takes_traffic_as_liveliness() -> None:
    swarm = build_swarm(6, seed=41, config=EngineConfig(mode="paper"), q=1.0)
    feed_readiness(swarm, loss=0.0, seed=41, until=60.0)
    swarm.run_until(60.0)
    commander_frames = [t for t in swarm.net.transmissions if t.node == COMMANDER]
    assert commander_frames
    member_renewals = [e.counters()["tx_kind"]["renewal"] for e in swarm.engines[1:]]
    assert all(r >= 4 for r in member_renewals)  # every ~10 s, as the paper's scheme
    assert swarm.engines[COMMANDER].status(60.0)["timing"]["renewal_period_s"] == 10.0


def _vouching_frame(bundle_n: int, sender: int, vouched: tuple[int, ...], sn: int) -> bytes:
    """A DATA(p) of ``sender`` carrying a vouch for ``vouched`` (window 2.5 s)."""
    bundle = make_bundle(bundle_n)
    plain = peer_datagram(bundle, sender, heard=tuple(range(bundle_n)), sequence_number=sn)
    _, samples = decode_spdp(plain)
    part = samples[0].participant  # type: ignore[union-attr]
    bitmap = bytearray((bundle_n + 7) // 8)
    for i in vouched:
        bitmap[i // 8] |= 1 << (i % 8)
    part = replace(
        part, vouched=Vouch(2500, bytes(bitmap)), lease_duration=Duration.from_seconds(20)
    )
    return encode_spdp(part, sequence_number=sn, timestamp=None)


def _member_engine(bundle_n: int) -> DiscoveryEngine:
    from swarmd_lab.testing import engine_for

    return engine_for(make_bundle(bundle_n), 1, q=1.0)


def _heard_all_at_zero(n: int) -> DiscoveryEngine:
    engine = _member_engine(n)  # uav1
    for i in range(n):
        if i != 1:
            engine.receive_datagram(_vouching_frame(n, i, (), 1), (f"10.0.0.{i + 1}", 7410), 0.0)
    assert engine.peer_counts() == (n - 1, n - 1)
    return engine


def _state(engine: DiscoveryEngine, name: str) -> str:
    view = engine.peer(name)
    assert view is not None
    return view.state.name


def test_a_vouch_from_a_member_is_ignored() -> None:
    # uav3 (a captured member, say: its own key, not the commander's) vouches for uav2 at
    # 15 s; uav2's lease still ends 20 s after its own frame
    engine = _heard_all_at_zero(4)
    engine.receive_datagram(_vouching_frame(4, 3, (1, 2), 2), ("10.0.0.4", 7410), 15.0)
    engine.handle_timer(19.9)
    assert _state(engine, "uav2") == "DISCOVERED"
    engine.handle_timer(20.0)
    assert _state(engine, "uav2") == "LOST"
    assert _state(engine, "uav3") == "DISCOVERED"  # its own frame renewed only itself


def test_the_commanders_vouch_runs_from_window_and_transit_before_it_arrived() -> None:
    engine = _heard_all_at_zero(4)
    # the commander vouches for uav2 at 15 s (window 2.5 s): to 15 + 20 - 2.5 - 0.5 = 32 s
    engine.receive_datagram(_vouching_frame(4, 0, (1, 2), 2), ("10.0.0.1", 7410), 15.0)
    engine.handle_timer(31.9)
    assert _state(engine, "uav2") == "DISCOVERED"
    assert _state(engine, "uav3") == "LOST"  # not vouched: 20 s after its frame
    engine.handle_timer(32.0)
    assert _state(engine, "uav2") == "LOST"


def test_a_vouch_never_shortens_a_lease_nor_revives_a_lost_peer() -> None:
    engine = _member_engine(4)
    for i in (0, 2):
        engine.receive_datagram(_vouching_frame(4, i, (), 1), (f"10.0.0.{i + 1}", 7410), 10.0)
    # uav2's own frame at 10 s runs to 30 s; a vouch at 11 s (to 28 s) must not shorten it
    engine.receive_datagram(_vouching_frame(4, 0, (2, 3), 2), ("10.0.0.1", 7410), 11.0)
    engine.handle_timer(29.0)
    assert engine.peer("uav2").state.name == "DISCOVERED"  # type: ignore[union-attr]
    # uav3 was never discovered here: the vouch did not invent it
    assert engine.peer("uav3").state.name != "DISCOVERED"  # type: ignore[union-attr]


def test_peer_traffic_keeps_a_silent_member_alive_at_the_commander_only_while_it_flows() -> None:
    from swarmd_lab.testing import engine_for

    bundle = make_bundle(3)
    commander = engine_for(bundle, 0, q=1.0)
    commander.receive_datagram(_vouching_frame(3, 1, (), 1), ("10.0.0.2", 7410), 0.0)
    for t in range(1, 40):
        commander.peer_traffic(bundle.participants[1].guid_prefix, float(t))
        commander.handle_timer(float(t))
    assert commander.peer("uav1").state.name == "DISCOVERED"  # type: ignore[union-attr]
    commander.handle_timer(39.0 + 20.0)  # last traffic at 39 s: lost at 59 s, not later
    assert commander.peer("uav1").state.name == "LOST"  # type: ignore[union-attr]


def test_the_vouch_pid_round_trips_and_refuses_an_absurd_window() -> None:
    plain = _vouching_frame(12, 0, (1, 5, 11), 3)
    _, samples = decode_spdp(plain)
    part = samples[0].participant  # type: ignore[union-attr]
    assert part.vouched == Vouch(2500, bytes([0b00100010, 0b00001000]))
    too_long = encode_spdp(
        replace(part, vouched=Vouch(60_001, b"\x01")), sequence_number=4, timestamp=None
    )
    with pytest.raises(DecodeError):
        decode_spdp(too_long)


def _directed(frame: bytes, to: int, n: int) -> bytes:
    """``frame`` (one DATA(p)) sent directed to bundle participant ``to`` (INFO_DST)."""
    _, samples = decode_spdp(frame)
    part = samples[0].participant  # type: ignore[union-attr]
    dst = make_bundle(n).participants[to].guid_prefix
    return encode_spdp(part, sequence_number=2, timestamp=None, destination=dst)


@pytest.mark.parametrize("directed", [False, True])
def test_only_a_multicast_vouch_makes_a_member_hold_its_renewal(directed: bool) -> None:
    """A vouch naming us lets our renewal wait a full period only when the others got it
    too (a multicast). The commander's directed answer reached us alone: the others hold
    nothing from it, and a member that stopped renewing on it was probed by every peer 15 s
    later (issue 20's blackout, tests/test_flight_rejoin.py)."""
    n = 4
    engine = _heard_all_at_zero(n)
    now = 0.0
    while engine.phase.name != "STEADY" and now < 30.0:
        now = engine.get_timer() or now + 1.0
        engine.handle_timer(now)
    assert engine.phase.name == "STEADY"
    renewal = engine._renewals.timer  # noqa: SLF001 - the schedule is what is asserted
    before = renewal.deadline()
    assert before is not None
    at = now + 0.5
    frame = _vouching_frame(n, 0, (1, 2, 3), 2)
    if directed:
        frame = _directed(frame, 1, n)
    engine.receive_datagram(frame, ("10.0.0.1", 7410), at)
    after = renewal.deadline()
    assert after is not None
    if directed:
        assert after == before  # our renewal goes out as planned
    else:
        assert after >= at + 0.9 * renewal.period_s  # a full (jittered) period from the vouch
