"""Unit tests for the RTPS codec pieces: header, submessages, parameter lists, ports, ids."""

from __future__ import annotations

import pytest

from swarmd.rtps import (
    AckNack,
    Data,
    DecodeError,
    Duration,
    EntityId,
    Gap,
    GuidPrefix,
    Header,
    Heartbeat,
    InfoDst,
    InfoTs,
    Locator,
    Parameter,
    ParameterList,
    ProtocolVersion,
    SequenceNumberSet,
    SkippedSubmessage,
    SpdpParticipant,
    VendorId,
    decode_message,
    decode_spdp,
    encode_message,
    encode_spdp,
    ports,
)
from swarmd.rtps.message import SubmessageId, encode_submessage
from swarmd.rtps.spdp import PID_SWARMD_HEARD, PID_SWARMD_LINK_QUALITY
from swarmd.rtps.types import (
    DURATION_INFINITE,
    ENTITYID_SPDP_WRITER,
    VENDORID_CYCLONE,
    VENDORID_SWARMD,
    Guid,
)

HEADER = Header(ProtocolVersion(2, 3), VENDORID_SWARMD, GuidPrefix(bytes(range(1, 13))))
W = EntityId.of(0x00000103)
R = EntityId.of(0x00000104)


def test_port_mapping_matches_spec_defaults() -> None:
    # spec 9.6.1.1 with PB 7400, DG 250, PG 2, d0 0, d1 10, d2 1, d3 11
    assert ports.spdp_multicast_port(0) == 7400
    assert ports.spdp_multicast_port(1) == 7650
    assert ports.metatraffic_unicast_port(0, 0) == 7410
    assert ports.metatraffic_unicast_port(0, 3) == 7416
    assert ports.user_unicast_port(0, 3) == 7417
    assert ports.user_multicast_port(2) == 7901
    assert ports.metatraffic_unicast_port(1, 5) == 7670


def test_port_mapping_refuses_overflow() -> None:
    top = ports.max_participant_index(0)
    assert ports.user_unicast_port(0, top) <= 65535
    with pytest.raises(ValueError, match="outside"):
        ports.user_unicast_port(0, top + 1)
    with pytest.raises(ValueError, match="domain id"):
        ports.spdp_multicast_port(ports.MAX_DOMAIN_ID + 1)
    with pytest.raises(ValueError, match="negative"):
        ports.metatraffic_unicast_port(0, -1)


def test_guid_prefix_text_forms_round_trip() -> None:
    prefix = GuidPrefix(bytes.fromhex("0110f12eb78897fa21779fa5"))
    assert str(prefix) == "110f12e:b78897fa:21779fa5"
    assert GuidPrefix.parse(str(prefix)) == prefix
    assert GuidPrefix.parse(prefix.hex()) == prefix
    guid = Guid(prefix, EntityId.of(0x1C1))
    assert str(guid) == "110f12e:b78897fa:21779fa5:1c1"
    assert Guid.from_bytes(guid.to_bytes()) == guid


def test_vendor_names() -> None:
    assert VENDORID_CYCLONE.name == "Eclipse Cyclone DDS"
    assert VENDORID_SWARMD.name == "swarmd"
    assert VendorId(b"\xca\xfe").name == "unregistered ca.fe"


def test_duration_conversions() -> None:
    assert Duration.from_seconds(1.5) == Duration(1, 1 << 31)
    assert Duration.from_seconds(20) == Duration(20, 0)
    assert Duration(2, 1 << 30).total_seconds() == 2.25
    assert DURATION_INFINITE.is_infinite


def test_locators() -> None:
    v4 = Locator.udpv4("10.0.0.7", 7410)
    assert str(v4) == "udp/10.0.0.7:7410" and v4.host == "10.0.0.7" and not v4.is_multicast
    assert Locator.udpv4("239.255.0.1", 7400).is_multicast
    v6 = Locator.udpv6("ff02::1", 7400)
    assert v6.is_multicast and str(v6) == "udp/[ff02::1]:7400"
    odd = Locator(16, 0, bytes(16))  # Cyclone PSMX / Fast DDS SHM-like kinds are kept opaque
    assert odd.host == "" and not odd.is_udp


