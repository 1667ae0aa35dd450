"""The ROS 2 SPDP relay core (swarmd.ros2.relay) on hand-set time: what it announces to the
drone's nodes and when, what it takes from them (shown, never relayed), and hostile input.
The real-process test is tests/test_ros2_relay_netns.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import (
    GRAPH_TOPIC,
    Ros2EndpointKind,
    Ros2Participant,
    bundle_ros2_participants,
)
from swarmd.cli.status_cmd import render_status
from swarmd.ros2.relay import (
    LOOPBACK,
    MAX_UNDECLARED_PER_PARTICIPANT,
    MAX_UNKNOWN_PARTICIPANTS,
    MIN_NODE_LEASE_S,
    SIBLING_REMATCH_MAX_S,
    SIBLING_REMATCH_S,
    UNKNOWN_REPORT_BURST,
    UNKNOWN_REPORTS_PER_S,
    Ros2Relay,
)
from swarmd.ros2.relay_events import (
    LocalLivenessChanged,
    LocalParticipantHeard,
    RelayEvent,
    RemoteParticipantsRelayed,
    UndeclaredEndpoint,
    UnknownParticipantHeard,
)
from swarmd.ros2.relay_spdp import static_edp_entity_id, static_edp_properties
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import (
    BES_SPDP_ONLY,
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.types import Duration, GuidPrefix, VendorId

REPO = Path(__file__).resolve().parent.parent
MISSION = (REPO / "firmware_bundle" / "missions" / "swarm3-ros2.yaml").read_text()
LEASE_S = 8.0
RELAY_PORT = 7399
EPOCH = 1_790_000_000
ADDRESS = {"lead": "10.42.0.10", "drone-1": "10.42.0.11", "drone-2": "10.42.0.12"}


def _participants() -> tuple[Ros2Participant, ...]:
    return bundle_ros2_participants(build_dev_bundle(parse_mission(MISSION)).bundle)


def _by(participants: tuple[Ros2Participant, ...], drone: str) -> Ros2Participant:
    return next(p for p in participants if p.drone == drone)


def _relay(drone: str = "lead", epoch: int = EPOCH) -> Ros2Relay:
    return Ros2Relay(
        _participants(),
        drone,
        domain_id=0,
        lease_s=LEASE_S,
        relay_port=RELAY_PORT,
        epoch=epoch,
    )


def _events(relay: Ros2Relay) -> list[RelayEvent]:
    out = []
    while (event := relay.next_event()) is not None:
        out.append(event)
    return out


def _local_spdp(
    p: Ros2Participant,
    sn: int,
    properties: tuple[tuple[str, str], ...] = (),
    lease_s: float = 100.0,
) -> bytes:
    """What a --via-swarmd node sends the relay (its own DATA(p) from [::1])."""
    return encode_spdp(
        SpdpParticipant(
            GuidPrefix(p.guid_prefix),
            lease_duration=Duration.from_seconds(lease_s),
            vendor_id=VendorId(b"\x01\x0f"),
            metatraffic_unicast_locators=(Locator.udpv6(LOOPBACK, p.metatraffic_port),),
            default_unicast_locators=(Locator.udpv4(ADDRESS[p.drone], p.user_port),),
            builtin_endpoints=0xFC03,
            entity_name="/",
            properties=properties,
        ),
        sequence_number=sn,
        timestamp=None,
    )


def _decoded(datagram: bytes) -> SpdpAlive:
    _header, samples = decode_spdp(datagram)
    assert len(samples) == 1
    sample = samples[0]
    assert isinstance(sample, SpdpAlive)
    return sample


def test_entity_id_property_matches_what_fast_dds_announced() -> None:
    # measured on rclpy + Fast DDS 3.2.2 (docs/ros2.md): a writer profile with
    # userDefinedID 8 and entityID 108 was announced as
    # eProsimaEDPStatic_Writer_ALIVE_ID_8 = 0.0.108.3, its reader 109 as 0.0.109.4
    assert static_edp_entity_id(108, Ros2EndpointKind.WRITER) == "0.0.108.3"
    assert static_edp_entity_id(109, Ros2EndpointKind.READER) == "0.0.109.4"
    assert static_edp_entity_id(0x1234, Ros2EndpointKind.WRITER) == "0.18.52.3"


def test_a_discovered_drone_is_announced_to_every_local_node_from_the_bundle() -> None:
    participants = _participants()
    relay = _relay("lead")
    assert relay.get_timer() is None  # nothing to renew before any peer is discovered
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 1.0)
    out = relay.datagrams_to_send()
    lead = _by(participants, "lead")
    talker = _by(participants, "drone-1")
    assert [dest for _, dest in out] == [(LOOPBACK, lead.metatraffic_port)]
    sample = _decoded(out[0][0])
    p = sample.participant
    assert p.guid_prefix == GuidPrefix(talker.guid_prefix)
    assert p.vendor_id == VendorId(b"\x01\x0f")
    # user data straight to the peer's address; discovery back to this relay on ::1
    assert p.default_unicast_locators == (Locator.udpv4(ADDRESS["drone-1"], talker.user_port),)
    assert p.metatraffic_unicast_locators == (Locator.udpv6(LOOPBACK, RELAY_PORT),)
    assert p.builtin_endpoints == BES_SPDP_ONLY  # no SEDP, no WLP endpoint to start
    assert p.properties == static_edp_properties(talker)
    # every endpoint but its ros_discovery_info writer and reader: rmw's graph topic stays
    # among the nodes of one drone (docs/ros2.md, "Graph traffic")
    graph_ids = [
        talker.first_user_id + i
        for i, e in enumerate(talker.endpoints)
        if e.dds_topic == GRAPH_TOPIC
    ]
    assert len(graph_ids) == 2
    assert len(p.properties) == len(talker.endpoints) - 2
    assert not any(name.endswith(f"_ID_{uid}") for name, _ in p.properties for uid in graph_ids)
    assert sample.sequence_number > EPOCH << 32
    assert _events(relay) == [RemoteParticipantsRelayed("drone-1", 1, up=True)]
    assert relay.get_timer() == pytest.approx(1.0 + LEASE_S / 4)
    # the same address again is no news
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 1.5)
    assert relay.datagrams_to_send() == []


def test_renewed_within_the_lease_then_disposed_when_the_peer_is_lost() -> None:
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 0.0)
    first = [_decoded(d).sequence_number for d, _ in relay.datagrams_to_send()]
    now = relay.get_timer()
    assert now is not None and now < LEASE_S
    relay.handle_timer(now - 0.001)  # early: nothing
    assert relay.datagrams_to_send() == []
    relay.handle_timer(now)
    renewed = [_decoded(d).sequence_number for d, _ in relay.datagrams_to_send()]
    assert len(renewed) == 2 and min(renewed) > max(first)
    relay.peer_lost("drone-1", now + 0.5)
    out = relay.datagrams_to_send()
    _header, samples = decode_spdp(out[0][0])
    assert isinstance(samples[0], SpdpDisposed)
    assert samples[0].guid_prefix == GuidPrefix(_by(_participants(), "drone-1").guid_prefix)
    relay.peer_lost("drone-2", now + 0.6)
    relay.datagrams_to_send()
    assert relay.get_timer() is None
    relay.peer_lost("drone-2", now + 0.7)  # twice: nothing more
    assert relay.datagrams_to_send() == []


def test_a_restarted_swarmd_numbers_above_its_earlier_life() -> None:
    # a node matched the relayed SPDP writer and drops sequence numbers it has passed
    before = _relay(epoch=EPOCH)
    after = _relay(epoch=EPOCH + 1)
    for relay in (before, after):
        relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
        for _ in range(100):
            relay.handle_timer(relay.get_timer() or 0.0)
    last_before = max(_decoded(d).sequence_number for d, _ in before.datagrams_to_send())
    first_after = min(_decoded(d).sequence_number for d, _ in after.datagrams_to_send())
    assert first_after > last_before


def test_a_local_node_heard_first_or_after_a_restart_gets_everything_at_once() -> None:
    participants = _participants()
    relay = _relay("lead")
    lead = _by(participants, "lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 0.0)
    relay.datagrams_to_send()
    _events(relay)
    relay.receive_datagram(_local_spdp(lead, 5), ("::1", 40000), 1.0)
    assert _events(relay) == [
        LocalParticipantHeard("lead", "listener", GuidPrefix(lead.guid_prefix), False)
    ]
    assert len(relay.datagrams_to_send()) == 2
    relay.receive_datagram(_local_spdp(lead, 6), ("::1", 40000), 1.5)  # its second: answered
    assert len(relay.datagrams_to_send()) == 2 and _events(relay) == []
    relay.receive_datagram(_local_spdp(lead, 7), ("::1", 40000), 2.0)  # a renewal
    assert relay.datagrams_to_send() == [] and _events(relay) == []
    relay.receive_datagram(_local_spdp(lead, 1), ("::1", 40001), 3.0)  # SN back to 1
    assert _events(relay) == [
        # a new life, counted in the signed liveness word (bitmap, then its restarts)
        LocalLivenessChanged(b"\x01\x01", "listener", up=True),
        LocalParticipantHeard("lead", "listener", GuidPrefix(lead.guid_prefix), True),
    ]
    assert len(relay.datagrams_to_send()) == 2
    relay.receive_datagram(_local_spdp(lead, 2), ("::1", 40001), 3.0)
    relay.datagrams_to_send()
    row = relay.status(3.5)["local"][0]
    assert row["state"] == "heard" and row["last_heard_s"] == 0.5
    # its DATA(p[UD]) on shutdown: shown as left; back with SN going on: a restart anyway
    relay.receive_datagram(
        encode_spdp_dispose(
            GuidPrefix(lead.guid_prefix),
            sequence_number=9,
            timestamp=None,
            vendor_id=VendorId(b"\x01\x0f"),
        ),
        ("::1", 40001),
        4.0,
    )
    assert relay.status(4.0)["local"][0]["state"] == "left"
    assert relay.datagrams_to_send() == []
    assert _events(relay) == [LocalLivenessChanged(b"\x00\x01", "listener", up=False)]
    relay.receive_datagram(_local_spdp(lead, 10), ("::1", 40002), 5.0)
    assert _events(relay) == [
        LocalLivenessChanged(b"\x01\x02", "listener", up=True),
        LocalParticipantHeard("lead", "listener", GuidPrefix(lead.guid_prefix), True),
    ]
    assert len(relay.datagrams_to_send()) == 2


def test_a_starting_node_gets_everything_again_at_its_second_datagram() -> None:
    """The late publisher of the testbed (docs/ros2.md, "A late publisher"): a starting
    Fast DDS participant sends its first DATA(p) before its receivers are registered, and
    drops what arrives in between; the relay's answer to that first datagram can be lost
    that way. Its second datagram is sent once it listens: the relay answers it in full
    too, then falls back to the renewals. Checked by content, not by timing."""
    participants = _participants()
    relay = _relay("drone-1")
    talker = _by(participants, "drone-1")
    relay.peer_discovered("lead", ADDRESS["lead"], 0.0)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 0.0)
    relay.datagrams_to_send()
    expected = {GuidPrefix(p.guid_prefix) for p in participants if p.drone != "drone-1"}
    answers = []
    for sn in (1, 2, 3, 4):  # its announcement, two endpoint updates, a repeat
        relay.receive_datagram(_local_spdp(talker, sn), ("::1", 40000), 0.5)
        answers.append(relay.datagrams_to_send())
    for out in answers[:2]:
        assert {dest for _, dest in out} == {(LOOPBACK, talker.metatraffic_port)}
        assert {_decoded(d).participant.guid_prefix for d, _ in out} == expected
    assert answers[2] == [] and answers[3] == []
    assert relay.counters["tx_start_answers"] == 2


def _two_on_drone_1() -> tuple[Ros2Relay, Ros2Participant, Ros2Participant]:
    two = MISSION.replace(
        "    - name: listener\n", "    - {name: helper, drones: [drone-1]}\n    - name: listener\n"
    )
    participants = bundle_ros2_participants(build_dev_bundle(parse_mission(two)).bundle)
    relay = Ros2Relay(participants, "drone-1", domain_id=0, lease_s=LEASE_S, epoch=EPOCH)
    talker, helper = (p for p in participants if p.drone == "drone-1")
    return relay, talker, helper


def test_a_starting_node_gets_its_alive_siblings_own_announcement() -> None:
    """Two nodes on one drone are each other's initial peers; the running one answers the
    starting one at once, possibly before it listens (as the relay's answer can be lost:
    docs/ros2.md, "Several nodes on one drone"). The relay passes the sibling's own latest
    DATA(p), byte for byte, with its two start answers; nothing once the sibling left."""
    relay, talker, helper = _two_on_drone_1()
    helper_spdp = _local_spdp(helper, 7)
    relay.receive_datagram(helper_spdp, ("::1", 40000), 0.0)
    relay.datagrams_to_send()
    answers = []
    for sn in (1, 2, 3):
        relay.receive_datagram(_local_spdp(talker, sn), ("::1", 40001), 0.5)
        answers.append(relay.datagrams_to_send())
    to_talker = (LOOPBACK, talker.metatraffic_port)
    assert [out.count((helper_spdp, to_talker)) for out in answers] == [1, 1, 0]
    assert relay.counters["tx_sibling_spdp"] == 2
    # the helper leaves (DATA(p[UD])): a talker starting again gets nothing of it
    relay.receive_datagram(
        encode_spdp_dispose(GuidPrefix(helper.guid_prefix), sequence_number=8, timestamp=None),
        ("::1", 40000),
        1.0,
    )
    relay.receive_datagram(
        encode_spdp_dispose(GuidPrefix(talker.guid_prefix), sequence_number=4, timestamp=None),
        ("::1", 40001),
        1.0,
    )
    relay.datagrams_to_send()
    relay.receive_datagram(_local_spdp(talker, 1), ("::1", 40002), 1.5)
    assert helper_spdp not in [d for d, _ in relay.datagrams_to_send()]


def test_a_node_killed_and_started_again_is_disposed_at_its_siblings_first() -> None:
    """Its sibling still holds the writer proxies of its earlier life and drops its new
    DATA(p), numbered from 1 again (docs/ros2.md, "A restart under the same GUIDs"): the
    relay sends the sibling the node's DATA(p[UD]), numbered above anything the relay sent
    before, then the node's own new DATA(p) as it sent it. Not after a DATA(p[UD]) of its
    own (the sibling got that one), nor to a sibling that is not alive."""
    relay, talker, helper = _two_on_drone_1()
    relay.receive_datagram(_local_spdp(helper, 7), ("::1", 40000), 0.0)
    for sn in (1, 2, 3):
        relay.receive_datagram(_local_spdp(talker, sn), ("::1", 40001), 0.5)
    before = relay.datagrams_to_send()
    to_helper = (LOOPBACK, helper.metatraffic_port)
    second_life = _local_spdp(talker, 1)
    relay.receive_datagram(second_life, ("::1", 40002), 1.0)  # SIGKILLed, started again
    to_sibling = [d for d, dest in relay.datagrams_to_send() if dest == to_helper]
    dispose, announcement = to_sibling
    _header, samples = decode_spdp(dispose)
    assert samples == [SpdpDisposed(GuidPrefix(talker.guid_prefix), samples[0].sequence_number)]
    assert samples[0].sequence_number > max(
        s.sequence_number for d, _ in before for s in decode_spdp(d)[1]
    )
    assert announcement == second_life
    assert relay.counters["tx_sibling_dispose"] == 1
    # its own DATA(p[UD]) reached the sibling: nothing to dispose when it comes back
    relay.receive_datagram(
        encode_spdp_dispose(GuidPrefix(talker.guid_prefix), sequence_number=4, timestamp=None),
        ("::1", 40002),
        2.0,
    )
    relay.receive_datagram(_local_spdp(talker, 1), ("::1", 40003), 2.5)
    assert relay.counters["tx_sibling_dispose"] == 1
    # the sibling is gone (both leases ran out): a restart, and no one to tell
    relay.receive_datagram(_local_spdp(talker, 2), ("::1", 40003), 2.6)
    relay.handle_timer(1000.0)
    assert [r["alive"] for r in relay.status(1000.0)["local"]] == [False, False]
    _events(relay)
    relay.receive_datagram(_local_spdp(talker, 1), ("::1", 40004), 1000.0)
    assert LocalParticipantHeard("drone-1", "talker", GuidPrefix(talker.guid_prefix), True) in (
        _events(relay)
    )
    assert relay.counters["tx_sibling_dispose"] == 1


def _edp(*uids: int) -> tuple[tuple[str, str], ...]:
    """A node's static EDP properties for writers ``uids`` (what it lists as it creates them)."""
    return tuple(
        (f"eProsimaEDPStatic_Writer_ALIVE_ID_{u}", static_edp_entity_id(u, Ros2EndpointKind.WRITER))
        for u in uids
    )


