"""Many real engines on the in-memory network (virtual time, seeded loss)."""

from __future__ import annotations

from collections import Counter

import pytest
from swarmd_lab.memnet import Channel
from swarmd_lab.testing import build_swarm

from swarmd.discovery import EngineConfig, Phase
from swarmd.discovery.events import PeerDiscovered, PeerLost


def discovery_frames(swarm_engines: list) -> int:  # type: ignore[type-arg]
    return sum(
        e.counters()["tx_kind"]["announce"] + e.counters()["tx_kind"]["reply"]
        for e in swarm_engines
    )


def test_ten_engines_adaptive_clean_channel_meet_within_one_second_with_about_2n_frames() -> None:
    swarm = build_swarm(10, seed=1)
    swarm.run_until(60.0)
    assert swarm.full_at is not None and swarm.full_at < 1.0
    assert all(e.phase == Phase.STEADY for e in swarm.engines)
    assert all(len(e.lists_me_names()) == 9 for e in swarm.engines)
    # N announcements + at most N acks; stock Cyclone: 4 replies per new peer = 360
    assert discovery_frames(swarm.engines) <= 2 * 10
    assert swarm.lost == 0


def test_ten_engines_paper_mode_meet_within_tmax_plus_two_seconds() -> None:
    swarm = build_swarm(10, seed=2, config=EngineConfig(mode="paper"), q=0.0)
    swarm.run_until(60.0)
    assert swarm.full_at is not None and swarm.full_at <= 20.0 + 2.0
    assert all(e.phase == Phase.STEADY for e in swarm.engines)
    assert all(e.passive_timer_s is not None and e.passive_timer_s <= 20.0 for e in swarm.engines)


def test_passive_nodes_send_no_multicast_before_their_timer() -> None:
    swarm = build_swarm(10, seed=3, config=EngineConfig(mode="paper"), q=0.5)
    swarm.run_until(30.0)
    for t in swarm.net.transmissions:
        engine = swarm.engines[t.node]
        timer = engine.passive_timer_s
        assert timer is not None
        if t.time < timer:
            assert not t.multicast, f"uav{t.node} multicast at {t.time} while passive"


def test_fifty_engines_converge_on_a_lossy_duplicating_network() -> None:
    channel = Channel(loss=0.1, duplicate=0.05, delay_s=0.0005, jitter_s=0.003)
    swarm = build_swarm(50, seed=4, channel=channel, q=0.5)
    swarm.run_until(30.0)
    assert swarm.all_met_at is not None and swarm.all_met_at < 15.0
    # discovery frames grow with N, not N^2: a few per node even at 10 % loss
    assert discovery_frames(swarm.engines) <= 6 * 50
    # at the end nearly every pair is current (a lease may lapse after 3 lost renewals)
    assert swarm.pairs >= 0.99 * 50 * 49
    assert swarm.net.stats.lost > 0 and swarm.net.stats.duplicated > 0


def test_lease_expiry_and_rejoin_without_a_storm() -> None:
    swarm = build_swarm(6, seed=5)
    swarm.run_until(10.0)
    assert swarm.all_discovered()
    swarm.net.isolate(5)
    swarm.run_until(40.0)
    lost = [(t, e) for i in range(5) for t, e in swarm.events[i] if isinstance(e, PeerLost)]
    assert sorted(e.name for _, e in lost) == ["uav5"] * 5
    assert all(e.reason == "lease" and 10.0 < t <= 30.0 for t, e in lost)
    before = len(swarm.net.transmissions)
    swarm.net.isolate(5, False)
    swarm.run_until(60.0)
    assert swarm.all_discovered()
    back = [
        t
        for i in range(5)
        for t, e in swarm.events[i]
        if isinstance(e, PeerDiscovered) and e.name == "uav5" and t > 40.0
    ]
    assert len(back) == 5
    # 20 s of renewals for 6 nodes (~2 each) plus at most one answer per pair
    kinds = Counter(t.multicast for t in swarm.net.transmissions[before:])
    assert kinds[False] <= 2 * 5
    assert kinds[True] <= 6 * 3


def test_shutdown_is_seen_by_every_peer_at_once() -> None:
    swarm = build_swarm(5, seed=6)
    swarm.run_until(5.0)
    leaving = swarm.engines[2]
    swarm.net.call_at(5.0, lambda now: leaving.shutdown(now))
    swarm.net.call_at(5.0, lambda now: swarm.net.poke(2))
    swarm.run_until(5.1)
    for i in (0, 1, 3, 4):
        lost = [(t, e) for t, e in swarm.events[i] if isinstance(e, PeerLost)]
        assert [(e.name, e.reason) for _, e in lost] == [("uav2", "disposed")]
        assert lost[0][0] < 5.01
    assert leaving.phase == Phase.STOPPED


@pytest.mark.parametrize("mode", ["adaptive", "paper"])
def test_runs_are_reproducible_from_the_seed(mode: str) -> None:
    def trace() -> list[tuple[float, int, tuple[str, int]]]:
        swarm = build_swarm(8, seed=9, config=EngineConfig(mode=mode), channel=Channel(loss=0.2))  # type: ignore[arg-type]
        swarm.run_until(20.0)
        return [(t.time, t.node, t.target) for t in swarm.net.transmissions]

    assert trace() == trace()
