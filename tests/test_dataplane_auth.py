"""The data plane's trust boundary (issue 10): forged and replayed user data moves nothing.

Each attack of issue 10 on user data, in virtual time on the in-memory network of
``test_dataplane_swarm``: an attacker who sniffed SPDP knows every GUID prefix, entity id
and boot epoch, sees every datagram, and can send anything from anywhere, but holds no pair
key (or, as a captured member, only its own). Each forged datagram must be refused and
counted by reason, leave every reader position, acknowledged set, readiness row and dedup
set as it was, and the real commander must still command afterwards.

Each attack also has a control: the same submessages sealed with the right key are
accepted and do move the state, so the assertions here can fail.
"""

from __future__ import annotations

import copy
import random
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from swarmd.auth.freshness import Freshness
from swarmd.bundle.model import Participant
from swarmd.dataplane import (
    TOPIC_COMMAND,
    TOPIC_OUTCOME,
    CommandKind,
    CommandOutcome,
    CommandReceived,
    CommandResult,
    DataPlane,
    DataPlaneEvent,
    PacketDropped,
    Readiness,
    encode_sample,
)
from swarmd.dataplane.endpoints import MAX_SEQUENCE_NUMBER
from swarmd.dataplane.reader import ReliableReader
from swarmd.dataplane.seal import (
    TAG_BYTES,
    TRAILER_BYTES,
    seal,
    user_data_key,
)
from swarmd.dataplane.writer import ReliableWriter
from swarmd.rtps import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    SequenceNumberSet,
    Submessage,
    encode_message,
)
from swarmd.rtps.types import PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, EntityId, GuidPrefix
from tests.test_dataplane_swarm import (
    Swarm,
    address_of,
    keyring,
    make_bundle,
    make_plane,
    make_swarm,
    send_at,
)

ATTACKER = ("10.0.0.66", 7411)
TOP_SN = (1 << 63) - 1  # the largest SequenceNumber_t
READY_W, READY_R = EntityId.user(1, 0x03), EntityId.user(1, 0x04)
CMD_W, CMD_R = EntityId.user(2, 0x03), EntityId.user(2, 0x04)
OUT_W, OUT_R = EntityId.user(3, 0x03), EntityId.user(3, 0x04)


# --- the attacker's tools -------------------------------------------------------------------


def message(prefix: GuidPrefix, *subs: Submessage) -> bytes:
    return encode_message(Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, prefix), list(subs))


def sealed(
    swarm: Swarm, key_of: str, claimed: Participant, to: str, *subs: Submessage, seq: int
) -> bytes:
    """``subs`` under ``claimed``'s GUID prefix, sealed with the pair key ``key_of`` shares
    with ``to``, with the freshness and epochs the real sender would use now."""
    receiver = swarm.bundle.participant(to)
    key = keyring(swarm.bundle, key_of).pair_key(receiver.guid_prefix)
    assert key is not None
    fresh = Freshness(swarm.epochs.get(claimed.name, 1), seq)
    return seal(
        user_data_key(key),
        message(claimed.guid_prefix, *subs),
        fresh,
        receiver.guid_prefix,
        swarm.epochs.get(to, 1),
    )


def forged(swarm: Swarm, claimed: Participant, to: str, *subs: Submessage, seq: int) -> bytes:
    """What an outsider can make: a well-formed trailer with the right epochs and a fresh
    sequence (all public), and a tag it had to guess."""
    good = sealed(swarm, claimed.name, claimed, to, *subs, seq=seq)
    return good[:-TAG_BYTES] + random.Random(seq).randbytes(TAG_BYTES)


def state(plane: DataPlane) -> dict[str, Any]:
    """Everything a datagram could move: reader positions and buffers, writer proxies
    (acknowledged sets), readiness rows, dedup sets, replay windows."""
    readers = {
        t.name: copy.deepcopy(r.proxies if isinstance(r, ReliableReader) else r.highest)
        for t, r in plane._endpoints.readers.values()
    }
    writers = {
        t.name: (w.last_sn, copy.deepcopy(w.proxies) if isinstance(w, ReliableWriter) else None)
        for t, w in plane._endpoints.writers.values()
    }
    windows = {p: (c.peer_epoch, c.window.high) for p, c in plane._channels.items()}
    return {
        "readers": readers,
        "writers": writers,
        "readiness": copy.deepcopy(plane._readiness),
        "executed": plane._ledger.executed,
        "outcomes": list(plane._ledger._outcomes),
        "windows": windows,
    }