def _to(relay: Ros2Relay, node: Ros2Participant, prefix: GuidPrefix) -> list[bytes]:
    """The datagrams out to ``node`` that speak of participant ``prefix``."""
    port = node.metatraffic_port
    return [
        d
        for d, dest in relay.datagrams_to_send()
        if dest == (LOOPBACK, port) and decode_spdp(d)[0].guid_prefix == prefix
    ]


def _lapsed_talker(
    relay: Ros2Relay, talker: Ros2Participant, helper: Ros2Participant, lease_s: float = 4.0
) -> float:
    """The helper alive (60 s lease), the talker heard with ``lease_s`` and then silent
    past it (dropped by lease at the relay, as at its sibling); returns the time."""
    relay.receive_datagram(_local_spdp(helper, 1, lease_s=60.0), ("::1", 40000), 0.0)
    for sn in (1, 2, 3):
        spdp = _local_spdp(talker, sn, _edp(8, 12), lease_s=lease_s)
        relay.receive_datagram(spdp, ("::1", 40001), float(sn))
    relay.handle_timer(3.0 + lease_s)
    assert [r["state"] for r in relay.status(3.0 + lease_s)["local"]][0] == "lease expired"
    relay.datagrams_to_send()
    return 30.0


def test_a_node_back_after_its_lease_is_disposed_at_its_siblings_once_it_listed_its_writers() -> (
    None
):
    """Its sibling dropped it by lease and kept its writers' last numbers; a dispose finds
    only writers it matched again (docs/ros2.md, "A node back after its own lease"). So the
    relay sends nothing of the node while it starts (its own DATA(p)s, which list its
    endpoints as it creates them, must reach the sibling's SPDP reader unhindered: nothing
    numbered above them), and the dispose, then its latest own DATA(p), once its endpoint
    list has been the same for SIBLING_REMATCH_S."""
    relay, talker, helper = _two_on_drone_1()
    t = _lapsed_talker(relay, talker, helper)
    prefix = GuidPrefix(talker.guid_prefix)
    lives = [(t, ()), (t + 0.01, _edp(8)), (t + 0.05, _edp(8, 12)), (t + 0.3, _edp(8, 12))]
    for sn, (at, edp) in enumerate(lives, start=1):
        relay.receive_datagram(_local_spdp(talker, sn, edp, lease_s=4.0), ("::1", 40002), at)
        assert _to(relay, helper, prefix) == []
    assert relay.get_timer() == t + 0.05 + SIBLING_REMATCH_S
    relay.handle_timer(t + 0.05 + SIBLING_REMATCH_S - 0.001)
    assert _to(relay, helper, prefix) == []
    relay.handle_timer(t + 0.05 + SIBLING_REMATCH_S)
    dispose, latest = _to(relay, helper, prefix)
    assert decode_spdp(dispose)[1] == [
        SpdpDisposed(prefix, decode_spdp(dispose)[1][0].sequence_number)
    ]
    assert latest == _local_spdp(talker, 4, _edp(8, 12), lease_s=4.0)
    assert relay.counters["sibling_dispose_deferred"] == 1
    assert relay.counters["tx_sibling_dispose"] == 1
    relay.handle_timer(t + 10.0)
    assert relay.counters["tx_sibling_dispose"] == 1


