"""CDR payloads of the user-data types: exact bytes, padding, bounds, round trips, garbage."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, replace
from typing import Any

import pytest
from cyclonedds_idl import IdlStruct
from cyclonedds_idl._support import Endianness
from cyclonedds_idl.types import uint8, uint64
from hypothesis import given
from hypothesis import strategies as st

from swarmd.dataplane.endpoints import TOPIC_TYPES
from swarmd.dataplane.types import (
    MAX_ALTITUDE_M,
    MAX_NAME_CHARS,
    MAX_REASON_CHARS,
    MAX_TARGETS,
    MAX_VALID_MS,
    OUTCOME_NOT_SAVED,
    TYPES_BY_NAME,
    Command,
    CommandKind,
    CommandOutcome,
    CommandResult,
    NodeName,
    PayloadError,
    Readiness,
    Reason,
    Sample,
    TimeEcho,
    decode_sample,
    encode_sample,
)


def ready(**changes: Any) -> Readiness:
    fields: dict[str, Any] = {
        "node": "uav1",
        "seq": 1,
        "ready": True,
        "reason": "",
        "armed": False,
        "landed_state": 1,
        "gps_fix": 3,
        "satellites": 12,
        "battery_pct": 80,
        "link_q_permille": 900,
    }
    fields.update(changes)
    return Readiness(**fields)


def test_type_names_match_the_bundle_declarations() -> None:
    assert {cls.__idl_typename__ for cls in TYPES_BY_NAME.values()} == set(TYPES_BY_NAME)
    assert set(TOPIC_TYPES.values()) == set(TYPES_BY_NAME)


def test_readiness_bytes_follow_xcdr1_alignment() -> None:
    # ... u16 link_q ends at 32: the u32 stamp (issue 18, the member's clock) needs no pad
    body = struct.pack(
        "<I5s3xI?3xI1s?BBBbHI", 5, b"uav1\0", 1, True, 1, b"\0", False, 1, 3, 12, 80, 900, 0
    )
    assert encode_sample(ready()) == b"\x00\x01\x00\x00" + body  # CDR_LE, no padding needed


def test_command_body_is_padded_and_options_say_by_how_much() -> None:
    cmd = Command(1, CommandKind.TAKEOFF, 10.0, ["a"], 3000, [TimeEcho("a", 7, 40, 2)])
    # u64 id, enum as u32, float32, sequence length, string length, "a\0": 26 octets, then
    # u32 valid_ms aligned to 4, the echoes' length and one TimeEcho (string, u32 stamp,
    # u32 age, u32 epoch): 58
    body = struct.pack(
        "<QIfII2s2xIII2s2xIII", 1, 0, 10.0, 1, 2, b"a\0", 3000, 1, 2, b"a\0", 7, 40, 2
    )
    payload = encode_sample(cmd)
    assert payload == b"\x00\x01\x00\x00" + body
    assert decode_sample(payload, Command) == cmd
    bare = Command(1, CommandKind.LAND, 0.0, ["ab"])  # 27 octets of body, then valid_ms, []
    body = struct.pack("<QIfII3sxII", 1, 1, 0.0, 1, 3, b"ab\0", 0, 0)
    assert encode_sample(bare) == b"\x00\x01\x00\x00" + body
    # a body that ends off a 4-octet boundary: an outcome's reason "x" ends at 30 octets
    out = CommandOutcome(7, "uav1", CommandResult.REJECTED, "x")
    body = struct.pack("<QI5s3xII2s", 7, 5, b"uav1\0", 2, 2, b"x\0")
    assert encode_sample(out) == b"\x00\x01\x00\x02" + body + b"\x00\x00"


def test_an_echo_without_its_epoch_is_refused_not_misread() -> None:
    """The layout before the echo named its life (string, u32 stamp, u32 age): a peer of
    that build is 4 octets short at the end, so its command is refused, never read with
    another field as the epoch; so is every proper prefix of the new layout's body."""
    old = struct.pack("<QIfII2s2xIII2s2xII", 1, 0, 10.0, 1, 2, b"a\0", 3000, 1, 2, b"a\0", 7, 40)
    with pytest.raises(PayloadError):
        decode_sample(b"\x00\x01\x00\x00" + old, Command)
    payload = encode_sample(
        Command(1, CommandKind.TAKEOFF, 10.0, ["a"], 3000, [TimeEcho("a", 7, 40, 2)])
    )
    for end in range(4, len(payload)):
        with pytest.raises(PayloadError):
            decode_sample(payload[:end], Command)