@pytest.mark.parametrize(
    "submessage",
    [
        InfoTs(None),
        InfoTs(Duration(12, 34)),
        InfoDst(GuidPrefix(bytes(range(12)))),
        Data(R, W, 7, serialized_payload=b"\x00\x01\x00\x00abcd"),
        Data(R, W, (1 << 32) + 5, inline_qos=ParameterList((Parameter(0x71, bytes(4)),))),
        Data(R, W, 1, serialized_payload=b"\x00\x03\x00\x00\x01\x00\x00\x00", key=True),
        Heartbeat(R, W, 1, 10, 3, final=True, liveliness=True),
        AckNack(R, W, SequenceNumberSet.of(5, [5, 7, 40]), 2, final=False),
        AckNack(R, W, SequenceNumberSet(11, 0, ()), 9, final=True),
        Gap(R, W, 3, SequenceNumberSet.of(6, [6, 8])),
        SkippedSubmessage(SubmessageId.DATA_FRAG, 0x01, bytes(36)),
        SkippedSubmessage(0x80, 0x00, b"\x00\x00\x00\x01"),  # vendor-specific, big-endian
    ],
    ids=lambda sm: type(sm).__name__,
)
def test_submessage_round_trip(submessage: object) -> None:
    data = encode_message(HEADER, [submessage])  # type: ignore[list-item]
    assert decode_message(data).submessages == (submessage,)


def test_sequence_number_set_members() -> None:
    s = SequenceNumberSet.of(100, [100, 131, 132, 355])
    assert s.members() == [100, 131, 132, 355]
    assert s.num_bits == 256
    with pytest.raises(ValueError, match="exceeds"):
        SequenceNumberSet.of(0, [256])


def test_big_endian_submessages_decode() -> None:
    # flag E clear: lengths and fields in network byte order
    body = R.value + W.value + (0).to_bytes(4, "big") + (1).to_bytes(4, "big")
    body += (0).to_bytes(4, "big") + (4).to_bytes(4, "big") + (9).to_bytes(4, "big")
    sm = bytes([SubmessageId.HEARTBEAT, 0x00]) + len(body).to_bytes(2, "big") + body
    message = decode_message(b"RTPS\x02\x01\x01\x10" + bytes(12) + sm)
    assert message.submessages == (Heartbeat(R, W, 1, 4, 9),)


def test_data_frag_is_skipped_not_fatal() -> None:
    frag = encode_submessage(SkippedSubmessage(SubmessageId.DATA_FRAG, 0x01, bytes(40)))
    data = encode_message(HEADER, [InfoTs(None)]) + frag
    subs = decode_message(data).submessages
    assert (
        isinstance(subs[1], SkippedSubmessage) and subs[1].submessage_id == SubmessageId.DATA_FRAG
    )


def test_length_zero_means_rest_of_message_for_last_submessage() -> None:
    hb = encode_submessage(Heartbeat(R, W, 1, 2, 3))
    zero_len = hb[:2] + b"\x00\x00" + hb[4:]
    assert decode_message(encode_message(HEADER, []) + zero_len).submessages == (
        Heartbeat(R, W, 1, 2, 3),
    )


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (b"", "header needs 20 bytes"),
        (b"XXXX" + bytes(16), "not an RTPS message"),
        (b"RTPS\x01\x00" + bytes(14), "major version"),
        (encode_message(HEADER, []) + b"\x15\x05", "truncated submessage header"),
        (encode_message(HEADER, []) + b"\x09\x01\x08\x00\x00", "claims 8 bytes"),
    ],
)
def test_malformed_messages_name_the_problem(data: bytes, message: str) -> None:
    with pytest.raises(DecodeError, match=message):
        decode_message(data)