def test_a_quick_restart_is_disposed_at_once_and_one_near_its_lease_end_waits() -> None:
    """Well within its lease the sibling still knows the node: the dispose at once finds its
    writers (test above for the dispose's content). Within a quarter of its lease of the
    end (the sibling's lease timer is not the relay's) it is handled as lapsed."""
    relay, talker, helper = _two_on_drone_1()
    relay.receive_datagram(_local_spdp(helper, 1, lease_s=60.0), ("::1", 40000), 0.0)
    relay.receive_datagram(_local_spdp(talker, 5, lease_s=4.0), ("::1", 40001), 1.0)
    relay.receive_datagram(_local_spdp(talker, 1, lease_s=4.0), ("::1", 40002), 2.0)
    assert relay.counters["tx_sibling_dispose"] == 1
    assert relay.counters["sibling_dispose_deferred"] == 0
    relay.receive_datagram(_local_spdp(talker, 9, lease_s=4.0), ("::1", 40002), 3.0)
    relay.receive_datagram(_local_spdp(talker, 1, lease_s=4.0), ("::1", 40003), 6.2)
    assert relay.counters["tx_sibling_dispose"] == 1
    assert relay.counters["sibling_dispose_deferred"] == 1
    relay.handle_timer(6.2 + SIBLING_REMATCH_S)
    assert relay.counters["tx_sibling_dispose"] == 2


