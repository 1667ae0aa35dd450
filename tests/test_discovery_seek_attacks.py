"""Attacks on this session's seek and rejoin paths (issue 20; docs/security.md, "Seek and
rejoin paths").

Two inputs were added or changed: a lost peer heard again now freshens the seek's put-off
bound (``Seek.returned``), and the multicast such a return pulls in also goes directed, a
re-ack gap later, to each peer found again not listing us by then
(``Debts.take_late_copies``). Both run only on a DATA(p) that passed its signature and
replay window, so an outsider's forgery never reaches them; these tests drive the two other
attackers on MemNet, virtual time, authenticated engines:

* a sniffer that replays a lost peer's captured DATA(p)s (attacker 1 of the threat model);
* a relay that forwards a lost peer's genuine, fresh DATA(p)s from its own address (the
  "relay a genuine datagram" of attacker 1: the frames are the peer's, the address is not).

The captured member (attacker 2) leaving and returning is
``tests/test_discovery_found_again.py::test_a_captured_member_leaving_and_returning_draws_at_most_one_copy_per_reack_gap``.
"""

from __future__ import annotations

import pytest
from swarmd_lab.testing import ScriptedSender, Swarm, build_swarm, node_ipv4

from swarmd.discovery import seek as seek_module
from swarmd.discovery.events import PeerDiscovered
from swarmd.discovery.received import ipv4_octets
from swarmd.discovery.seek import (
    SEEK_FOR_S,
    SEEK_PUT_OFF_FOR_S,
    SEEK_PUT_OFF_MAX_S,
    SEEK_PUT_OFF_SEEKERS_MAX,
)

N = 6
GONE = N - 1  # uav5: lost for good (its frames are what the attacker captured)
MISSING = N - 2  # uav4: also lost, so a return pulls a multicast in (``PullIn.rejoined``)
HONEST = range(N - 2)
T_CUT = 30.0
# the loss is stale by then at every honest drone: the seek's put-off bound is off
T_ATTACK = T_CUT + SEEK_PUT_OFF_FOR_S + 20.0
ATTACK_FOR_S = 30.0
ATTACKER_HOST = "10.66.0.66"


class _Attacker(ScriptedSender):
    """A host on the swarm's link at ``ATTACKER_HOST``, in the SPDP group: it records every
    datagram it hears from ``victim_host`` and, from ``start`` to ``start + ATTACK_FOR_S``,
    sends what it holds to the group every ``period_s`` (bounded by the window: at most
    ``ATTACK_FOR_S / period_s`` rounds). ``fresh_only``: each datagram is sent once, the
    newest first (a relay of what it has not forwarded yet); otherwise every captured one,
    every round (a replayer)."""

    def __init__(
        self,
        group: tuple[str, int],
        victim_host: str,
        *,
        start: float,
        period_s: float,
        fresh_only: bool,
    ) -> None:
        super().__init__(start)
        self._group = group
        self._victim = victim_host
        self._end = start + ATTACK_FOR_S
        self._period_s = period_s
        self._fresh_only = fresh_only
        self.captured: list[bytes] = []
        self._forwarded = 0
        self.sent = 0

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        if source[0] == self._victim:
            self.captured.append(data)

    def handle_timer(self, now: float) -> None:
        while self._next is not None and self._next <= now:
            if self._fresh_only:
                batch = self.captured[self._forwarded :]
                self._forwarded = len(self.captured)
            else:
                batch = list(self.captured)
            self._out += [(d, self._group) for d in batch]
            self.sent += len(batch)
            self._next += self._period_s
            if self._next > self._end:
                self._next = None


def _swarm_with_attacker(
    seed: int, *, fresh_only: bool, period_s: float
) -> tuple[Swarm, _Attacker]:
    swarm = build_swarm(N, seed=seed, authenticated=True)
    swarm.run_until(1.0)  # every engine exists: the group and ports are known
    group = swarm.engines[0].spdp_multicast
    attacker = _Attacker(
        group, node_ipv4(GONE), start=T_ATTACK, period_s=period_s, fresh_only=fresh_only
    )
    swarm.net.add(
        attacker,
        ATTACKER_HOST,
        (swarm.engines[0].metatraffic_port, group[1]),
        groups=(group,),
        source_port=swarm.engines[0].metatraffic_port,
    )
    return swarm, attacker


def _found(swarm: Swarm, observer: int, peer: int, since: float) -> list[float]:
    name = swarm.bundle.participants[peer].name
    return [
        t
        for t, e in swarm.events[observer]
        if t >= since and isinstance(e, PeerDiscovered) and e.name == name
    ]


