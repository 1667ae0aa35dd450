"""Issue 20's flight scenarios on the real discovery engines, in virtual time (MemNet).

A swarm's day after take-off: half of it behind a building (split and heal), one drone at
the edge of range with its link fading in and out, a drone whose daemon restarts in the air,
the commander's link down for 30 s. Each scenario asserts the issue's targets on the engines'
own events, seeded so that a run is a pure function of its seed:

- no false losses: a peer that stayed in range is never reported lost;
- a real loss is reported within one lease of the link's loss (DDSI-RTPS 8.5.3.2: a
  participant is removed when its lease expires unrenewed);
- re-discovery within 2 s of the link's return, with at most 4 discovery frames (announce,
  reply) per rejoining pair: no storm when half a swarm comes back at once.

These are shapes on a clean channel; the same scenarios on the emulated 802.11 channel with
every stack are bench/wifi's (docs/benchmarks.md), and the real-daemon split is
tests/test_daemon_netns.py's.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterable

import pytest
from swarmd_lab.testing import Swarm, auth_for, build_swarm, node_ipv4

from swarmd.discovery import DiscoveryEngine, EngineConfig, LinkSample
from swarmd.discovery.events import PeerDiscovered, PeerLost, PeerRestarted
from swarmd.discovery.leases import PROBE_ATTEMPTS

N = 10
SEEDS = (1, 2, 3)
SEEDS_MORE = (1, 2, 3, 4, 5)  # the scenarios issue 20 found weak: two more seeds
LEASE_S = EngineConfig().lease_s
REDISCOVERY_TARGET_S = 2.0  # issue 20: from a link's return to the peer's re-discovery
FRAMES_PER_PAIR_TARGET = 4  # issue 20: discovery frames per rejoining pair during the heal


class Links:
    """Per-pair loss the scenario changes over time: ``cut`` pairs lose everything."""

    def __init__(self) -> None:
        self.cut: Callable[[int, int], bool] = lambda a, b: False

    def loss(self, src: int, dst: int) -> float:
        return 1.0 if self.cut(src, dst) else 0.0


def _swarm(seed: int, links: Links, *, authenticated: bool = False) -> Swarm:
    swarm = build_swarm(N, seed=seed, authenticated=authenticated)
    swarm.net.link_loss = links.loss
    swarm.run_until(30.0)
    assert swarm.all_discovered(), "the swarm did not form before the scenario"
    return swarm


def _name(swarm: Swarm, event: object) -> int:
    return swarm.index_of[str(getattr(event, "name", ""))]


def _events(swarm: Swarm, kind: type, since: float) -> list[tuple[int, int, float]]:
    """(observer, peer, time) of every ``kind`` event at or after ``since``."""
    return [
        (i, _name(swarm, e), t)
        for i, events in enumerate(swarm.events)
        for t, e in events
        if t >= since and isinstance(e, kind)
    ]


def _discovery_frames(engines: Iterable[DiscoveryEngine]) -> int:
    """Announcements, replies and last-chance probes sent (renewals are not counted)."""
    kinds = ("announce", "reply", "probe")
    return sum(e.counters()["tx_kind"][k] for e in engines for k in kinds)


def _probes(engines: Iterable[DiscoveryEngine]) -> int:
    return sum(e.counters()["tx_kind"]["probe"] for e in engines)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_healthy_swarm_never_probes(seed: int) -> None:
    """Renewals come at least twice per lease: no peer in range reaches its probe point."""
    swarm = _swarm(seed, Links())
    swarm.run_until(120.0)
    assert _probes(swarm.engines) == 0
    assert _events(swarm, PeerLost, 0.0) == []


@pytest.mark.parametrize("seed", SEEDS)
def test_split_and_heal(seed: int) -> None:
    """Half the swarm out of range of the other half for 60 s, then back."""
    links = Links()
    swarm = _swarm(seed, links)
    west = set(range(N // 2))
    t_cut, t_heal = 30.0, 90.0

    def split(now: float) -> None:
        links.cut = lambda a, b: (a in west) != (b in west)

    def heal(now: float) -> None:
        links.cut = lambda a, b: False

    swarm.net.call_at(t_cut, split)
    swarm.net.call_at(t_heal, heal)
    swarm.run_until(t_heal)
    # each side probes each peer it lost at most PROBE_ATTEMPTS times, then lets it go
    assert 0 < _probes(swarm.engines) <= PROBE_ATTEMPTS * len(crossing_pairs(west))
    frames_at_heal = _discovery_frames(swarm.engines)
    swarm.run_until(t_heal + 30.0)

    crossing = crossing_pairs(west)
    lost = _events(swarm, PeerLost, t_cut)
    assert {(a, b) for a, b, _ in lost} == crossing, "a peer on the same side was lost"
    assert all(t - t_cut <= LEASE_S for _, _, t in lost)
    back = {(a, b): t for a, b, t in _events(swarm, PeerDiscovered, t_heal)}
    assert set(back) == crossing
    assert max(back.values()) - t_heal <= REDISCOVERY_TARGET_S
    heal_frames = _discovery_frames(swarm.engines) - frames_at_heal
    assert heal_frames <= FRAMES_PER_PAIR_TARGET * len(crossing) // 2  # per unordered pair
    assert swarm.all_discovered()


def crossing_pairs(west: set[int]) -> set[tuple[int, int]]:
    return {(a, b) for a in range(N) for b in range(N) if (a in west) != (b in west)}


def _fade(seed: int, edge: int) -> Swarm:
    """One drone's link to everyone swings in and out every 3 s for two minutes (RSSI
    across the edge of range); its own link monitor reads the quality as it swings."""
    links = Links()
    swarm = _swarm(seed, links)
    t0, t_end, half_period = FADE_START_S, FADE_START_S + 120.0, 3.0
    fading = {"out": False}

    def swing(now: float) -> None:
        fading["out"] = not fading["out"]
        q = 0.0 if fading["out"] else 0.4
        swarm.engines[edge].update_link_quality(LinkSample(q=q, source="static"), now)
        swarm.net.poke(edge)
        if now + half_period < t_end:
            swarm.net.call_at(now + half_period, swing)

    links.cut = lambda a, b: fading["out"] and edge in (a, b)
    swarm.net.call_at(t0, swing)
    swarm.run_until(t_end + 30.0)
    return swarm


FADE_START_S = 30.0


@pytest.mark.parametrize("seed", SEEDS)
def test_fade_costs_the_drones_in_range_nothing(seed: int) -> None:
    """Nobody loses a peer that never left while one drone fades in and out."""
    edge = N - 1
    swarm = _fade(seed, edge)
    lost = _events(swarm, PeerLost, FADE_START_S)
    assert [(a, b) for a, b, _ in lost if edge not in (a, b)] == []
    assert swarm.all_discovered()


@pytest.mark.parametrize("seed", SEEDS_MORE)
def test_a_drone_out_of_range_3_s_at_a_time_is_never_lost(seed: int) -> None:
    """Outages of 3 s are far shorter than the 20 s lease: the fading drone and its peers
    should keep each other throughout (the paper's network awareness, section 3.2: the
    renewal rate follows the link quality)."""
    edge = N - 1
    swarm = _fade(seed, edge)
    assert _events(swarm, PeerLost, FADE_START_S) == []


@pytest.mark.parametrize(
    "seed",
    SEEDS_MORE,
)
def test_commander_blackout(seed: int) -> None:
    """The commander's link is down for 30 s, longer than a lease: every member loses it
    (and only it) within a lease, and finds it again within 2 s of its return."""
    links = Links()
    swarm = _swarm(seed, links)
    commander = 0
    t_cut, t_back = 30.0, 60.0
    swarm.net.call_at(t_cut, lambda now: swarm.net.isolate(commander))
    swarm.net.call_at(t_back, lambda now: swarm.net.isolate(commander, False))
    swarm.run_until(t_back + 20.0)

    lost = _events(swarm, PeerLost, t_cut)
    expected = {(m, commander) for m in range(1, N)} | {(commander, m) for m in range(1, N)}
    assert {(a, b) for a, b, _ in lost} == expected
    assert all(t - t_cut <= LEASE_S for _, _, t in lost)
    back = {(a, b): t for a, b, t in _events(swarm, PeerDiscovered, t_back)}
    assert set(back) == expected
    assert max(back.values()) - t_back <= REDISCOVERY_TARGET_S


@pytest.mark.parametrize("seed", SEEDS)
def test_reboot_in_the_air(seed: int) -> None:
    """A member's daemon restarts mid-flight with a new boot epoch (its state dir kept:
    the epoch advances as swarmd's state file makes it). Its peers see a restart, not a
    loss, and it finds every peer again within 2 s; nobody else loses anyone."""
    links = Links()
    swarm = _swarm(seed, links, authenticated=True)
    member = 4
    t_reboot = 40.0
    participant = swarm.bundle.participants[member]

    def reboot(now: float) -> None:
        engine = DiscoveryEngine(
            swarm.bundle,
            participant.name,
            config=EngineConfig(),
            rng=random.Random(seed * 1000 + member),  # noqa: S311 - seeded on purpose
            now=now,
            local_ipv4=node_ipv4(participant.index),
            link=LinkSample(q=1.0, source="static"),
            auth=auth_for(swarm.bundle, member, epoch=2, now=now),
        )
        swarm.engines[member] = engine
        swarm.net.replace(member, engine)

    swarm.net.call_at(t_reboot, reboot)
    swarm.run_until(t_reboot + 30.0)

    assert _events(swarm, PeerLost, t_reboot) == []
    restarted = _events(swarm, PeerRestarted, t_reboot)
    assert {(a, b) for a, b, _ in restarted} == {(o, member) for o in range(N) if o != member}
    found = [t for a, _, t in _events(swarm, PeerDiscovered, t_reboot) if a == member]
    assert len(found) == N - 1
    assert max(found) - t_reboot <= REDISCOVERY_TARGET_S