@pytest.mark.parametrize("padding", [1, 2, 3])
def test_decoder_strips_exactly_the_announced_padding(padding: int) -> None:
    out = CommandOutcome(7, "uav1", CommandResult.REJECTED, "x")
    raw = out.serialize(endianness=Endianness.Little)
    payload = raw[:3] + bytes([padding]) + raw[4:] + bytes(padding)
    assert decode_sample(payload, CommandOutcome) == out


def test_big_endian_cdr_from_a_peer_is_accepted() -> None:
    cmd = Command(2**40 + 3, CommandKind.ABORT, 0.0, ["m1", "m2"])
    raw = cmd.serialize(endianness=Endianness.Big, use_version_2=False)
    assert raw[:2] == b"\x00\x00"
    assert decode_sample(raw, Command) == cmd


@pytest.mark.parametrize("encapsulation", [b"\x00\x03", b"\x00\x07", b"\x00\x09", b"\xff\xff"])
def test_other_encapsulations_are_refused(encapsulation: bytes) -> None:
    payload = encapsulation + encode_sample(ready())[2:]
    with pytest.raises(PayloadError, match="encapsulation"):
        decode_sample(payload, Readiness)


@pytest.mark.parametrize(
    ("sample", "field"),
    [
        (ready(node="n" * (MAX_NAME_CHARS + 1)), "node"),
        (ready(reason="r" * (MAX_REASON_CHARS + 1)), "reason"),
        (ready(node="a\0b"), "node"),
        (ready(battery_pct=101), "battery_pct"),
        (ready(battery_pct=-2), "battery_pct"),
        (ready(link_q_permille=1001), "link_q_permille"),
        (ready(gps_fix=256), "gps_fix"),
        (ready(seq=-1), "seq"),
        (Command(1, CommandKind.TAKEOFF, 0.0, []), "altitude"),
        (Command(1, CommandKind.TAKEOFF, MAX_ALTITUDE_M + 1, []), "altitude"),
        (Command(1, CommandKind.LAND, math.nan, []), "altitude"),
        (Command(1, CommandKind.LAND, 0.0, ["m"] * (MAX_TARGETS + 1)), "targets"),
        (Command(2**64, CommandKind.LAND, 0.0, []), "command_id"),
        (Command(1, CommandKind.LAND, 0.0, [], 3000, [TimeEcho("m", 0, 0, 2**32)]), "epoch"),
        (Command(1, CommandKind.LAND, 0.0, [], 3000, [TimeEcho("m", 0, 0, -1)]), "epoch"),
        (CommandOutcome(1, "", CommandResult.FAILED, "f" * 200), "reason"),
    ],
)
def test_encode_refuses_out_of_bounds_fields(sample: Sample, field: str) -> None:
    with pytest.raises(PayloadError, match=field):
        encode_sample(sample)


def test_decode_validates_what_the_idl_layer_lets_through() -> None:
    # The IDL layer does not enforce string<64>: a peer's over-long name must still fail.
    name = b"x" * (MAX_NAME_CHARS + 4) + b"\0"  # 69 octets: a 3-octet pad follows
    raw = struct.pack(f"<QI{len(name)}s3xII1s", 1, len(name), name, 0, 1, b"\0")
    with pytest.raises(PayloadError, match="node"):
        decode_sample(b"\x00\x01\x00\x00" + raw, CommandOutcome)
    short = struct.pack("<QI5s3xII1s", 1, 5, b"uav1\0", 0, 1, b"\0")
    assert decode_sample(b"\x00\x01\x00\x00" + short, CommandOutcome).node == "uav1"


