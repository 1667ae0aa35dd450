"""The XRCE codec against PX4's client library and eProsima's agent, byte for byte.

Golden: every datagram of a recorded 40 s session (``px4_like_client -V 1.16 -c 1`` and
``cmd_sender`` through MicroXRCEAgent v2.4.2, tests/fixtures/xrce, from shared/peers/xrce).
"""

from __future__ import annotations

import collections
import json
import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.xrce.binary import (
    EndpointBinary,
    GroupBinary,
    ServiceBinary,
    TopicBinary,
    encode_endpoint,
    encode_group,
    encode_service,
    encode_topic,
    parse_endpoint,
    parse_group,
    parse_service,
    parse_topic,
)
from swarmd.xrce.buffer import DecodeError
from swarmd.xrce.framing import Deframer, crc16, frame
from swarmd.xrce.message import (
    AckNack,
    Create,
    CreateClient,
    Data,
    Delete,
    Fragment,
    GetInfo,
    Header,
    Heartbeat,
    Info,
    ObjectKind,
    ReadData,
    Repr,
    StatusAgent,
    StatusReply,
    Submessage,
    Time,
    Timestamp,
    TimestampReply,
    WriteData,
    decode_message,
    encode_message,
    object_ident,
    object_kind,
)

FIXTURES = Path(__file__).parent / "fixtures" / "xrce"
TAP = FIXTURES / "px4-1.16-core.tap.jsonl"
SUMMARY = (FIXTURES / "px4-1.16-core.summary.txt").read_text()
RECORDS = [json.loads(line) for line in TAP.read_text().splitlines()]
NAMES = {
    "CreateClient": "CREATE_CLIENT", "Create": "CREATE", "GetInfo": "GET_INFO",
    "Delete": "DELETE", "StatusAgent": "STATUS_AGENT", "StatusReply": "STATUS",
    "Info": "INFO", "WriteData": "WRITE_DATA", "ReadData": "READ_DATA", "Data": "DATA",
    "AckNack": "ACKNACK", "Heartbeat": "HEARTBEAT", "Fragment": "FRAGMENT",
    "Timestamp": "TIMESTAMP", "TimestampReply": "TIMESTAMP_REPLY",
}  # fmt: skip


def _same_but_padding(ours: bytes, theirs: bytes) -> bool:
    """Equal, except where we wrote a zero alignment octet and eProsima left stale bytes."""
    return len(ours) == len(theirs) and all(
        a == 0 for a, b in zip(ours, theirs, strict=True) if a != b
    )


def _decoded() -> list[tuple[dict[str, str], bytes]]:
    return [(r, bytes.fromhex(r["hex"])) for r in RECORDS]


def test_every_golden_datagram_parses_and_counts_match_the_summary() -> None:
    counts: collections.Counter[tuple[str, str, str, str]] = collections.Counter()
    for rec, raw in _decoded():
        msg = decode_message(raw)
        for sub in msg.submessages:
            key = (
                rec["dir"],
                f"session 0x{msg.header.session_id:02x}",
                f"stream 0x{msg.header.stream_id:02x}",
                NAMES[type(sub).__name__],
            )
            counts[key] += 1
    expected = {}
    for line in SUMMARY.split("submessages by direction")[1].split("FRAGMENT")[0].splitlines():
        m = re.match(r"\s+(\w+)\s+(session 0x\w+)\s+(stream 0x\w+)\s+(\w+)\s+(\d+)$", line)
        if m:
            expected[m.group(1, 2, 3, 4)] = int(m.group(5))
    assert len(expected) == 19
    assert dict(counts) == expected


def test_reencoding_is_byte_exact_where_padding_is_zero() -> None:
    exact = differ = 0
    for _rec, raw in _decoded():
        msg = decode_message(raw)
        again = encode_message(msg.header, msg.submessages, msg.padding)
        assert len(again) == len(raw)
        assert decode_message(again) == msg
        if again == raw:
            exact += 1
            continue
        # the eProsima client leaves stale buffer octets in CDR alignment gaps; we write 0
        differ += 1
        assert all(a == 0 for a, b in zip(again, raw, strict=True) if a != b)
    assert exact >= 1900
    assert differ == len(RECORDS) - exact


