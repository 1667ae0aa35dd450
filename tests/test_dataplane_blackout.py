"""The commander's blackout (issue 20) on virtual time: readiness after the return.

The shape of the ns-3 scenario (``bench/wifi/flight.py`` ``blackout``): the commander is cut
off from every member for 30 s (MemNet ``isolate``), both sides' leases end (discovery,
played by the test as the daemon reports it: ``peer_down`` 20 s after the cut), then it is
back. As on the channel, each member re-discovers the commander first (it heard the
commander's multicast) and the commander re-discovers each member a rejoin delay later (its
answer, U(0, N / 50 s): 0.004-0.40 s measured; docs/benchmarks.md, "Where the blackout's
missing readiness goes"). The member's report pulled in at its re-discovery reached a
commander that still had it down; it was dropped, and the first report counted came a
readiness period later. The bound: once both sides have each other up, the member's report
is counted within the network's delay (2-12 ms here), not a period later
(``swarmd/dataplane/early.py``).

Also the trust boundary of that hold: a forged or replayed datagram held while its
claimed sender is down moves nothing when the sender comes up, and the table is capped.
"""

from __future__ import annotations

import random
from functools import partial

from swarmd.auth.freshness import Freshness
from swarmd.dataplane.early import EARLY_HOLD_S, MAX_EARLY_PER_PEER
from swarmd.dataplane.events import PacketDropped, ReadinessReceived
from swarmd.dataplane.plane import MAX_DATAGRAM_BYTES, DataPlane
from swarmd.dataplane.seal import seal, user_data_key
from swarmd.dataplane.types import Readiness, encode_sample
from swarmd.rtps.message import Data, Header, encode_message
from swarmd.rtps.types import PROTOCOLVERSION_SWARMD, VENDORID_SWARMD
from swarmd.swarm.core import SwarmSettings
from tests.test_dataplane_plane import BUNDLE, LEAD, M1, READY_R, READY_W, drain, from_peer
from tests.test_dataplane_swarm import address_of, keyring, make_plane
from tests.test_swarm_core import Swarm

PERIOD_S = 1.0  # the members' readiness period (the bundle's 1 Hz)
NET_DELAY_S = 0.012  # the test channel's delay + jitter bound (Swarm: 2 ms + U(0, 10 ms))
LEASE_S = 20.0
BLACKOUT_S = 30.0


def _count(swarm: Swarm, member: str) -> int:
    return int(swarm.lead.table.rows(swarm.net.now)[member]["count"])


def _blackout(seed: int, lags: dict[str, float]) -> tuple[Swarm, dict[str, float]]:
    """Run the blackout; ``lags``: per member, how long after it re-discovers the commander
    the commander re-discovers it. Returns the swarm and, per member, the time of the
    commander's re-discovery of it."""
    swarm = Swarm(len(lags), seed=seed)
    for core in swarm.cores.values():
        core.settings = SwarmSettings(readiness_period_s=PERIOD_S, stale_after_s=3.0)
    rng = random.Random(seed)
    swarm.run(10.0 + rng.uniform(0.0, PERIOD_S))  # any phase of the members' ticks
    lead = swarm.ids["lead"]
    swarm.net.isolate(lead)
    swarm.run(LEASE_S)
    for m in swarm.members:  # both sides' leases end
        swarm.call(m, partial(swarm.cores[m].peer_down, "lead"))
        swarm.call("lead", partial(swarm.lead.peer_down, m))
    swarm.run(BLACKOUT_S - LEASE_S)
    swarm.net.isolate(lead, False)
    back = swarm.net.now + rng.uniform(0.0, PERIOD_S)  # the commander's multicast
    found: dict[str, float] = {}
    for m, lag in lags.items():

        def member_finds(now: float, m: str = m) -> None:
            swarm.cores[m].peer_up("lead", address_of(swarm.bundle, "lead"), 1, now)
            swarm.net.poke(swarm.ids[m])

        def lead_finds(now: float, m: str = m) -> None:
            swarm.lead.peer_up(m, address_of(swarm.bundle, m), 1, now)
            swarm.net.poke(lead)

        swarm.net.call_at(back, member_finds)
        swarm.net.call_at(back + lag, lead_finds)
        found[m] = back + lag
    return swarm, found


def test_after_the_blackout_each_members_report_is_counted_once_both_are_up() -> None:
    """Members whose answer is late by 0.05-0.4 s (the measured range): each one's report
    is counted within the network's delay of the commander finding it, and from then on
    one a period; seeds vary the phases."""
    for seed in range(1, 6):
        lags = {"m01": 0.05, "m02": 0.2, "m03": 0.4}
        swarm, found = _blackout(seed, lags)
        start = {m: _count(swarm, m) for m in lags}
        for m in sorted(lags, key=found.__getitem__):
            swarm.run(found[m] + NET_DELAY_S - swarm.net.now)
            assert _count(swarm, m) == start[m] + 1, (seed, m)
        swarm.run(10.0)
        for m in lags:  # then one a period, none lost: 10 s after the last find
            assert _count(swarm, m) >= start[m] + 10, (seed, m)