def deliver(swarm: Swarm, to: str, datagram: bytes) -> list[DataPlaneEvent]:
    plane = swarm.planes[to]
    plane.receive_datagram(datagram, ATTACKER, swarm.now)
    events = []
    while (event := plane.next_event()) is not None:
        events.append(event)
    return events


def assert_refused(
    swarm: Swarm, to: str, datagram: bytes, reason: str, *, authentic: bool = False
) -> None:
    """``datagram`` is refused with ``reason``, counted, and moves nothing. An ``authentic``
    one (a captured member under its own name) may move what is its own to move: its
    replay window and its own writers' proxies here; no row, command or outcome."""
    plane = swarm.planes[to]
    before = state(plane)
    counted = plane.counters[f"dropped_{reason}"]
    events = deliver(swarm, to, datagram)
    assert [type(e) for e in events] == [PacketDropped], events
    assert isinstance(events[0], PacketDropped) and events[0].reason == reason
    assert events[0].source == ATTACKER
    assert plane.counters[f"dropped_{reason}"] == counted + 1
    after = state(plane)
    if authentic:
        for moved in ("windows", "readers"):
            before.pop(moved), after.pop(moved)
    assert after == before
    assert plane.datagrams_to_send() == []  # not even an ACKNACK went out


def flying_swarm() -> Swarm:
    """lead + m01 + m02, discovered, readiness flowing, one command executed by all."""
    swarm = make_swarm(2, seed=1)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    first = lead.make_command(CommandKind.HOLD)
    readiness = [
        (0.5, lambda: swarm.planes["m01"].publish_readiness(ready("m01", 1), swarm.now)),
        (0.6, lambda: swarm.planes["m02"].publish_readiness(ready("m02", 1), swarm.now)),
    ]
    swarm.run_until(3.0, [send_at(swarm, 1.0, first), *readiness])
    assert swarm.executed[("m01", first.command_id)] == 1
    return swarm


def ready(node: str, seq: int) -> Readiness:
    return Readiness(node, seq, True, "", False, 1, 3, 12, 80, 900)


def still_commands(swarm: Swarm) -> None:
    """The real commander's next command runs exactly once on every member."""
    cmd = swarm.planes["lead"].make_command(CommandKind.LAND)
    swarm.run_until(swarm.now + 10.0, [send_at(swarm, swarm.now + 0.1, cmd)])
    for m in swarm.members:
        assert swarm.executed[(m, cmd.command_id)] == 1, m
    assert swarm.planes["lead"].get_timer() is None  # and every member acknowledged it


def next_sn(swarm: Swarm, member: str = "m01") -> int:
    lead = swarm.bundle.participant("lead")
    reader = swarm.planes[member]._endpoints.readers[CMD_R][1]
    assert isinstance(reader, ReliableReader)
    return reader.proxies[
        lead.guid(next(e for e in lead.endpoints if e.topic == TOPIC_COMMAND))
    ].next_expected


def takeoff_payload(swarm: Swarm) -> bytes:
    return encode_sample(swarm.planes["lead"].make_command(CommandKind.TAKEOFF, altitude_m=10))


# --- 1. one forged datagram flies a drone ---------------------------------------------------


def test_a_forged_takeoff_under_the_commanders_prefix_is_refused() -> None:
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    m01 = swarm.bundle.participant("m01")
    sn = next_sn(swarm)
    subs = (
        InfoDst(m01.guid_prefix),
        Data(CMD_R, CMD_W, sn, None, takeoff_payload(swarm)),
        Heartbeat(CMD_R, CMD_W, sn, sn, 1000),
    )
    # the 116-byte datagram, as it was: no authenticator at all
    assert_refused(swarm, "m01", message(lead.guid_prefix, *subs), "auth_missing")
    # with a trailer whose every public field is right and a guessed tag
    assert_refused(swarm, "m01", forged(swarm, lead, "m01", *subs, seq=10_000), "auth_failed")
    still_commands(swarm)


def test_control_the_same_takeoff_sealed_by_the_commander_is_executed() -> None:
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    sn = next_sn(swarm)
    subs = (Data(CMD_R, CMD_W, sn, None, takeoff_payload(swarm)),)
    events = deliver(swarm, "m01", sealed(swarm, "lead", lead, "m01", *subs, seq=10_000))
    assert [type(e) for e in events] == [CommandReceived]


# --- 2. locking the real commander out ------------------------------------------------------


