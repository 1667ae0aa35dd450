"""DataPlane at its edges: hostile datagrams, misaddressed submessages, misuse, imports."""

from __future__ import annotations

import ast
import itertools
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.auth.freshness import Freshness
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.model import Participant
from swarmd.dataplane import (
    CommandKind,
    CommandReceived,
    DataPlane,
    DataPlaneEvent,
    PacketDropped,
    Readiness,
    ReadinessReceived,
    encode_sample,
)
from swarmd.dataplane.early import EARLY_HOLD_S
from swarmd.dataplane.seal import seal, user_data_key
from swarmd.rtps import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    InfoTs,
    SequenceNumberSet,
    Submessage,
    encode_message,
)
from swarmd.rtps.types import (
    PROTOCOLVERSION_SWARMD,
    VENDORID_SWARMD,
    EntityId,
    GuidPrefix,
    Time,
)
from tests.test_dataplane_swarm import address_of, keyring, make_bundle, make_plane

SRC = ("10.0.0.2", 7413)
BUNDLE = make_bundle(2)
LEAD = BUNDLE.participant("lead")
M1 = BUNDLE.participant("m01")
M2 = BUNDLE.participant("m02")
READY_W = EntityId.user(1, 0x03)  # topic 0 (swarm/ready): writer / reader
READY_R = EntityId.user(1, 0x04)
CMD_W = EntityId.user(2, 0x03)
CMD_R = EntityId.user(2, 0x04)


def lead_plane() -> DataPlane:
    plane = make_plane(BUNDLE, "lead")
    for m in ("m01", "m02"):
        plane.peer_up(m, address_of(BUNDLE, m), 0.0, epoch=1)
    return plane


_SEQ = itertools.count(1)


def from_peer(prefix: GuidPrefix, *subs: Submessage, to: Participant = LEAD) -> bytes:
    """A datagram from ``prefix`` to ``to``, sealed with their pair key when they have one
    (epoch 1 on both ends, a sequence no earlier call used)."""
    message = encode_message(Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, prefix), list(subs))
    key = keyring(BUNDLE, to.name).pair_key(prefix)
    if key is None:
        return message
    return seal(user_data_key(key), message, Freshness(1, next(_SEQ)), to.guid_prefix, 1)


def readiness(node: str, seq: int = 1) -> bytes:
    return encode_sample(Readiness(node, seq, True, "", False, 1, 3, 10, 50, 700))


def drain(plane: DataPlane) -> list[DataPlaneEvent]:
    events = []
    while (e := plane.next_event()) is not None:
        events.append(e)
    return events


def drops(plane: DataPlane) -> list[str]:
    return [e.reason for e in drain(plane) if isinstance(e, PacketDropped)]


def test_a_member_readiness_reaches_the_commander() -> None:
    plane = lead_plane()
    plane.receive_datagram(
        from_peer(
            M1.guid_prefix,
            InfoDst(LEAD.guid_prefix),
            InfoTs(Time(1, 0)),
            Data(READY_R, READY_W, 1, None, readiness("m01")),
        ),
        SRC,
        1.0,
    )
    (event,) = drain(plane)
    assert isinstance(event, ReadinessReceived)
    assert event.node == "m01" and event.count == 1 and event.sample.link_q_permille == 700


@pytest.mark.parametrize(
    ("datagram", "reason"),
    [
        (b"RTPS\x02", "decode_error"),
        (b"garbage that is long enough to hold a header", "decode_error"),
        (from_peer(LEAD.guid_prefix), "own"),
        (from_peer(GuidPrefix(b"\x01\x10" + bytes(10))), "unknown_participant"),
        # right GUID prefix, but the member claims to be someone else
        (
            from_peer(M1.guid_prefix, Data(READY_R, READY_W, 1, None, readiness("m02"))),
            "node_mismatch",
        ),
        # a member is no writer of swarm/command: no match in the bundle
        (
            from_peer(M1.guid_prefix, Data(CMD_R, CMD_W, 1, None, b"\x00\x01\x00\x00")),
            "unmatched_writer",
        ),
        (
            from_peer(M1.guid_prefix, Data(READY_R, READY_W, 1, None, b"\x00\x03\x00\x00")),
            "bad_payload",
        ),
        (
            from_peer(M1.guid_prefix, Data(READY_R, READY_W, 0, None, readiness("m01"))),
            "invalid_sn",
        ),
        (from_peer(M1.guid_prefix, Data(READY_R, READY_W, 1)), "no_payload"),
        (
            from_peer(
                M1.guid_prefix,
                InfoDst(M2.guid_prefix),
                Data(READY_R, READY_W, 1, None, readiness("m01")),
            ),
            "not_for_us",
        ),
        (
            from_peer(M1.guid_prefix, AckNack(READY_R, READY_W, SequenceNumberSet.of(1, []), 1)),
            "unmatched_acknack",
        ),
    ],
)
def test_bad_input_is_dropped_with_a_reason(datagram: bytes, reason: str) -> None:
    plane = lead_plane()
    plane.receive_datagram(datagram, SRC, 1.0)
    assert drops(plane) == [reason]
    assert plane.counters[f"dropped_{reason}"] == 1
    assert plane.datagrams_to_send() == []