def test_a_node_growing_its_endpoint_list_forever_is_disposed_by_the_deadline() -> None:
    """Attack: a process on the drone speaks as the lapsed talker and lists one more
    endpoint every 0.3 s (bounded: 100): the dispose comes SIBLING_REMATCH_MAX_S after the
    life's first DATA(p) all the same, once."""
    relay, talker, helper = _two_on_drone_1()
    t = _lapsed_talker(relay, talker, helper)
    for i in range(100):
        at = t + 0.3 * i
        relay.handle_timer(at)
        spdp = _local_spdp(talker, i + 1, _edp(*range(8, 9 + i)), lease_s=4.0)
        relay.receive_datagram(spdp, ("::1", 40002), at)
        if relay.counters["tx_sibling_dispose"]:
            break
    assert relay.counters["tx_sibling_dispose"] == 1
    assert t + SIBLING_REMATCH_MAX_S - 0.3 <= at <= t + SIBLING_REMATCH_MAX_S + 0.3


def test_a_pending_dispose_is_dropped_by_the_next_life_and_never_reaches_it() -> None:
    """Attack: a process on the drone speaks as the lapsed talker (a new life: a smaller
    sequence number) and, before its deferred dispose is due, starts another life within
    that life's lease (the quick-restart path: dispose at once). The first life's dispose
    must not follow: sent after the second life's own DATA(p), it would remove the writers
    the sibling has just matched for it (Fast DDS forgets a disposed participant's writers).
    One dispose in all, none after the second life's (fails if a new life keeps the last
    one's ``sibling_dispose_at``)."""
    relay, talker, helper = _two_on_drone_1()
    t = _lapsed_talker(relay, talker, helper)
    relay.receive_datagram(_local_spdp(talker, 1, lease_s=4.0), ("::1", 40002), t)
    relay.receive_datagram(_local_spdp(talker, 2, _edp(8), lease_s=4.0), ("::1", 40002), t + 0.05)
    assert relay.counters["sibling_dispose_deferred"] == 1
    assert relay.counters["tx_sibling_dispose"] == 0
    relay.receive_datagram(_local_spdp(talker, 1, _edp(8), lease_s=4.0), ("::1", 40003), t + 0.1)
    assert relay.counters["tx_sibling_dispose"] == 1  # the second life's, at once
    relay.datagrams_to_send()
    for k in range(1, 21):  # 10 s of timers (bounded), past SIBLING_REMATCH_MAX_S
        relay.handle_timer(t + 0.1 + 0.5 * k)
    assert relay.counters["tx_sibling_dispose"] == 1
    assert _to(relay, helper, GuidPrefix(talker.guid_prefix)) == []