def test_replayed_frames_of_a_lost_peer_neither_return_it_nor_freshen_the_seek() -> None:
    """A sniffer holding every DATA(p) uav5 sent before it was lost replays them all from its
    own address every second for 30 s, once the loss is stale. Each is refused as a replay
    (``auth_replayed``) before anything moves: uav5 is not found again, the seek's loss stays
    stale (``Seek.fresh_at`` unchanged: the put-off bound stays off), no directed copy is
    owed (``Debts.found_again``) and nothing is sent to the replayer's address. Without the
    replay window each replay is a return: uav5 found again, the loss fresh again (so the
    bound on for another ``SEEK_PUT_OFF_FOR_S``), and a directed copy owed."""
    swarm, attacker = _swarm_with_attacker(1, fresh_only=False, period_s=1.0)
    swarm.run_until(T_CUT)
    assert swarm.all_discovered(), "the swarm did not form before the attack"
    swarm.net.isolate(GONE)
    swarm.net.isolate(MISSING)
    swarm.run_until(T_ATTACK)
    assert attacker.captured, "the sniffer heard nothing of uav5"
    engines = [swarm.engines[i] for i in HONEST]
    fresh_before = [e._seek.fresh_at for e in engines]
    assert all(T_ATTACK - f >= SEEK_PUT_OFF_FOR_S for f in fresh_before)  # stale
    replayed_before = [e.counters()["dropped"]["auth_replayed"] for e in engines]
    start = len(swarm.net.transmissions)
    swarm.run_until(T_ATTACK + ATTACK_FOR_S + 1.0)
    assert attacker.sent >= len(attacker.captured) * ATTACK_FOR_S  # the attack ran
    for i, engine in zip(HONEST, engines, strict=True):
        assert _found(swarm, i, GONE, T_CUT) == [], i
        assert engine._seek.fresh_at == fresh_before[i], i
        assert not engine._debts.found_again, i
        replayed = engine.counters()["dropped"]["auth_replayed"] - replayed_before[i]
        assert replayed >= attacker.sent // 2, (i, replayed, attacker.sent)
    sent = swarm.net.transmissions[start:]
    assert not [x for x in sent if x.node in HONEST and x.target[0] == ATTACKER_HOST]
    assert not [x for x in sent if x.node in HONEST and x.target[0] == node_ipv4(GONE)]


def test_a_relayed_genuine_frame_draws_the_copy_to_the_signed_locator_not_the_relay() -> None:
    """uav5 is alive but out of the others' range; a relay in range of both forwards uav5's
    genuine, fresh DATA(p)s from the relay's own address (a wormhole). They are uav5's: the
    others find it again, as they would through any repeater, and the directed copy of the
    pulled-in multicast (``Debts.take_late_copies``) goes where uav5's signed DATA(p) says
    (its metatraffic locator), never to the UDP source, so the relay cannot turn the copies
    onto an address of its choice. At most one copy per re-ack gap per drone, as every
    cue-driven directed frame."""
    swarm, attacker = _swarm_with_attacker(2, fresh_only=True, period_s=0.5)
    net = swarm.net
    attacker_id = N

    def loss(a: int, b: int) -> float:
        if net.now < T_CUT or attacker_id in (a, b):
            return 0.0
        return 1.0 if GONE in (a, b) and a != b else 0.0

    net.link_loss = loss
    swarm.run_until(T_CUT)
    assert swarm.all_discovered(), "the swarm did not form before the attack"
    net.isolate(MISSING)  # somebody else is still missing: a return pulls a multicast in
    swarm.run_until(T_ATTACK)
    attacker.captured.clear()  # relay only what uav5 sends from now on: fresh frames
    start = len(net.transmissions)
    swarm.run_until(T_ATTACK + ATTACK_FOR_S + 1.0)
    assert attacker.sent > 0
    assert all(_found(swarm, i, GONE, T_ATTACK) for i in HONEST)  # the relay's frames took
    sent = net.transmissions[start:]
    assert not [x for x in sent if x.node in HONEST and x.target[0] == ATTACKER_HOST]
    copies = [
        x for x in sent if x.node in HONEST and not x.multicast and x.target[0] == node_ipv4(GONE)
    ]
    assert copies  # the copies were sent: to uav5's signed locator
    gap = swarm.engines[0]._config.retransmit_min_gap_s
    for i in HONEST:
        mine = sorted(x.time for x in copies if x.node == i)
        assert all(b - a >= gap - 1e-9 for a, b in zip(mine, mine[1:], strict=False)), i


