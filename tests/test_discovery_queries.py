"""The engine's typed queries: ``peer``, ``peers``, ``peer_counts``, ``foreign``, the
locators ``PeerDiscovered`` carries, and ``status(now)`` as a pure function of the state."""

from __future__ import annotations

import json

from swarmd_lab.testing import engine_for, make_bundle, node_ipv4, peer_datagram

from swarmd.discovery import (
    DiscoveryEngine,
    DropReason,
    PeerDiscovered,
    PeerState,
)
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp
from swarmd.rtps.types import Duration, GuidPrefix

BUNDLE = make_bundle(4)


def fresh() -> DiscoveryEngine:
    return engine_for(BUNDLE, 0, seed=3, q=0.7)


def discovered_events(engine: DiscoveryEngine) -> list[PeerDiscovered]:
    out = []
    while (e := engine.next_event()) is not None:
        if isinstance(e, PeerDiscovered):
            out.append(e)
    return out


def test_peer_discovered_carries_the_locators_of_its_data_p() -> None:
    engine = fresh()
    uav2 = BUNDLE.participants[2]
    engine.receive_datagram(peer_datagram(BUNDLE, 2), (node_ipv4(2), 7000), 1.0)
    (event,) = discovered_events(engine)
    assert event.name == "uav2"
    assert event.metatraffic_unicast_locators == (
        Locator.udpv4(node_ipv4(2), BUNDLE.metatraffic_port(uav2)),
    )
    assert event.default_unicast_locators == (Locator.udpv4(node_ipv4(2), BUNDLE.user_port(uav2)),)


def test_peer_by_name_and_by_prefix_agree_and_follow_the_state() -> None:
    engine = fresh()
    uav1 = BUNDLE.participants[1]
    before = engine.peer("uav1")
    assert before is not None and before.state == PeerState.UNDISCOVERED
    assert not before.discovered and before.matches == () and before.last_heard is None
    assert before.metatraffic_unicast_locators == ()
    engine.receive_datagram(peer_datagram(BUNDLE, 1, heard=(0,)), (node_ipv4(1), 7000), 2.5)
    by_name, by_prefix = engine.peer("uav1"), engine.peer(uav1.guid_prefix)
    assert by_name == by_prefix
    assert by_name is not None
    assert by_name.discovered and by_name.lists_me and by_name.last_heard == 2.5
    assert by_name.locator == (node_ipv4(1), BUNDLE.metatraffic_port(uav1))
    assert by_name.matches == tuple(BUNDLE.matches(BUNDLE.participants[0], uav1))
    assert by_name.matches != ()
    assert engine.peer_counts() == (1, 3)
    assert [p.name for p in engine.peers()] == ["uav1", "uav2", "uav3"]
    # not peers: ourselves, a name or prefix the bundle does not list
    assert engine.peer("uav0") is None
    assert engine.peer("stranger") is None
    assert engine.peer(GuidPrefix(bytes(12))) is None


STRANGER = encode_spdp(
    SpdpParticipant(
        GuidPrefix(b"\x01" * 12),
        domain_id=0,
        metatraffic_unicast_locators=(Locator.udpv4("10.9.9.9", 7410),),
        lease_duration=Duration.from_seconds(10.0),
        entity_name="stock",
    ),
    sequence_number=1,
    timestamp=None,
)


def test_foreign_participants_are_listed_typed_with_their_reason() -> None:
    engine = fresh()
    engine.receive_datagram(STRANGER, ("10.9.9.9", 7410), 1.0)
    (seen,) = engine.foreign(1.0)
    assert seen.reason == DropReason.NOT_IN_BUNDLE and seen.name == "stock"
    assert engine.foreign(12.0) == ()  # silent past its lease: no longer listed
    assert engine.counters()["dropped"]["not_in_bundle"] == 1


def test_status_is_a_pure_function_of_the_state() -> None:
    engine = fresh()
    engine.receive_datagram(peer_datagram(BUNDLE, 1, heard=(0,)), (node_ipv4(1), 7000), 1.0)
    engine.receive_datagram(STRANGER, ("10.9.9.9", 7410), 1.0)
    while (t := engine.get_timer()) is not None and t <= 5.0:
        engine.handle_timer(t)
    engine.datagrams_to_send()
    while engine.next_event() is not None:
        pass
    timer = engine.get_timer()
    first = json.dumps(engine.status(6.0), sort_keys=True)
    assert json.loads(first)["foreign"] != []
    for now in (6.0, 500.0, 6.0):  # any `now`, any number of times: a later one used to
        engine.status(now)  # prune the foreign table, so an earlier one saw it shrink
    assert json.dumps(engine.status(6.0), sort_keys=True) == first
    assert engine.get_timer() == timer
    assert engine.next_event() is None and engine.datagrams_to_send() == []


def test_every_drop_reason_is_reported_in_enum_order() -> None:
    dropped = fresh().counters()["dropped"]
    assert list(dropped) == [str(r) for r in DropReason]
    assert set(dropped.values()) == {0}