def test_a_replayed_new_life_past_its_lease_is_disposed_at_the_siblings_once() -> None:
    """Attack: a process on the drone replays the lapsed node's new life's first DATA(p)
    1000 times (bounded), then continues it: one deferred dispose per sibling."""
    relay, talker, helper = _two_on_drone_1()
    t = _lapsed_talker(relay, talker, helper)
    replayed = _local_spdp(talker, 1, lease_s=4.0)
    for i in range(1000):
        relay.receive_datagram(replayed, ("::1", 40002), t + i * 0.0001)
    for sn in range(2, 500):
        relay.receive_datagram(_local_spdp(talker, sn, lease_s=4.0), ("::1", 40002), t + 0.2)
    relay.handle_timer(t + 5.0)
    assert relay.counters["sibling_dispose_deferred"] == 1
    assert relay.counters["tx_sibling_dispose"] == 1


@pytest.mark.parametrize("cadence_s", [0.1, 0.76, 1.5])
def test_a_local_process_cycling_lives_gets_one_dispose_per_life_at_the_siblings(
    cadence_s: float,
) -> None:
    """Attack: a process on the drone speaks as the talker with the shortest lease it may
    claim (0 s, clamped to MIN_NODE_LEASE_S) and a new life every ``cadence_s`` for 60 s of
    virtual time (bounded loop): at most one dispose (and one DATA(p)) per life the relay
    counts, per sibling, whether at once or deferred."""
    relay, talker, helper = _two_on_drone_1()
    prefix = GuidPrefix(talker.guid_prefix)
    relay.receive_datagram(_local_spdp(helper, 1, lease_s=300.0), ("::1", 40000), 0.0)
    relay.receive_datagram(_local_spdp(talker, 100, lease_s=0.0), ("::1", 40001), 0.0)
    lives, at_helper, now = 0, 0, 0.0
    for step in range(1, int(60.0 / cadence_s) + 1):
        now = step * cadence_s
        relay.handle_timer(now)
        at_helper += len(_to(relay, helper, prefix))
        for sn in (1, 2):  # each life: two DATA(p)s, the second listing a writer
            spdp = _local_spdp(talker, sn, _edp(8) if sn == 2 else (), lease_s=0.0)
            relay.receive_datagram(spdp, ("::1", 40002 + step), now)
        at_helper += len(_to(relay, helper, prefix))
        lives += 1
    relay.handle_timer(now + SIBLING_REMATCH_MAX_S)
    at_helper += len(_to(relay, helper, prefix))
    disposes = relay.counters["tx_sibling_dispose"]
    assert 0 < disposes <= lives
    assert at_helper == 2 * disposes  # each: the dispose, then the node's latest DATA(p)
    if cadence_s > MIN_NODE_LEASE_S:  # every life lapsed: each deferred, each sent
        assert relay.counters["sibling_dispose_deferred"] == lives == disposes