def test_data_with_both_d_and_k_is_rejected() -> None:
    good = encode_submessage(Data(R, W, 1, serialized_payload=b"\x00\x01\x00\x00"))
    bad = good[:1] + bytes([good[1] | 0x08]) + good[2:]
    with pytest.raises(DecodeError, match="both D and K"):
        decode_message(encode_message(HEADER, []) + bad)


def _participant(**kw: object) -> SpdpParticipant:
    base: dict[str, object] = {
        "guid_prefix": HEADER.guid_prefix,
        "metatraffic_unicast_locators": (Locator.udpv4("10.1.1.1", 7410),),
    }
    base.update(kw)
    return SpdpParticipant(**base)  # type: ignore[arg-type]


def test_spdp_guid_must_match_header_prefix() -> None:
    data = bytearray(encode_spdp(_participant(), sequence_number=1, timestamp=None))
    data[8] ^= 0xFF  # header prefix no longer equals PID_PARTICIPANT_GUID (Cyclone ignores it too)
    with pytest.raises(DecodeError, match="differs from RTPS source"):
        decode_spdp(bytes(data))


def test_spdp_vendor_pids_only_read_from_swarmd() -> None:
    ours = _participant(heard=b"\x07", link_quality_permille=500)
    _, (sample,) = decode_spdp(encode_spdp(ours, sequence_number=1, timestamp=None))
    assert sample.participant.heard == b"\x07"  # type: ignore[union-attr]
    theirs = _participant(vendor_id=VENDORID_CYCLONE, heard=b"\x07", link_quality_permille=500)
    _, (sample,) = decode_spdp(encode_spdp(theirs, sequence_number=1, timestamp=None))
    p = sample.participant  # type: ignore[union-attr]
    assert p.heard is None and p.link_quality_permille is None
    assert [x.pid for x in p.extra_parameters] == [PID_SWARMD_HEARD, PID_SWARMD_LINK_QUALITY]


def test_swarmd_pids_stay_in_the_ignorable_vendor_range() -> None:
    from swarmd.rtps.spdp import SWARMD_PIDS

    for pid in SWARMD_PIDS:
        # 0x8000 vendor-specific, 0x4000 clear: stock stacks may skip it (reference 1.5)
        assert pid & 0x8000 and not pid & 0x4000


def test_spdp_link_quality_out_of_range_is_rejected() -> None:
    data = encode_spdp(_participant(link_quality_permille=1001), sequence_number=1, timestamp=None)
    with pytest.raises(DecodeError, match="link quality"):
        decode_spdp(data)


def test_spdp_defaults_when_optional_pids_absent() -> None:
    # minimal DATA(p): only the GUID. Lease defaults to the spec's 100 s, domain to "receiver's"
    from swarmd.rtps.parameters import Pid
    from swarmd.rtps.spdp import SpdpParticipant as P

    plist = ParameterList(
        (Parameter(Pid.PARTICIPANT_GUID, HEADER.guid_prefix.value + b"\0\0\1\xc1"),)
    )
    p = P.from_parameters(plist)
    assert p.lease_duration == Duration(100, 0)
    assert p.domain_id is None and p.builtin_endpoints == 0


def test_spdp_without_guid_is_rejected() -> None:
    from swarmd.rtps.spdp import SpdpParticipant as P

    with pytest.raises(DecodeError, match="PID_PARTICIPANT_GUID"):
        P.from_parameters(ParameterList(()))


def test_non_spdp_data_is_ignored_by_decode_spdp() -> None:
    data = encode_message(HEADER, [Data(R, W, 1, serialized_payload=b"\x00\x01\x00\x00")])
    assert decode_spdp(data) == (HEADER, [])
    spdp_writer_but_garbage = encode_message(
        HEADER, [Data(R, ENTITYID_SPDP_WRITER, 1, serialized_payload=b"\x00\x01\x00\x00")]
    )
    with pytest.raises(DecodeError, match="not PL_CDR"):
        decode_spdp(spdp_writer_but_garbage)