@pytest.mark.parametrize(
    "attack",
    [
        Heartbeat(CMD_R, CMD_W, MAX_SEQUENCE_NUMBER, MAX_SEQUENCE_NUMBER, 1 << 31),
        Heartbeat(CMD_R, CMD_W, TOP_SN, TOP_SN, 1 << 31),  # the jump to ~2^63
        Gap(CMD_R, CMD_W, 1, SequenceNumberSet.of(MAX_SEQUENCE_NUMBER, [])),
    ],
    ids=["heartbeat_jump", "heartbeat_jump_2^63", "gap"],
)
def test_a_forged_heartbeat_jump_or_gap_cannot_deafen_a_member(attack: Submessage) -> None:
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    assert_refused(swarm, "m01", message(lead.guid_prefix, attack), "auth_missing")
    assert_refused(swarm, "m01", forged(swarm, lead, "m01", attack, seq=10_000), "auth_failed")
    still_commands(swarm)


def test_control_an_authentic_heartbeat_jump_does_move_the_reader() -> None:
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    hb = Heartbeat(CMD_R, CMD_W, MAX_SEQUENCE_NUMBER, MAX_SEQUENCE_NUMBER, 1 << 31)
    deliver(swarm, "m01", sealed(swarm, "lead", lead, "m01", hb, seq=10_000))
    assert next_sn(swarm) == MAX_SEQUENCE_NUMBER


def test_a_forged_acknack_cannot_stop_the_commanders_repairs() -> None:
    swarm = flying_swarm()
    m01 = swarm.bundle.participant("m01")
    lead = swarm.planes["lead"]
    # a command m01 will never hear: only a forged ACKNACK could make it "acknowledged"
    swarm.cut("m01")
    cmd = lead.make_command(CommandKind.TAKEOFF, altitude_m=5.0)
    swarm.run_until(swarm.now + 0.5, [send_at(swarm, swarm.now + 0.1, cmd)])
    swarm.cut("m01", False)
    everything = SequenceNumberSet.of(MAX_SEQUENCE_NUMBER, [])
    ack = AckNack(CMD_R, CMD_W, everything, 1 << 31, final=True)
    assert_refused(swarm, "lead", message(m01.guid_prefix, ack), "auth_missing")
    assert_refused(swarm, "lead", forged(swarm, m01, "lead", ack, seq=10_000), "auth_failed")
    # the commander still repairs m01: the take-off arrives through heartbeats
    swarm.run_until(swarm.now + 10.0)
    assert swarm.executed[("m01", cmd.command_id)] == 1


# --- 3. the commander's readiness table -----------------------------------------------------


def test_a_forged_readiness_at_a_high_sn_cannot_pin_a_row() -> None:
    swarm = flying_swarm()
    m01 = swarm.bundle.participant("m01")
    high = Data(READY_R, READY_W, MAX_SEQUENCE_NUMBER, None, encode_sample(ready("m01", 99)))
    assert_refused(swarm, "lead", message(m01.guid_prefix, high), "auth_missing")
    assert_refused(swarm, "lead", forged(swarm, m01, "lead", high, seq=10_000), "auth_failed")
    # the real member's next sample still counts
    swarm.run_until(
        swarm.now + 1.0,
        [
            (
                swarm.now + 0.1,
                lambda: swarm.planes["m01"].publish_readiness(ready("m01", 2), swarm.now),
            )
        ],
    )
    row = swarm.planes["lead"].readiness_received("m01")
    assert row is not None and row.last is not None and row.last.seq == 2
    still_commands(swarm)


def test_forged_outcomes_cannot_report_a_command_completed() -> None:
    swarm = flying_swarm()
    m01 = swarm.bundle.participant("m01")
    reader = swarm.planes["lead"]._endpoints.readers[OUT_R][1]
    assert isinstance(reader, ReliableReader)
    writer = m01.guid(next(e for e in m01.endpoints if e.topic == TOPIC_OUTCOME))
    sn = reader.proxies[writer].next_expected
    outcome = CommandOutcome(1, "m01", CommandResult.COMPLETED, "")
    data = Data(OUT_R, OUT_W, sn, None, encode_sample(outcome))
    assert_refused(swarm, "lead", forged(swarm, m01, "lead", data, seq=10_000), "auth_failed")


# --- 5. replay ------------------------------------------------------------------------------