def test_datagrams_from_a_peer_discovery_has_not_reported_are_held_not_taken() -> None:
    """A peer discovery has not reported up moves nothing: its datagram is held (early.py)
    and dropped ``peer_not_up`` unless discovery reports it within ``EARLY_HOLD_S``; then
    it is checked and taken as if just received."""
    plane = make_plane(BUNDLE, "lead")
    plane.receive_datagram(
        from_peer(M1.guid_prefix, Data(READY_R, READY_W, 1, None, readiness("m01"))), SRC, 0.0
    )
    assert drops(plane) == []
    assert plane.readiness_received("m01") is None
    plane.peer_up("m01", address_of(BUNDLE, "m01"), EARLY_HOLD_S + 0.1, epoch=1)
    assert drops(plane) == ["peer_not_up"]
    assert plane.readiness_received("m01") is None
    plane.peer_down("m01", 2.0)
    plane.receive_datagram(
        from_peer(M1.guid_prefix, Data(READY_R, READY_W, 2, None, readiness("m01"))), SRC, 3.0
    )
    assert drops(plane) == []
    assert plane.readiness_received("m01") is None
    plane.peer_up("m01", address_of(BUNDLE, "m01"), 3.0 + EARLY_HOLD_S, epoch=1)
    stats = plane.readiness_received("m01")
    assert stats is not None and stats.count == 1


def test_misuse_by_the_owner_is_a_clear_value_error() -> None:
    member = make_plane(BUNDLE, "m01")
    with pytest.raises(ValueError, match="no writer on 'swarm/command'"):
        member.send_command(member.make_command(CommandKind.LAND), 0.0)
    with pytest.raises(ValueError, match="readiness of 'm02' published by 'm01'"):
        member.publish_readiness(Readiness("m02", 1, True, "", False, 1, 3, 1, 1, 1), 0.0)
    with pytest.raises(ValueError, match="names this node itself"):
        member.peer_up("m01", ("10.0.0.2", 7413), 0.0, epoch=1)
    with pytest.raises(ValueError, match="incarnation"):
        make_plane(BUNDLE, "m01", incarnation=-1)


def test_a_bundle_declaring_another_type_on_a_swarmd_topic_is_refused() -> None:
    text = """\
swarm: t
domain_id: 0
participants:
  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}
  - {name: m1, index: 1, role: member, mavlink_sysid: 2}
topics:
  - {name: swarm/command, type: 'other::Command', reliability: reliable,
     writers: commander, readers: member}
"""
    bundle = build_dev_bundle(parse_mission(text)).bundle
    with pytest.raises(ValueError, match="'swarm/command' declares type 'other::Command'"):
        make_plane(bundle, "m1")


def test_topics_the_plane_does_not_carry_are_left_alone() -> None:
    mission = Path(__file__).parent.parent / "firmware_bundle" / "missions" / "swarm10.yaml"
    bundle = build_dev_bundle(parse_mission(mission.read_text())).bundle
    lead = bundle.participants[0].name
    plane = make_plane(bundle, lead)
    assert set(plane.status(0.0)["writers"]) == {"swarm/command"}
    assert set(plane.status(0.0)["readers"]) == {"swarm/ready", "swarm/outcome"}


def test_a_command_is_delivered_once_even_when_resent_under_a_new_sn() -> None:
    member = make_plane(BUNDLE, "m01")
    member.peer_up("lead", address_of(BUNDLE, "lead"), 0.0, epoch=1)
    cmd = encode_sample(make_plane(BUNDLE, "lead").make_command(CommandKind.TAKEOFF, altitude_m=5))
    for sn in (1, 1, 2):
        member.receive_datagram(
            from_peer(LEAD.guid_prefix, Data(CMD_R, CMD_W, sn, None, cmd), to=M1), SRC, 0.0
        )
    assert [type(e).__name__ for e in drain(member)] == ["CommandReceived"]
    assert member.counters["duplicate_sample"] == 1 and member.counters["command_duplicate"] == 1