def test_a_liveness_word_from_the_air_cannot_dispose_this_drones_nodes_at_their_siblings() -> None:
    """Attack: words naming this drone (its own participants, every restart count
    changing; 1000, bounded) are not this drone's relay's to act on: counted, no datagram
    about a local node goes to its sibling."""
    relay, talker, helper = _two_on_drone_1()
    relay.receive_datagram(_local_spdp(helper, 1, lease_s=60.0), ("::1", 40000), 0.0)
    relay.receive_datagram(_local_spdp(talker, 1, lease_s=60.0), ("::1", 40001), 0.0)
    relay.datagrams_to_send()
    for i in range(1000):
        relay.peer_liveness("drone-1", bytes([0xFF, i & 0xFF, i & 0xFF]), 1.0 + i * 0.001)
    assert _to(relay, helper, GuidPrefix(talker.guid_prefix)) == []
    assert relay.counters["liveness_unknown_drone"] == 1000
    assert relay.counters["tx_sibling_dispose"] == 0


def test_only_a_siblings_undirected_announcement_is_passed_on() -> None:
    """A DATA(p) the sibling directed (INFO_DST) to one participant would be dropped by any
    other: it is not kept to pass on; the next undirected one is."""
    relay, talker, helper = _two_on_drone_1()
    undirected = _local_spdp(helper, 7)
    _header, samples = decode_spdp(undirected)
    assert isinstance(samples[0], SpdpAlive)
    directed = encode_spdp(
        samples[0].participant,
        sequence_number=8,
        timestamp=None,
        destination=GuidPrefix(talker.guid_prefix),
    )
    relay.receive_datagram(directed, ("::1", 40000), 0.0)
    relay.receive_datagram(_local_spdp(talker, 1), ("::1", 40001), 0.5)
    assert relay.counters["tx_sibling_spdp"] == 0
    assert [r["state"] for r in relay.status(0.5)["local"]] == ["heard", "heard"]
    relay.receive_datagram(undirected, ("::1", 40000), 0.6)
    relay.datagrams_to_send()
    relay.receive_datagram(_local_spdp(talker, 2), ("::1", 40001), 0.7)  # 2nd start answer
    assert (undirected, (LOOPBACK, talker.metatraffic_port)) in relay.datagrams_to_send()


def _invented(like: Ros2Participant, i: int) -> Ros2Participant:
    """``like`` under an invented GUID prefix, number ``i``: no bundle places it here."""
    return Ros2Participant(
        like.drone,
        like.drone_index,
        like.node,
        bytes.fromhex("010f0bad00000000") + i.to_bytes(4, "big"),
        like.participant_id,
        like.metatraffic_port,
        like.user_port,
        like.endpoints,
        like.first_user_id,
    )


def test_an_unknown_participant_is_shown_never_relayed_and_its_table_is_capped() -> None:
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.datagrams_to_send()
    _events(relay)
    stranger = _by(_participants(), "lead")
    n = MAX_UNKNOWN_PARTICIPANTS + 5
    for i in range(n):
        forged = _invented(stranger, i)
        relay.receive_datagram(_local_spdp(forged, 1), ("::1", 40000 + i), float(i))
    assert relay.datagrams_to_send() == []  # nothing relayed, nothing answered
    events = _events(relay)
    assert all(isinstance(e, UnknownParticipantHeard) for e in events) and len(events) == n
    status = relay.status(float(n))
    assert len(status["unknown"]) == MAX_UNKNOWN_PARTICIPANTS
    assert status["counters"]["unknown_evicted"] == 5
    assert status["unknown"][0]["guid_prefix"].endswith(":5")  # the oldest went first
    assert [r["guid_prefix"] for r in status["remote"]] == [
        str(GuidPrefix(p.guid_prefix)) for p in _participants() if p.drone != "lead"
    ]


def test_a_remote_drones_prefix_on_loopback_is_dropped() -> None:
    relay = _relay("lead")
    talker = _by(_participants(), "drone-1")
    relay.receive_datagram(_local_spdp(talker, 1), ("::1", 40000), 0.0)
    assert relay.datagrams_to_send() == [] and _events(relay) == []
    assert relay.counters["rx_remote_prefix"] == 1
    assert relay.status(0.0)["remote"][0]["state"] == "waiting for drone"