def captured_takeoff(swarm: Swarm) -> tuple[bytes, int]:
    """The commander's real TAKEOFF datagram to m01, as a sniffer recorded it."""
    swarm.net.transmissions.clear()
    cmd = swarm.planes["lead"].make_command(CommandKind.TAKEOFF, altitude_m=10.0)
    swarm.run_until(swarm.now + 2.0, [send_at(swarm, swarm.now + 0.1, cmd)])
    cut = address_of(swarm.bundle, "m01")
    first = next(p for p, _, d in swarm.net.payloads() if d == cut)
    assert swarm.executed[("m01", cmd.command_id)] == 1
    return first, cmd.command_id


def test_a_captured_takeoff_replayed_in_the_same_life_is_refused() -> None:
    swarm = flying_swarm()
    capture, _ = captured_takeoff(swarm)
    assert_refused(swarm, "m01", capture, "auth_replayed")


def test_a_captured_takeoff_never_runs_again_after_the_member_restarts_without_state() -> None:
    swarm = flying_swarm()
    capture, command_id = captured_takeoff(swarm)
    # m01 restarts with its state file gone: no dedup set, no replay windows, a new epoch
    reborn = swarm.restart("m01", incarnation=0)
    swarm.up("m01", "lead")
    swarm.up("lead", "m01")
    swarm.run_until(swarm.now + 1.0)
    # the capture was made for m01's previous epoch: the hint says so, before any MAC
    assert_refused(swarm, "m01", capture, "auth_receiver_epoch")
    # rewriting the hint bits to the new epoch breaks the tag (it covers the flags)
    flags_at = len(capture) - TRAILER_BYTES + 1
    patched = bytearray(capture)
    patched[flags_at] = (patched[flags_at] & 1) | ((swarm.epochs["m01"] & 0x7F) << 1)
    assert_refused(swarm, "m01", bytes(patched), "auth_failed")
    assert swarm.executed[("m01", command_id)] == 1
    assert reborn.counters["commands_received"] == 0
    still_commands(swarm)


def test_datagrams_of_a_senders_earlier_life_are_refused() -> None:
    swarm = flying_swarm()
    capture, _ = captured_takeoff(swarm)
    swarm.restart("lead", incarnation=1)
    swarm.up("lead", "m01")
    swarm.up("lead", "m02")
    swarm.up("m01", "lead")
    assert_refused(swarm, "m01", capture, "auth_stale_epoch")


def test_a_restarted_sender_is_refused_until_its_new_epoch_is_known() -> None:
    swarm = flying_swarm()
    new = swarm.restart("lead", incarnation=1)
    swarm.up("lead", "m01")  # the new commander heard m01; m01 has not yet heard it
    new.send_command(new.make_command(CommandKind.HOLD), swarm.now)
    (datagram, _), *_ = new.datagrams_to_send()
    assert_refused(swarm, "m01", datagram, "auth_epoch_ahead")
    for m in swarm.members:  # its SPDP arrives
        swarm.up("lead", m)
        swarm.up(m, "lead")
    still_commands(swarm)


# --- a captured member ----------------------------------------------------------------------


def test_a_captured_member_cannot_impersonate_the_commander() -> None:
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    m02 = swarm.bundle.participant("m02")
    sn = next_sn(swarm)
    takeoff = Data(CMD_R, CMD_W, sn, None, takeoff_payload(swarm))
    # m02's own key with m01, under the commander's prefix
    as_lead = sealed(swarm, "m02", lead, "m01", takeoff, seq=10_000)
    assert_refused(swarm, "m01", as_lead, "auth_failed")
    # under its own prefix the tag verifies, but m02 is no writer of swarm/command
    as_itself = sealed(swarm, "m02", m02, "m01", takeoff, seq=10_000)
    assert_refused(swarm, "m01", as_itself, "unmatched_writer", authentic=True)
    still_commands(swarm)


def test_a_captured_member_cannot_speak_for_another_member() -> None:
    swarm = flying_swarm()
    m01 = swarm.bundle.participant("m01")
    fake = Data(READY_R, READY_W, 1 << 40, None, encode_sample(ready("m01", 50)))
    assert_refused(
        swarm, "lead", sealed(swarm, "m02", m01, "lead", fake, seq=10_000), "auth_failed"
    )
    # nor name another member in its own, authentic, sample
    m02 = swarm.bundle.participant("m02")
    as_itself = sealed(swarm, "m02", m02, "lead", fake, seq=10_000)
    assert_refused(swarm, "lead", as_itself, "node_mismatch", authentic=True)