def test_a_member_found_first_by_the_commander_is_counted_at_once_as_before() -> None:
    swarm, found = _blackout(7, {"m01": -0.2, "m02": 0.0})
    start = {m: _count(swarm, m) for m in found}
    swarm.run(max(found.values()) + 0.2 + NET_DELAY_S - swarm.net.now)
    assert {m: _count(swarm, m) - start[m] for m in found} == {"m01": 1, "m02": 1}


def test_a_report_held_longer_than_the_hold_is_dropped_the_next_one_taken() -> None:
    """The commander finds the member 1.3 s late: the report the member sent at its
    re-discovery is older than ``EARLY_HOLD_S`` and dropped (``peer_not_up``), the one it
    sent a period later is held 0.3 s and counted at the find: one report, not two."""
    swarm, found = _blackout(3, {"m01": EARLY_HOLD_S + 0.3})
    start = _count(swarm, "m01")
    swarm.run(found["m01"] + NET_DELAY_S - swarm.net.now)
    assert _count(swarm, "m01") == start + 1
    assert swarm.lead.plane is not None
    assert swarm.lead.plane.counters["dropped_peer_not_up"] == 1
    assert swarm.lead.plane.counters["early_taken"] == 1


def _readiness_datagram(seq: int) -> bytes:
    sample = Readiness("m01", seq, True, "", False, 1, 3, 10, 50, 700)
    return from_peer(M1.guid_prefix, Data(READY_R, READY_W, seq, None, encode_sample(sample)))


def test_a_forged_datagram_held_for_a_down_peer_moves_nothing() -> None:
    """Attacker: datagrams under m01's prefix while the commander has m01 down, one with a
    flipped tag bit, one a replay of a datagram the commander already took. Neither is
    held (``auth_failed``, ``auth_replayed`` on arrival), nothing is refused later at m01's
    peer_up, no readiness moves. m01's own datagrams past the cap keep at most
    ``MAX_EARLY_PER_PEER`` held."""
    plane = make_plane(BUNDLE, "lead")
    plane.peer_up("m01", address_of(BUNDLE, "m01"), 0.0, epoch=1)
    taken = _readiness_datagram(1)
    plane.receive_datagram(taken, ("10.0.0.2", 7411), 0.1)
    assert plane.readiness_received("m01") is not None
    plane.peer_down("m01", 1.0)
    forged = bytearray(_readiness_datagram(2))
    forged[-1] ^= 0x01
    while plane.next_event() is not None:
        pass
    for data in (bytes(forged), taken):
        plane.receive_datagram(data, ("10.0.0.66", 7411), 1.2)
    assert plane.status(1.2)["early_holding"] == 0
    assert sorted(e.reason for e in drain(plane) if isinstance(e, PacketDropped)) == [
        "auth_failed",
        "auth_replayed",
    ]
    plane.peer_up("m01", address_of(BUNDLE, "m01"), 1.5, epoch=1)
    assert not [e for e in drain(plane) if isinstance(e, ReadinessReceived | PacketDropped)]
    stats = plane.readiness_received("m01")
    assert stats is not None and stats.count == 1
    plane.peer_down("m01", 2.0)
    for k in range(3 * MAX_EARLY_PER_PEER):
        plane.receive_datagram(_readiness_datagram(10 + k), ("10.0.0.2", 7411), 2.0 + k * 0.01)
    assert plane.status(2.2)["early_holding"] == MAX_EARLY_PER_PEER


def test_what_cannot_be_ours_is_dropped_at_once_not_held() -> None:
    """Only a bundle participant's datagram with an authenticator made for this life of
    ours, and of at most the plane's datagram size, is held; the rest is dropped on arrival
    as before (``peer_not_up``)."""
    plane = make_plane(BUNDLE, "lead")
    sample = encode_sample(Readiness("m01", 1, True, "", False, 1, 3, 10, 50, 700))
    header = Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, M1.guid_prefix)
    message = encode_message(header, [Data(READY_R, READY_W, 1, None, sample)])
    key = user_data_key(keyring(BUNDLE, "lead").pair_key(M1.guid_prefix) or b"")
    other_life = seal(key, message, Freshness(1, 1), LEAD.guid_prefix, 2)  # our epoch is 1
    big = Data(READY_R, READY_W, 2, None, b"\0" * MAX_DATAGRAM_BYTES)
    for datagram in (message, other_life, from_peer(M1.guid_prefix, big)):
        plane.receive_datagram(datagram, ("10.0.0.2", 7411), 0.0)
    assert plane.status(0.0)["early_holding"] == 0
    assert plane.counters["dropped_peer_not_up"] == 3