def test_create_requests_match_the_summary() -> None:
    creates = [
        sub
        for _rec, raw in _decoded()
        for sub in decode_message(raw).submessages
        if isinstance(sub, Create)
    ]
    want = [
        json.loads(line.strip())
        for line in SUMMARY.splitlines()
        if line.strip().startswith('{"req"')
    ]
    assert len(creates) == len(want) == 36
    for c, w in zip(creates, want, strict=True):
        # the summary tool reads the octet pair little-endian; the ids are big-endian octets
        assert w["req"] == ((c.request_id & 0xFF) << 8 | c.request_id >> 8)
        assert w["id"] == f"0x{object_ident(c.object_id):03x}"
        assert w["kind"] == ObjectKind(c.kind).name
        assert w["repr"] == Repr(c.repr_format).name
        if c.kind == ObjectKind.PARTICIPANT:
            assert c.representation == w["text"]
            assert c.domain_id == w["domain_id"]
            continue
        assert c.parent_id is not None and w["parent"] == f"0x{object_ident(c.parent_id):03x}"
        blob = c.representation
        assert isinstance(blob, bytes) and len(blob) == w["bin_len"]
        if c.kind == ObjectKind.TOPIC:
            t = parse_topic(blob)
            assert (t.topic_name, t.type_name) == (w["topic_name"], w["type_name"])
            assert _same_but_padding(encode_topic(t), blob)
        elif c.kind in (ObjectKind.DATAWRITER, ObjectKind.DATAREADER):
            e = parse_endpoint(blob, writer=c.kind == ObjectKind.DATAWRITER)
            assert f"0x{object_ident(e.topic_id):03x}" == w["topic_id"]
            assert e.qos_flags == w["qos_flags"]
            assert e.history_depth == w.get("history_depth")
            assert _same_but_padding(encode_endpoint(e), blob)
        elif c.kind in (ObjectKind.REQUESTER, ObjectKind.REPLIER):
            s = parse_service(blob)
            assert s.service_name == w["service_name"]
            assert (s.request_type, s.reply_type) == (w["request_type"], w["reply_type"])
            assert s.request_topic_name == w["request_topic_name"]
            assert s.reply_topic_name == w["reply_topic_name"]
            assert _same_but_padding(encode_service(s), blob)
        else:
            assert parse_group(blob) == GroupBinary()
            assert _same_but_padding(encode_group(GroupBinary()), blob)


def test_handshake_fields() -> None:
    records = _decoded()
    ping = decode_message(records[0][1])
    assert ping.header == Header(0x80, 0, 0)
    assert ping.submessages == (GetInfo(0x000A, 0xFFFD, 2),)
    pong = decode_message(records[1][1]).submessages[0]
    assert isinstance(pong, Info) and pong.availability == 1 and pong.agent is not None
    cc = decode_message(records[2][1]).submessages[0]
    assert cc == CreateClient(b"\x00\x00\x00\x01", 0x81, 508)
    sa = decode_message(records[3][1])
    assert sa.header == Header(0x81, 0, 0)
    assert isinstance(sa.submessages[0], StatusAgent) and sa.submessages[0].status == 0
    ts = [
        s
        for _r, raw in records
        for s in decode_message(raw).submessages
        if isinstance(s, TimestampReply)
    ]
    # the agent echoes the client's transmit time as originate (§8.3.5.16)
    first_ts = decode_message(records[8][1]).submessages[0]
    assert isinstance(first_ts, Timestamp) and ts[0].originate == first_ts.transmit


def test_read_data_and_samples() -> None:
    reads = [
        s for _r, raw in _decoded() for s in decode_message(raw).submessages
        if isinstance(s, ReadData)
    ]  # fmt: skip
    assert [(object_ident(r.object_id), object_kind(r.object_id)) for r in reads] == [
        (0x814, 6), (0x800, 8), (0x020, 6), (0x021, 6), (0x030, 7),
    ]  # fmt: skip
    assert reads[0].preferred_stream_id == 1 and reads[0].delivery_control is not None
    assert reads[0].delivery_control.max_samples == 0xFFFF
    writes = collections.Counter(
        (object_ident(s.object_id), len(s.data))
        for _r, raw in _decoded()
        for s in decode_message(raw).submessages
        if isinstance(s, WriteData)
    )
    assert writes[(0x0FD, 80)] == 70  # vehicle_status_v1, 80 B (1.16)
    assert writes[(0x0F3, 159)] == 347  # vehicle_gps_position


def test_every_proper_prefix_raises_decode_error() -> None:
    for _rec, raw in _decoded()[:60]:
        for n in range(len(raw)):
            try:
                msg = decode_message(raw[:n])
            except DecodeError:
                continue
            # a prefix that cuts only the trailing padding still holds every submessage
            assert len(raw) - n < 4 and msg.submessages


def test_acknack_bitmap_octet_order() -> None:
    a = AckNack(0xFFFE, 0b1000_0000_0000_0101, 0x80)
    raw = encode_message(Header(0x81, 0, 7), [a])
    assert raw.hex() == "81000700" + "0a010500" + "feff" + "8005" + "80"
    assert decode_message(raw).submessages == (a,)


