"""Graph preloading's core (swarmd.ros2.graph) on hand-set time: the ParticipantEntitiesInfo
codec against a sample captured from real rclpy 9.1 / Fast DDS 3.2, arbitrary bytes, and the
writer's DATA/HEARTBEAT/ACKNACK exchange with a local reader. The real-process test is
tests/test_ros2_graph_netns.py."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import Ros2EndpointKind, Ros2Participant, bundle_ros2_participants
from swarmd.ros2.graph import (
    MIN_RESEND_S,
    GraphWriter,
    decode_entities_info,
    encode_entities_info,
    entities_info,
    graph_endpoint_id,
)
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.message import (
    AckNack,
    Data,
    Header,
    Heartbeat,
    InfoDst,
    SequenceNumberSet,
    decode_message,
    encode_message,
)
from swarmd.rtps.types import GuidPrefix, ProtocolVersion, VendorId

REPO = Path(__file__).resolve().parent.parent
MISSION = (REPO / "firmware_bundle" / "missions" / "swarm3-ros2.yaml").read_text()
EPOCH = 7

# the serialized payload of a ros_discovery_info DATA sent by a default rclpy 9.1 talker
# (Fast DDS 3.2.2, UDPv4 on lo, captured with tshark):
#   61 1.126640567 127.0.0.1 -> 127.0.0.1 RTPS 290 INFO_DST, INFO_TS, DATA -> ros_discovery_info
# padding after "talker\0" is 0x7f: rmw leaves it uninitialised
GOLDEN = bytes.fromhex(
    "00010000010f7f01d824326200000000000001c101000000020000002f0000000700000074616c6b65"
    "72007f01000000010f7f01d8243262000000000000050403000000010f7f01d824326200000000000003"
    "03010f7f01d82432620000000000000403010f7f01d82432620000000000000603"
)


def _participants() -> tuple[Ros2Participant, ...]:
    return bundle_ros2_participants(build_dev_bundle(parse_mission(MISSION)).bundle)


def test_golden_sample_from_rclpy_parses_field_by_field() -> None:
    info = decode_entities_info(GOLDEN)
    prefix = bytes.fromhex("010f7f01d824326200000000")
    assert info.gid == prefix + bytes.fromhex("000001c1")
    (node,) = info.nodes
    assert (node.namespace, node.name) == ("/", "talker")
    assert node.reader_gids == (prefix + bytes.fromhex("00000504"),)
    assert node.writer_gids == tuple(
        prefix + bytes.fromhex(x) for x in ("00000303", "00000403", "00000603")
    )
    # re-encoded with zero padding: the same bytes but that one padding octet
    again = encode_entities_info(info)
    assert len(again) == len(GOLDEN)
    assert [i for i in range(len(GOLDEN)) if again[i] != GOLDEN[i]] == [GOLDEN.index(b"talker") + 7]


def test_every_proper_prefix_of_the_golden_sample_is_a_decode_error() -> None:
    for n in range(len(GOLDEN)):
        with pytest.raises(DecodeError):
            decode_entities_info(GOLDEN[:n])


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_arbitrary_bytes_parse_or_raise_decode_error(data: bytes) -> None:
    try:
        decode_entities_info(data)
    except DecodeError:
        pass


@settings(max_examples=100, deadline=None)
@given(st.sampled_from(_participants()))
def test_the_bundles_samples_round_trip(p: Ros2Participant) -> None:
    info = entities_info(p)
    assert decode_entities_info(encode_entities_info(info)) == info
    (node,) = info.nodes
    assert node.name == p.node.name
    # every endpoint but the graph topic's own two
    assert len(node.reader_gids) + len(node.writer_gids) == len(p.endpoints) - 2


def _acknack(local: Ros2Participant, remote: Ros2Participant, base: int, bits: list[int]) -> bytes:
    header = Header(ProtocolVersion(2, 3), VendorId(b"\x01\x0f"), GuidPrefix(local.guid_prefix))
    return encode_message(
        header,
        [
            InfoDst(GuidPrefix(remote.guid_prefix)),
            AckNack(
                graph_endpoint_id(local, Ros2EndpointKind.READER),
                graph_endpoint_id(remote, Ros2EndpointKind.WRITER),
                SequenceNumberSet.of(base, bits, num_bits=len(bits) and (max(bits) - base + 1)),
                1,
            ),
        ],
    )


def test_writer_offers_heartbeats_until_acknowledged_and_answers_acknacks() -> None:
    participants = _participants()
    lead = next(p for p in participants if p.drone == "lead")
    remote = next(p for p in participants if p.drone == "drone-1")
    writer = GraphWriter(participants, "lead", period_s=5.0, epoch=EPOCH)
    assert writer.get_timer() is None
    writer.remote_up("drone-1", 0.0)
    out = writer.datagrams_to_send()
    assert {dest for _, dest in out} == {("::1", lead.user_port)}
    first = decode_message(out[0][0])
    assert first.header.guid_prefix == GuidPrefix(remote.guid_prefix)
    data = next(sm for sm in first.submessages if isinstance(sm, Data))
    assert data.writer_id == graph_endpoint_id(remote, Ros2EndpointKind.WRITER)
    assert data.writer_sn == (EPOCH << 32) + 1
    assert data.serialized_payload is not None
    assert decode_entities_info(data.serialized_payload) == entities_info(remote)
    # not acknowledged: heartbeats, backing off
    t1 = writer.get_timer()
    assert t1 is not None and t1 == pytest.approx(0.5)
    writer.handle_timer(t1)
    hb = [sm for d, _ in writer.datagrams_to_send() for sm in decode_message(d).submessages]
    assert [type(sm) for sm in hb] == [InfoDst, Heartbeat]
    assert writer.get_timer() == pytest.approx(t1 + 1.0)
    sn = (EPOCH << 32) + 1
    # a NACK of the sample: DATA again, once per MIN_RESEND_S
    assert writer.receive_datagram(_acknack(lead, remote, sn, [sn]), 2.0)
    assert len(writer.datagrams_to_send()) == 1
    assert writer.receive_datagram(_acknack(lead, remote, sn, [sn]), 2.0 + MIN_RESEND_S / 2)
    assert writer.datagrams_to_send() == []
    assert writer.counters["graph_resend_limited"] == 1
    # acknowledged: no more heartbeats
    assert writer.receive_datagram(_acknack(lead, remote, sn + 1, []), 3.0)
    assert writer.get_timer() is None
    # lost: nothing served for it, its ACKNACKs ignored
    writer.remote_down("drone-1")
    assert writer.receive_datagram(_acknack(lead, remote, sn, [sn]), 4.0)
    assert writer.datagrams_to_send() == []


def test_an_acknack_from_a_foreign_prefix_or_for_an_unknown_writer_moves_nothing() -> None:
    participants = _participants()
    lead = next(p for p in participants if p.drone == "lead")
    remote = next(p for p in participants if p.drone == "drone-1")
    writer = GraphWriter(participants, "lead", period_s=5.0, epoch=EPOCH)
    writer.remote_up("drone-1", 0.0)
    writer.datagrams_to_send()
    sn = (EPOCH << 32) + 1
    # from drone-1's own prefix (not a local node): counted, nothing sent
    assert writer.receive_datagram(_acknack(remote, remote, sn + 1, []), 1.0)
    assert writer.counters["graph_rx_ignored"] == 1
    assert writer.get_timer() is not None  # still not acknowledged
    # for a writer no bundle has: not ours
    assert not writer.receive_datagram(_acknack(lead, lead, sn, [sn]), 1.0)
    assert not writer.receive_datagram(b"RTPS garbage", 1.0)
    assert writer.datagrams_to_send() == []