# --- any bit flipped ------------------------------------------------------------------------


PAIR_BUNDLE = make_bundle(1)


def fresh_pair(kind: str) -> tuple[Swarm, str, bytes]:
    """Two planes and one authentic datagram the receiver has not seen yet (the same bytes
    on every call: nothing in the planes is random)."""
    planes = {p.name: make_plane(PAIR_BUNDLE, p.name) for p in PAIR_BUNDLE.participants}
    swarm = Swarm(PAIR_BUNDLE, planes)
    swarm.discover_all()
    if kind == "command":
        lead = swarm.planes["lead"]
        lead.send_command(lead.make_command(CommandKind.TAKEOFF, altitude_m=10.0), 0.0)
        return swarm, "m01", lead.datagrams_to_send()[0][0]
    member = swarm.planes["m01"]
    member.publish_readiness(ready("m01", 1), 0.0)
    return swarm, "lead", member.datagrams_to_send()[0][0]


KINDS = ["command", "readiness"]


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kind=st.sampled_from(KINDS), data=st.data())
def test_flipping_any_bit_of_an_authenticated_datagram_gets_it_refused(
    kind: str, data: st.DataObject
) -> None:
    swarm, to, datagram = fresh_pair(kind)
    bits = data.draw(
        st.lists(st.integers(0, 8 * len(datagram) - 1), min_size=1, max_size=3, unique=True)
    )
    mutated = bytearray(datagram)
    for bit in bits:
        mutated[bit // 8] ^= 0x80 >> (bit % 8)
    plane = swarm.planes[to]
    before = state(plane)
    events = deliver(swarm, to, bytes(mutated))
    assert len(events) == 1 and isinstance(events[0], PacketDropped)
    assert state(plane) == before
    assert plane.counters["rx_authenticated"] == 0
    # the forgery burnt nothing: the authentic datagram is still accepted
    events = deliver(swarm, to, datagram)
    assert not any(isinstance(e, PacketDropped) for e in events)
    assert plane.counters["rx_authenticated"] == 1


def test_every_single_bit_flip_of_a_takeoff_is_refused() -> None:
    swarm, to, datagram = fresh_pair("command")
    reasons: set[str] = set()
    plane = swarm.planes[to]
    before = state(plane)
    for bit in range(8 * len(datagram)):
        mutated = bytearray(datagram)
        mutated[bit // 8] ^= 0x80 >> (bit % 8)
        plane.receive_datagram(bytes(mutated), ATTACKER, 0.0)
        event = plane.next_event()
        assert isinstance(event, PacketDropped), bit
        assert plane.next_event() is None
        reasons.add(event.reason)
    assert state(plane) == before
    assert plane.counters["rx_authenticated"] == 0
    assert {"auth_failed", "auth_missing", "decode_error"} <= reasons


# --- what discovery reports -----------------------------------------------------------------


def test_an_epoch_going_back_is_ignored_and_the_old_lifes_datagrams_stay_refused() -> None:
    swarm = flying_swarm()
    capture, _ = captured_takeoff(swarm)
    swarm.restart("lead", incarnation=1)
    for m in swarm.members:
        swarm.up("lead", m)
        swarm.up(m, "lead")
    member = swarm.planes["m01"]
    member.peer_up("lead", address_of(swarm.bundle, "lead"), swarm.now, epoch=1)
    assert member.counters["peer_epoch_went_back"] == 1
    assert member.status(swarm.now)["peer_epochs"]["lead"] == 2
    assert_refused(swarm, "m01", capture, "auth_stale_epoch")
    still_commands(swarm)


def test_a_peer_without_a_pair_key_stays_down() -> None:
    class NoKeys:
        def pair_key(self, peer: GuidPrefix) -> bytes | None:
            return None

    swarm = make_swarm(1)
    plane = DataPlane(swarm.bundle, "lead", keys=NoKeys(), epoch=1)
    plane.peer_up("m01", address_of(swarm.bundle, "m01"), 0.0, epoch=1)
    assert plane.peers_up == [] and plane.counters["peer_without_key"] == 1


def test_a_peer_lost_and_found_in_the_same_epoch_keeps_its_replay_window() -> None:
    swarm = flying_swarm()
    capture, _ = captured_takeoff(swarm)
    member = swarm.planes["m01"]
    member.peer_down("lead", swarm.now)
    swarm.up("m01", "lead")
    assert_refused(swarm, "m01", capture, "auth_replayed")