def test_a_peer_back_every_minute_does_not_extend_the_seek_for_one_gone_for_good() -> None:
    """uav4 (a captured member, or a real drone whose frames a relay lets across) is back
    for 1.5 s every minute, so every loss of it is fresh and every return freshens the
    seek again (``Seek.returned``): the others seek it at the put-off bound's pace for as
    long as it goes on (``bench/seek_return_cost.py`` measures what that costs per hour).
    It cannot extend what uav5, gone for good, costs: uav5 is sought ``SEEK_FOR_S`` from its
    own last frame and then no more, whatever the freshness (``Seek._prune``)."""
    swarm = build_swarm(N, seed=3, authenticated=True)
    net = swarm.net
    back_every_s, open_s = 60.0, 1.5

    def loss(a: int, b: int) -> float:
        if a == b or net.now < T_CUT:
            return 0.0
        if GONE in (a, b):
            return 1.0
        if MISSING in (a, b):  # uav4: in range for open_s of every back_every_s
            return 0.0 if (net.now - T_CUT) % back_every_s < open_s else 1.0
        return 0.0

    net.link_loss = loss
    swarm.run_until(T_CUT)
    assert swarm.all_discovered(), "the swarm did not form before the scenario"
    end = T_CUT + SEEK_FOR_S + 2 * back_every_s  # bounded: 12 minutes of virtual time
    swarm.run_until(end)
    for i in HONEST:
        engine = swarm.engines[i]
        gone = engine._peers[GONE]
        assert gone.last_heard is not None and gone.last_heard <= T_CUT
        assert GONE not in engine._seek.sought, i  # sought SEEK_FOR_S, then no more
        assert len(_found(swarm, i, MISSING, T_CUT)) >= 10, i  # uav4 did come back
        assert end - engine._seek.fresh_at < back_every_s, i  # and kept the loss fresh


# The seekers count (``Seek.seekers``, ``SEEK_PUT_OFF_SEEKERS_MAX``): a drone keeps the seek's
# put-off bound only while it heard at most that many seekers of the peers it seeks. A forger
# that made it count more would lift the bound where it matters, at the edge of a swarm strung
# out over more than one radio range (tests/test_discovery_seek_reach.py): the edge drone's
# seeks then wait on frames that cannot reach, and the edge pair on a race.
SIDE = 6  # side A: uav0-uav5, side B: uav6-uav11; uav5 is A's edge drone
EDGE = SIDE - 1
# uav12..: in range of both sides, they lose nobody (their frames list side B: no seekers);
# one more than the seekers count may hold besides the edge drone's five honest ones
BRIDGES = tuple(range(2 * SIDE, 2 * SIDE + SEEK_PUT_OFF_SEEKERS_MAX - (SIDE - 1) + 1))
FORGE_T = T_CUT + 15.0  # every lease across the cut has ended: the seeks are under way
FORGE_FOR_S = 15.0
FORGE_PERIOD_S = 0.25


class _Forger(ScriptedSender):
    """A host in range of everyone, without a key: it records side A's frames (which omit
    side B, lost to them) and, from ``FORGE_T`` for ``FORGE_FOR_S``, resends the latest one
    every ``FORGE_PERIOD_S`` under each bridge's GUID prefix in turn (the prefix rewritten
    wherever it occurs: the header's and the DATA(p)'s), so each looks like a bridge's frame
    that seeks side B (at most ``FORGE_FOR_S / FORGE_PERIOD_S`` rounds), its locators
    rewritten to the bridge's address (the bundle pins each drone's: any other is refused
    whole, keyed or not)."""

    def __init__(
        self,
        group: tuple[str, int],
        side_a: dict[str, bytes],
        bridges: list[bytes],
        bridge_hosts: list[str],
    ) -> None:
        super().__init__(FORGE_T)
        self._group = group
        self._side_a = side_a  # host -> its GUID prefix octets
        self._bridges = bridges
        # a UDPv4 locator's address field: 12 zero octets, then the IPv4 address
        self._bridge_addresses = [bytes(12) + ipv4_octets(h) for h in bridge_hosts]
        self._latest_address = b""
        self._latest: tuple[bytes, bytes] | None = None  # (datagram, its sender's prefix)
        self.sent = 0

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        prefix = self._side_a.get(source[0])
        if prefix is not None and data[8:20] == prefix:
            self._latest = (data, prefix)
            self._latest_address = bytes(12) + ipv4_octets(source[0])

    def handle_timer(self, now: float) -> None:
        while self._next is not None and self._next <= now:
            if self._latest is not None:
                data, prefix = self._latest
                k = self.sent % len(self._bridges)
                forged = data.replace(prefix, self._bridges[k])
                forged = forged.replace(self._latest_address, self._bridge_addresses[k])
                self._out.append((forged, self._group))
                self.sent += 1
            self._next += FORGE_PERIOD_S
            if self._next > FORGE_T + FORGE_FOR_S:
                self._next = None