names = st.text(st.characters(blacklist_characters="\0", codec="utf-8"), max_size=16)
readiness_st = st.builds(
    Readiness,
    node=names,
    seq=st.integers(0, 2**32 - 1),
    ready=st.booleans(),
    reason=names,
    armed=st.booleans(),
    landed_state=st.integers(0, 255),
    gps_fix=st.integers(0, 255),
    satellites=st.integers(0, 255),
    battery_pct=st.integers(-1, 100),
    link_q_permille=st.integers(0, 1000),
)
u32 = st.integers(0, 2**32 - 1)
echo_st = st.builds(TimeEcho, node=names, stamp_ms=u32, age_ms=u32, epoch=u32)
command_st = st.one_of(
    st.builds(
        Command,
        command_id=st.integers(0, 2**64 - 1),
        kind=st.just(CommandKind.TAKEOFF),
        altitude_m=st.floats(0.5, MAX_ALTITUDE_M, width=32),
        targets=st.lists(names, max_size=5),
        valid_ms=st.integers(0, MAX_VALID_MS),
        echoes=st.lists(echo_st, max_size=3),
    ),
    st.builds(
        Command,
        command_id=st.integers(0, 2**64 - 1),
        kind=st.sampled_from([CommandKind.LAND, CommandKind.HOLD, CommandKind.ABORT]),
        altitude_m=st.just(0.0),
        targets=st.lists(names, max_size=5),
        valid_ms=st.integers(0, MAX_VALID_MS),
        echoes=st.lists(echo_st, max_size=3),
    ),
)
outcome_st = st.builds(
    CommandOutcome,
    command_id=st.integers(0, 2**64 - 1),
    node=names,
    result=st.sampled_from(list(CommandResult)),
    reason=names,
    flags=st.one_of(st.just(0), st.integers(0, 255)),
    save_gen=st.one_of(st.just(0), st.integers(0, 2**32 - 1)),
)


@given(st.one_of(readiness_st, command_st, outcome_st))
def test_round_trip(sample: Sample) -> None:
    payload = encode_sample(sample)
    assert payload[:2] == b"\x00\x01" and len(payload) % 4 == 0
    # an outcome without flags or save_gen is written without them (the earlier layout)
    if isinstance(sample, CommandOutcome) and not (sample.flags or sample.save_gen):
        body = len(_earlier(sample).serialize()) - 4
    else:
        body = len(sample.serialize()) - 4
    assert len(payload) - 4 - (payload[3] & 0x03) == body
    assert decode_sample(payload, type(sample)) == sample


@given(st.binary(max_size=120), st.sampled_from(sorted(TYPES_BY_NAME)))
def test_garbage_payload_raises_only_payload_error(data: bytes, type_name: str) -> None:
    try:
        decode_sample(data, TYPES_BY_NAME[type_name])
    except PayloadError:
        pass


@given(
    st.one_of(readiness_st, command_st, outcome_st),
    st.lists(st.tuples(st.integers(0, 200), st.integers(0, 255)), min_size=1, max_size=4),
    st.integers(0, 200),
)
def test_corrupted_payload_decodes_valid_or_raises_payload_error(
    sample: Sample, flips: list[tuple[int, int]], cut: int
) -> None:
    payload = bytearray(encode_sample(sample))
    for offset, value in flips:
        if offset < len(payload):
            payload[offset] = value
    try:
        decoded = decode_sample(bytes(payload[: len(payload) - cut % 8]), type(sample))
    except PayloadError:
        return
    encode_sample(decoded)  # whatever got through is a valid sample again


@dataclass
class EarlierOutcome(IdlStruct, typename="swarmd::CommandOutcome"):
    """``swarmd::CommandOutcome`` as builds before session 14 declare it: no ``flags``."""

    command_id: uint64
    node: NodeName
    result: CommandResult
    reason: Reason