# --- never raises ---------------------------------------------------------------------------

prefixes = st.sampled_from(
    [LEAD.guid_prefix, M1.guid_prefix, M2.guid_prefix, GuidPrefix(bytes(12))]
)
entity_ids = st.sampled_from(
    [READY_W, READY_R, CMD_W, CMD_R, EntityId(bytes(4)), EntityId.user(3, 4)]
)
sns = st.one_of(
    st.integers(-2, 12), st.integers(-(2**63), 2**63 - 1), st.sampled_from([2**63 - 2, 2**63 - 1])
)
sn_sets = st.builds(
    lambda base, bits, members: SequenceNumberSet.of(
        base, [base + m for m in members if m < bits], bits
    ),
    st.integers(-(2**40), 2**62),
    st.integers(0, 256),
    st.lists(st.integers(0, 255), max_size=8),
)
payloads = st.one_of(
    st.none(),
    st.binary(min_size=4, max_size=64),
    st.sampled_from([readiness("m01"), readiness("m02"), readiness("lead")]),
)
submessages = st.one_of(
    st.builds(InfoDst, prefixes),
    st.builds(Data, entity_ids, entity_ids, sns, st.none(), payloads),
    st.builds(
        Heartbeat, entity_ids, entity_ids, sns, sns, st.integers(0, 2**32 - 1), st.booleans()
    ),
    st.builds(AckNack, entity_ids, entity_ids, sn_sets, st.integers(0, 2**32 - 1), st.booleans()),
    st.builds(Gap, entity_ids, entity_ids, sns, sn_sets),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(prefixes, st.lists(submessages, max_size=6)), max_size=6))
def test_structured_hostile_traffic_never_raises(
    datagrams: list[tuple[GuidPrefix, list[Submessage]]],
) -> None:
    for name in ("lead", "m01"):
        plane = make_plane(BUNDLE, name)
        for peer in ("lead", "m01", "m02"):
            if peer != name:
                plane.peer_up(peer, address_of(BUNDLE, peer), 0.0, epoch=1)
        if name == "lead":
            plane.send_command(plane.make_command(CommandKind.HOLD), 0.0)
        now = 0.0
        for prefix, subs in datagrams:
            now += 0.1
            plane.receive_datagram(from_peer(prefix, *subs, to=plane.local), SRC, now)
            plane.handle_timer(now)
            for payload, _ in plane.datagrams_to_send():
                assert len(payload) <= 1400
            for event in drain(plane):
                assert not isinstance(event, CommandReceived) or name == "m01"
        plane.status(now)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    plane = lead_plane()
    plane.receive_datagram(data, SRC, 0.0)
    plane.receive_datagram(from_peer(M1.guid_prefix)[:20] + data, SRC, 0.0)
    assert all(isinstance(e, PacketDropped | ReadinessReceived) for e in drain(plane))


# --- the sans-IO boundary -------------------------------------------------------------------


def test_dataplane_source_imports_no_io_or_clock() -> None:
    package = Path(__file__).parent.parent / "swarmd" / "dataplane"
    forbidden = {"asyncio", "socket", "time", "selectors", "threading"}
    for path in package.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not {n.split(".")[0] for n in names} & forbidden, f"{path.name} imports {names}"


def test_importing_the_dataplane_pulls_in_no_event_loop_or_sockets() -> None:
    code = "import sys, swarmd.dataplane; print(sorted({'asyncio', 'socket'} & set(sys.modules)))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.strip() == "[]"


def test_sequence_numbers_at_the_top_of_the_range_cannot_break_the_encoder() -> None:
    member = make_plane(BUNDLE, "m01")
    member.peer_up("lead", address_of(BUNDLE, "lead"), 0.0, epoch=1)
    top = 2**63 - 1
    cmd = encode_sample(make_plane(BUNDLE, "lead").make_command(CommandKind.HOLD))
    for sm in (
        Heartbeat(CMD_R, CMD_W, top, top, 1),
        Data(CMD_R, CMD_W, top, None, cmd),
        Heartbeat(CMD_R, CMD_W, top, top, 2),
        Gap(CMD_R, CMD_W, top, SequenceNumberSet.of(top, [])),
    ):
        member.receive_datagram(from_peer(LEAD.guid_prefix, sm, to=M1), SRC, 0.0)
        member.datagrams_to_send()
    assert "invalid_sn" in drops(member)