def _forged_edge(*, authenticated: bool) -> tuple[Swarm, _Forger, list[float]]:
    """Two sides cut apart at ``T_CUT`` for good, two bridges in range of both, the forger in
    range of all; the edge drone's multicast gaps while the forgery runs."""
    n = 2 * SIDE + len(BRIDGES)
    swarm = build_swarm(n, seed=4, authenticated=authenticated)
    net = swarm.net

    def loss(a: int, b: int) -> float:
        if net.now < T_CUT or a >= 2 * SIDE or b >= 2 * SIDE:  # a bridge or the forger
            return 0.0
        return 0.0 if (a < SIDE) == (b < SIDE) else 1.0

    net.link_loss = loss
    swarm.run_until(1.0)
    group = swarm.engines[0].spdp_multicast
    prefixes = [p.guid_prefix.value for p in swarm.bundle.participants]
    forger = _Forger(
        group,
        {node_ipv4(i): prefixes[i] for i in range(SIDE) if i != EDGE},
        [prefixes[b] for b in BRIDGES],
        [node_ipv4(b) for b in BRIDGES],
    )
    net.add(
        forger,
        ATTACKER_HOST,
        (swarm.engines[0].metatraffic_port, group[1]),
        groups=(group,),
        source_port=swarm.engines[0].metatraffic_port,
    )
    swarm.run_until(T_CUT)
    assert swarm.all_discovered(), "the swarm did not form before the attack"
    swarm.run_until(FORGE_T + FORGE_FOR_S + 0.5)  # the last forged frame delivered too
    assert forger.sent >= FORGE_FOR_S / FORGE_PERIOD_S  # the forgery ran
    sent = [
        x.time
        for x in net.transmissions
        if x.node == EDGE and x.multicast and FORGE_T <= x.time < FORGE_T + FORGE_FOR_S
    ]
    edges = [FORGE_T, *sent, FORGE_T + FORGE_FOR_S]
    return swarm, forger, [b - a for a, b in zip(edges, edges[1:], strict=False)]


def test_forged_seekers_neither_count_nor_lift_the_edge_drones_put_off_bound(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Authenticated: each forged frame fails its bridge's signature and is refused before
    anything moves, so the edge drone counts only its own side's five seekers (the bridges'
    genuine frames list side B: they seek nothing) and keeps seeking at least every
    ``SEEK_PUT_OFF_MAX_S``. Unauthenticated (the control), the same frames count the bridges
    as seekers too, one more than ``SEEK_PUT_OFF_SEEKERS_MAX``, and lift the bound: the edge
    drone falls silent longer than that. The rank (``SEEK_PUT_OFF_RANK_MAX``) is off here so
    that the count alone decides: uav5 ranks first for one of side B, so the rank would keep
    its bound through the control's forgery too (a forger would need three identities that
    outrank it for every peer of side B; the rank reads the same table, so a refused frame
    moves it no more than the count)."""
    monkeypatch.setattr(seek_module, "SEEK_PUT_OFF_RANK_MAX", 0)
    swarm, forger, gaps = _forged_edge(authenticated=True)
    seek = swarm.engines[EDGE]._seek
    assert set(seek.seekers) <= set(range(SIDE)) - {EDGE}, sorted(seek.seekers)
    assert len(seek.seekers) <= SEEK_PUT_OFF_SEEKERS_MAX
    dropped = swarm.engines[EDGE].counters()["dropped"]
    assert dropped["auth_bad_tag"] >= forger.sent, dict(dropped)
    assert max(gaps) <= SEEK_PUT_OFF_MAX_S + 1e-9, [round(g, 2) for g in gaps]

    swarm, forger, gaps = _forged_edge(authenticated=False)
    seek = swarm.engines[EDGE]._seek
    assert set(BRIDGES) <= set(seek.seekers), sorted(seek.seekers)
    assert max(gaps) > SEEK_PUT_OFF_MAX_S, [round(g, 2) for g in gaps]