@dataclass
class Session14Outcome(IdlStruct, typename="swarmd::CommandOutcome"):
    """``swarmd::CommandOutcome`` as session 14 declares it: ``flags``, no ``save_gen``."""

    command_id: uint64
    node: NodeName
    result: CommandResult
    reason: Reason
    flags: uint8 = 0


def _earlier(outcome: CommandOutcome) -> EarlierOutcome:
    return EarlierOutcome(outcome.command_id, outcome.node, outcome.result, outcome.reason)


def _earlier_payload(outcome: EarlierOutcome | Session14Outcome) -> bytes:
    raw = outcome.serialize(endianness=Endianness.Little, use_version_2=False)
    padding = -len(raw) % 4
    return raw[:2] + bytes((0, padding)) + raw[4:] + bytes(padding)


def _session14_payload(outcome: Session14Outcome) -> bytes:
    """Session 14's encoder: the flags octet only when a flag is set."""
    if not outcome.flags:
        return _earlier_payload(
            EarlierOutcome(outcome.command_id, outcome.node, outcome.result, outcome.reason)
        )
    return _earlier_payload(outcome)


def _session14_decode(body: bytes) -> Session14Outcome:
    """Session 14's decoder: its layout, else the earlier one as flags 0."""
    try:
        return Session14Outcome.deserialize(body, has_header=True)
    except Exception:  # noqa: BLE001 - as session 14's decode_sample
        old = EarlierOutcome.deserialize(body, has_header=True)
        return Session14Outcome(old.command_id, old.node, old.result, old.reason)


@given(outcome_st)
def test_outcomes_cross_builds_both_ways(outcome: CommandOutcome) -> None:
    """The flags octet and ``save_gen`` are written only when one of them is set: an
    unflagged outcome is the earlier builds' bytes exactly; an earlier build (before
    session 14, and session 14's) reads a flagged one and ignores what it does not know
    (the IDL layer leaves the tail unread); this build reads each earlier build's outcome,
    with flags 0 or session 14's flags, and ``save_gen`` 0 (docs/wire.md, "The outcome's
    flags")."""
    earlier = _earlier(outcome)
    payload = encode_sample(outcome)
    if not (outcome.flags or outcome.save_gen):
        assert payload == _earlier_payload(earlier)
    body_end = len(payload) - (payload[3] & 0x03)
    assert EarlierOutcome.deserialize(payload[:body_end], has_header=True) == earlier
    s14 = _session14_decode(payload[:body_end])
    assert s14 == Session14Outcome(
        outcome.command_id, outcome.node, outcome.result, outcome.reason, outcome.flags
    )
    back = decode_sample(_earlier_payload(earlier), CommandOutcome)
    assert (back, back.flags, back.save_gen) == (replace(outcome, flags=0, save_gen=0), 0, 0)
    from14 = decode_sample(_session14_payload(s14), CommandOutcome)
    assert from14 == replace(outcome, save_gen=0)


def test_a_flagged_outcome_carries_its_save_gen_after_the_flags() -> None:
    """``flags``, then ``save_gen`` aligned to 4 (XCDR1): with reason ``x`` the payload is
    40 octets flagged, 36 unflagged (the earlier builds' bytes)."""
    out = CommandOutcome(7, "uav1", CommandResult.ACCEPTED, "x", OUTCOME_NOT_SAVED, 5)
    body = struct.pack("<QI5s3xII2sBxI", 7, 5, b"uav1\0", 0, 2, b"x\0", OUTCOME_NOT_SAVED, 5)
    assert encode_sample(out) == b"\x00\x01\x00\x00" + body
    back = decode_sample(encode_sample(out), CommandOutcome)
    assert (back.flags, back.save_gen) == (OUTCOME_NOT_SAVED, 5)
    plain = replace(out, flags=0, save_gen=0)
    assert len(encode_sample(plain)) == 36
    assert encode_sample(plain) == _earlier_payload(_earlier(plain))