def test_undeclared_endpoints_are_reported_by_node_and_capped() -> None:
    lead = _by(_participants(), "lead")
    relay = _relay("lead")
    declared = static_edp_properties(lead)
    extra = [
        ("eProsimaEDPStatic_Writer_ALIVE_ID_65535", f"0.0.{i}.3")
        for i in range(1, MAX_UNDECLARED_PER_PARTICIPANT + 4)
    ]
    others = (("PARTICIPANT_TYPE", "SIMPLE"), ("eProsimaEDPStatic_Bogus", "x"))
    props = (*declared, *others, *extra)
    relay.receive_datagram(_local_spdp(lead, 1, props), ("::1", 40000), 0.0)
    relay.receive_datagram(_local_spdp(lead, 2, props), ("::1", 40000), 1.0)  # again: no news
    undeclared = [e for e in _events(relay) if isinstance(e, UndeclaredEndpoint)]
    assert len(undeclared) == MAX_UNDECLARED_PER_PARTICIPANT
    assert undeclared[0] == UndeclaredEndpoint("lead", "listener", "writer", 65535, "0.0.1.3")
    row = relay.status(1.0)["local"][0]
    assert len(row["undeclared_endpoints"]) == MAX_UNDECLARED_PER_PARTICIPANT
    assert relay.counters["undeclared_dropped"] == 2 * 3


LO = ("::1", 40000)  # the node's own socket


def _local_dispose(p: Ros2Participant, sn: int) -> bytes:
    """A node's DATA(p[UD]) as it shuts down."""
    return encode_spdp_dispose(GuidPrefix(p.guid_prefix), sequence_number=sn, timestamp=None)


def _undeclared_rows(relay: Ros2Relay, now: float) -> list[str]:
    return [u["entity_id"] for u in relay.status(now)["local"][0]["undeclared_endpoints"]]


def _extra(entities: range) -> tuple[tuple[str, str], ...]:
    """Undeclared writers (no id: Fast DDS says 65535 when a node has none), by entity."""
    return tuple(("eProsimaEDPStatic_Writer_ALIVE_ID_65535", f"0.0.{i}.3") for i in entities)


@pytest.mark.parametrize("how", ["dispose", "killed"])
def test_a_nodes_undeclared_rows_are_those_of_its_current_life(how: str) -> None:
    """Review 18b: a node's undeclared endpoints stayed in ``swarmctl status`` across its
    lives, so a node fixed and restarted still showed the old rows. They are what its
    latest DATA(p) lists: a new life (after its dispose, or killed and started again,
    numbering from 1) starts with none. [fails on main: the old row stays]"""
    lead = _by(_participants(), "lead")
    relay = _relay("lead")
    declared = static_edp_properties(lead)
    relay.receive_datagram(_local_spdp(lead, 1, (*declared, *_extra(range(1, 2)))), LO, 0.0)
    relay.receive_datagram(_local_spdp(lead, 2, (*declared, *_extra(range(1, 2)))), LO, 1.0)
    assert _undeclared_rows(relay, 1.0) == ["0.0.1.3"]
    if how == "dispose":
        relay.receive_datagram(_local_dispose(lead, 3), LO, 2.0)
    relay.receive_datagram(_local_spdp(lead, 1, declared), LO, 3.0)  # fixed, started again
    assert _undeclared_rows(relay, 3.0) == []
    assert relay.status(3.0)["local"][0]["restarts"] == 1


def test_a_local_forger_filling_the_undeclared_rows_cannot_hide_a_real_endpoint() -> None:
    """Review 18b, a local process of any user (``ros2.node_users`` unset) sends a
    declared node's DATA(p) listing 40 invented undeclared endpoints: the 32 rows
    (``MAX_UNDECLARED_PER_PARTICIPANT``) filled for good, and the node's own undeclared
    writer, in its next DATA(p), was never shown. The rows are what the node's latest
    DATA(p) lists, the first 32 in its own order and a count of the rest: the forgery
    shows until the node's next DATA(p), then the node's own rows are back.
    [fails on main: the real writer is not listed]"""
    lead = _by(_participants(), "lead")
    relay = _relay("lead")
    declared = static_edp_properties(lead)
    real = (*declared, *_extra(range(200, 201)))
    relay.receive_datagram(_local_spdp(lead, 1, real), LO, 0.0)
    forged = (*declared, *_extra(range(1, 41)))
    relay.receive_datagram(_local_spdp(lead, 2, forged), ("::1", 40999), 0.5)
    row = relay.status(0.5)["local"][0]
    assert len(row["undeclared_endpoints"]) == MAX_UNDECLARED_PER_PARTICIPANT
    assert row["undeclared_not_shown"] == 40 - MAX_UNDECLARED_PER_PARTICIPANT
    relay.receive_datagram(_local_spdp(lead, 3, real), LO, 3.0)  # the node's next renewal
    row = relay.status(3.0)["local"][0]
    assert _undeclared_rows(relay, 3.0) == ["0.0.200.3"]
    assert row["undeclared_not_shown"] == 0
    # each row is reported once while it stays listed, again only after it was gone
    reported = [e.entity_id for e in _events(relay) if isinstance(e, UndeclaredEndpoint)]
    assert reported.count("0.0.200.3") == 2 and len(reported) == 2 + MAX_UNDECLARED_PER_PARTICIPANT


def test_peers_without_ros2_nodes_or_address_are_ignored() -> None:
    relay = _relay("lead")
    relay.peer_discovered("drone-1", None, 0.0)
    relay.peer_discovered("nobody", "10.0.0.9", 0.0)
    relay.peer_lost("nobody", 0.0)
    assert relay.datagrams_to_send() == [] and relay.get_timer() is None


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_on_the_relay_port_are_counted_and_dropped(data: bytes) -> None:
    relay = _relay("lead")
    relay.receive_datagram(data, ("::1", 40000), 0.0)
    assert relay.datagrams_to_send() == []
    c = relay.counters
    kinds = ("rx_malformed", "rx_not_spdp", "rx_wlp", "rx_dispose", "rx_unknown")
    assert c["rx"] == 1 and sum(c[k] for k in kinds) <= 1