def test_serial_framing_round_trip_and_crc() -> None:
    assert crc16(b"123456789") == 0xBB3D  # CRC-16/ARC check value
    payload = bytes([0x7E, 0x7D, 0x00, 0xFF]) * 10
    f = frame(payload, src=1, dst=0)
    assert f[0] == 0x7E and 0x7E not in f[1:]
    d = Deframer()
    assert d.feed(b"\x00\x7d\x7e" + f + f[:5] + f) == [(1, 0, payload), (1, 0, payload)]
    assert d.dropped == 1  # the cut frame (noise before a flag is skipped, not a frame)
    bad = bytearray(f)
    bad[-1] ^= 1
    assert d.feed(bytes(bad)) == [] and d.dropped == 2


@given(st.binary(max_size=600))
@settings(max_examples=300, deadline=None)
def test_deframer_never_raises(data: bytes) -> None:
    d = Deframer()
    for _src, _dst, payload in d.feed(data):
        assert len(payload) <= 512


@given(st.binary(max_size=300))
@settings(max_examples=500, deadline=None)
def test_arbitrary_bytes_decode_or_decode_error(data: bytes) -> None:
    try:
        msg = decode_message(data)
    except DecodeError:
        return
    again = encode_message(msg.header, msg.submessages, msg.padding)
    assert decode_message(again) == msg


@given(st.binary(min_size=4, max_size=200))
@settings(max_examples=300, deadline=None)
def test_arbitrary_blobs_parse_or_decode_error(blob: bytes) -> None:
    for parse in (parse_topic, parse_group, parse_service):
        try:
            parse(blob)
        except DecodeError:
            pass
    for writer in (True, False):
        try:
            parse_endpoint(blob, writer=writer)
        except DecodeError:
            pass


u16 = st.integers(0, 0xFFFF)
ids = st.integers(0, 0xFFFF)
text = st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\x00"), max_size=30)
subs: st.SearchStrategy[Submessage] = st.one_of(
    st.builds(AckNack, u16, u16, st.integers(0, 255)),
    st.builds(Heartbeat, u16, u16, st.integers(0, 255)),
    st.builds(StatusReply, ids, ids, st.integers(0, 255), st.integers(0, 255)),
    st.builds(Delete, ids, ids),
    st.builds(GetInfo, ids, ids, st.integers(0, 2**32 - 1)),
    st.builds(WriteData, ids, ids, st.binary(max_size=64)),
    st.builds(Data, ids, ids, st.binary(max_size=64)),
    st.builds(Fragment, st.binary(max_size=64), st.booleans()),
    st.builds(Timestamp, st.builds(Time, st.integers(0, 2**31 - 1), st.integers(0, 999_999_999))),
    st.builds(ReadData, ids, ids, st.integers(0, 255), st.just(0), st.none() | text),
    st.builds(
        Create,
        ids,
        st.integers(0, 0xFFF).map(lambda i: i << 4 | 2),
        st.just(2),
        st.just(3),
        st.builds(TopicBinary, text, st.none() | text).map(encode_topic),
        st.none(),
        ids,
    ),  # fmt: skip
)


@given(st.integers(0x80, 0xFF), st.integers(0, 255), u16, st.lists(subs, min_size=1, max_size=5))
@settings(max_examples=300, deadline=None)
def test_round_trip(session: int, stream: int, seq: int, submessages: list[Submessage]) -> None:
    raw = encode_message(Header(session, stream, seq), submessages)
    msg = decode_message(raw)
    assert msg.header == Header(session, stream, seq)
    assert list(msg.submessages) == submessages
    assert encode_message(msg.header, msg.submessages) == raw


@given(st.builds(EndpointBinary, ids, st.booleans(), st.none() | u16, st.none() | u16))
def test_endpoint_round_trip(e: EndpointBinary) -> None:
    if e.qos_flags is None:
        e = EndpointBinary(e.topic_id, e.writer)
    assert parse_endpoint(encode_endpoint(e), writer=e.writer) == e


@given(st.builds(ServiceBinary, text, text, text, st.none() | text, st.none() | text))
def test_service_round_trip(s: ServiceBinary) -> None:
    assert parse_service(encode_service(s)) == s


def test_keyed_session_header() -> None:
    raw = encode_message(Header(0x01, 0x80, 3, b"\xaa\xbb\xcc\xdd"), [Delete(1, 0xFFFE)])
    assert raw[:8].hex() == "01800300aabbccdd"
    assert decode_message(raw).header.client_key == b"\xaa\xbb\xcc\xdd"
    with pytest.raises(DecodeError):
        decode_message(raw[:6])