def _sealed_readiness(sender: str, key_of: str, seq: int, *, epoch: int = 1) -> bytes:
    """m01's readiness (DATA SN ``seq``) to the commander in freshness ``epoch``/``seq``,
    its tag made with ``key_of``'s pair key with the commander (m01's own: genuine)."""
    prefix = BUNDLE.participant(sender).guid_prefix
    sample = Readiness(sender, seq, True, "", False, 1, 3, 10, 50, 700)
    header = Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, prefix)
    message = encode_message(header, [Data(READY_R, READY_W, seq, None, encode_sample(sample))])
    pair = keyring(BUNDLE, "lead").pair_key(BUNDLE.participant(key_of).guid_prefix)
    assert pair is not None
    return seal(user_data_key(pair), message, Freshness(epoch, seq), LEAD.guid_prefix, 1)


def _down_with_one_report_held() -> tuple[DataPlane, bytes]:
    """The commander had m01 up (SN 1 taken), then down; m01's genuine report SN 9 arrives
    before its re-discovery and is held."""
    plane = make_plane(BUNDLE, "lead")
    plane.peer_up("m01", address_of(BUNDLE, "m01"), 0.0, epoch=1)
    plane.receive_datagram(_sealed_readiness("m01", "m01", 1), ("10.0.0.2", 7411), 0.1)
    plane.peer_down("m01", 1.0)
    genuine = _sealed_readiness("m01", "m01", 9)
    plane.receive_datagram(genuine, ("10.0.0.2", 7411), 1.1)
    assert plane.status(1.1)["early_holding"] == 1
    return plane, genuine


def _taken_at_peer_up(plane: DataPlane, now: float) -> list[int]:
    """m01 up again: the readiness sequence numbers the commander counts from the hold."""
    while plane.next_event() is not None:
        pass
    plane.peer_up("m01", address_of(BUNDLE, "m01"), now, epoch=1)
    taken = []
    while (event := plane.next_event()) is not None:
        if isinstance(event, ReadinessReceived):
            taken.append(event.sample.seq)
    return taken


def test_an_outsiders_forgeries_cannot_push_a_held_genuine_report_out() -> None:
    """Attacker without keys, and a captured member (m02) tagging with its own pair key:
    datagrams under m01's prefix, sealed for the commander's life (the epoch hint is public,
    in its SPDP), more than the hold keeps. They are refused on arrival (``auth_failed``),
    never held, so m01's genuine report still counts at m01's peer_up. On a plane that holds
    before it verifies, the flood displaced it (the report was lost, as in the blackout)."""
    plane, _ = _down_with_one_report_held()
    flood = 3 * MAX_EARLY_PER_PEER
    for k in range(flood):
        outsider = bytearray(_sealed_readiness("m01", "m01", 20 + k))
        outsider[-1] ^= 0x01  # a guessed tag
        captured = _sealed_readiness("m01", "m02", 40 + k)  # m02's key, m01's prefix
        plane.receive_datagram(bytes(outsider), ("10.0.0.66", 7411), 1.2 + k * 0.01)
        plane.receive_datagram(captured, ("10.0.0.3", 7411), 1.2 + k * 0.01)
    assert plane.status(1.4)["early_holding"] == 1
    assert plane.counters["dropped_auth_failed"] == 2 * flood
    assert _taken_at_peer_up(plane, 1.5) == [9]


def test_replayed_captures_cannot_push_a_held_genuine_report_out() -> None:
    """Attacker replaying genuine datagrams of m01: one the commander already took (the
    replay window refuses it on arrival), and older ones of m01's life the commander never
    received (they verify), each sent again and again. The hold keeps the freshest
    (highest freshness), so the genuine SN 9 report is never displaced by older captures."""
    plane, _ = _down_with_one_report_held()
    taken_before = _sealed_readiness("m01", "m01", 1)
    older = [_sealed_readiness("m01", "m01", seq) for seq in range(2, 2 + MAX_EARLY_PER_PEER)]
    for k in range(3):
        plane.receive_datagram(taken_before, ("10.0.0.66", 7411), 1.2 + k * 0.01)
        for data in older:
            plane.receive_datagram(data, ("10.0.0.66", 7411), 1.2 + k * 0.01)
    assert plane.counters["dropped_auth_replayed"] >= 3
    assert plane.status(1.4)["early_holding"] <= MAX_EARLY_PER_PEER
    assert 9 in _taken_at_peer_up(plane, 1.5)


def test_copies_of_the_newest_held_datagram_cannot_push_the_others_out() -> None:
    """Attacker replaying the newest of m01's held reports (it verifies, its freshness is
    the highest) again and again: an exact copy is not held twice, so m01's other held
    reports are all counted at its peer_up. Held once per copy, they pushed the others out."""
    plane, _ = _down_with_one_report_held()  # SN 9
    newer = [_sealed_readiness("m01", "m01", seq) for seq in (10, 11)]
    for data in newer:
        plane.receive_datagram(data, ("10.0.0.2", 7411), 1.15)
    for k in range(2 * MAX_EARLY_PER_PEER):
        plane.receive_datagram(newer[-1], ("10.0.0.66", 7411), 1.2 + k * 0.01)
    assert plane.status(1.4)["early_holding"] == 3
    assert sorted(_taken_at_peer_up(plane, 1.5)) == [9, 10, 11]