def test_status_view_lists_local_remote_unknown_and_undeclared_rows_safely() -> None:
    participants = _participants()
    lead = _by(participants, "lead")
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    props = (("eProsimaEDPStatic_Writer_ALIVE_ID_65535", "0.0.1.3"),)
    relay.receive_datagram(_local_spdp(lead, 1, props), ("::1", 40000), 1.0)
    hostile = encode_spdp(
        SpdpParticipant(
            GuidPrefix(bytes(11) + b"\x07"),
            vendor_id=VendorId(b"\x01\x0f"),
            entity_name="evil\x1b[2Jnode",
        ),
        sequence_number=1,
        timestamp=None,
    )
    relay.receive_datagram(hostile, ("::1", 40001), 1.0)
    text = "\n".join(render_status({"ros2": relay.status(2.0)}))
    assert "ros2 relay ::1:7399  lease 8 s  alive bitmap 01" in text
    rows = {line.split()[0] + " " + line.split()[1] for line in text.splitlines()[2:]}
    assert {"this drone", "drone-1 talker", "drone-2 talker", "unknown evil\\x1b[2Jnode"} <= rows
    assert re.search(r"undeclared writer +id 65535 +entity 0\.0\.1\.3 +not in the bundle", text)
    assert "waiting for drone" in text and "relayed" in text
    assert "\x1b" not in text


def test_status_view_shows_the_graph_participant_and_no_hostile_value() -> None:
    view = render_status(
        {
            "ros2": {
                "relay": "::1:7399",
                "graph": {"samples": 2, "readers": 1, "readers_up_to_date": 1},
            }
        }
    )
    assert "ros2 graph: 2 node entries served to 1 local graph readers, 1 up to date" in view
    hostile = render_status(
        {"ros2": {"relay": "::1:7399", "graph": {"samples": "\x1b[2J", "readers": None}}}
    )
    assert "ros2 graph: - node entries served to - local graph readers, - up to date" in hostile
    assert not any("\x1b" in line for line in hostile)


def test_a_local_flood_of_invented_participants_is_reported_at_a_bounded_rate() -> None:
    """Review 16: a local process (any user, without ``ros2.node_users``) cycling more
    invented prefixes than the unknown table holds made each datagram a new participant and
    a ``ros2_unknown_participant`` warning line: journald's rate limit then drops the
    daemon's other lines too. Reported at most ``UNKNOWN_REPORTS_PER_S`` a second (burst
    ``UNKNOWN_REPORT_BURST``), each report saying how many it stands for; the table and
    its counters still see every one."""
    relay = _relay("lead")
    stranger = _by(_participants(), "lead")
    n, flood_s = 400, 2.0
    for i in range(n):
        forged = _invented(stranger, i)
        relay.receive_datagram(_local_spdp(forged, 1), ("::1", 40000), flood_s * i / n)
    reports = [e for e in _events(relay) if isinstance(e, UnknownParticipantHeard)]
    assert len(reports) <= UNKNOWN_REPORT_BURST + UNKNOWN_REPORTS_PER_S * flood_s
    assert relay.counters["rx_unknown"] == n
    assert relay.counters["unknown_suppressed"] == n - len(reports)
    assert sum(r.suppressed for r in reports) <= relay.counters["unknown_suppressed"]
    assert len(relay.status(flood_s)["unknown"]) == MAX_UNKNOWN_PARTICIPANTS


@settings(max_examples=100, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(("node", "dispose", "unknown", "garbage")),
            st.integers(min_value=1, max_value=40),
            st.integers(min_value=1024, max_value=65535),
        ),
        max_size=30,
    )
)
def test_whatever_a_local_sender_sends_the_relay_answers_only_the_bundles_loopback_ports(
    script: list[tuple[str, int, int]],
) -> None:
    """Review 16, held: the relay is no reflector. Whatever a local process sends it (a
    declared node's DATA(p) at any SN, so restarts at will; its dispose; invented
    participants; garbage), from any source port, everything it sends goes to a loopback
    port the bundle gives one of this drone's nodes, never to the sender's port, and one
    datagram draws at most what a node's start draws (every relayed participant, each
    sibling's DATA(p), a dispose and a DATA(p) to each sibling)."""
    participants = _participants()
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 0.0)
    mine = [p for p in participants if p.drone == "lead"]
    allowed = {(LOOPBACK, p.metatraffic_port) for p in mine}
    bound = len(participants) + 3 * len(mine)
    assert {dst for _, dst in relay.datagrams_to_send()} <= allowed
    node = mine[0]
    for t, (kind, sn, port) in enumerate(script):
        now = 0.1 * (t + 1)
        if kind == "node":
            data = _local_spdp(node, sn)
        elif kind == "dispose":
            data = encode_spdp_dispose(
                GuidPrefix(node.guid_prefix), sequence_number=sn, timestamp=None
            )
        elif kind == "unknown":
            data = _local_spdp(_invented(node, sn), 1)
        else:
            data = bytes([sn]) * 40
        relay.receive_datagram(data, (LOOPBACK, port), now)
        out = relay.datagrams_to_send()
        assert {dst for _, dst in out} <= allowed
        assert len(out) <= bound
        relay.handle_timer(now)
        assert {dst for _, dst in relay.datagrams_to_send()} <= allowed
