"""DDS-XRCE 1.0 messages and submessages (OMG formal/20-02-01 §8.3), as PX4's client uses them.

A message (§8.3.2) is a 4-byte header -- sessionId, streamId, little-endian u16
sequenceNr -- plus a 4-byte clientKey only when sessionId < 0x80 (§8.3.2.1: sessions
0x80..0xFF are identified by the transport address, so the key is left out), then one or
more submessages (§8.3.4), each a 4-byte header (submessageId, flags, little-endian u16
submessageLength) and a payload, every submessage starting 4-aligned in the message. Flag
bit 0 (E) is the payload's endianness (§8.3.4.2); eProsima's client and agent always set it.

Binary object representations (topic, data writer, ...) are eProsima's ``*_Binary`` types
(Micro XRCE-DDS ``xrce_types``), the form PX4's ``uxrce_dds_client`` creates everything but
its participant in.

``decode_message`` raises ``DecodeError`` and nothing else. ``encode_message`` inverts it:
for any datagram whose padding is zero and whose submessages are encoded the eProsima way
(every datagram of the recorded PX4 session), ``encode_message(decode_message(b)) == b``.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final, Self

from swarmd.xrce.buffer import DecodeError, Reader, Writer

XRCE_COOKIE: Final = b"XRCE"
XRCE_VERSION: Final = b"\x01\x00"  # §8.3.5.1 xrce_version 1.0
VENDOR_SWARMD: Final = b"\x0f\x53"  # not eProsima's 01 0f; no OMG vendor id is assigned to us

SESSION_ID_NONE_WITH_KEY: Final = 0x00
SESSION_ID_NONE_WITHOUT_KEY: Final = 0x80  # §8.3.2.1: session-less, key left out
STREAM_NONE: Final = 0x00
STREAM_BEST_EFFORT_MIN: Final = 0x01  # §8.3.2.2: 0x01..0x7F best effort, 0x80..0xFF reliable
STREAM_RELIABLE_MIN: Final = 0x80

FLAG_E: Final = 0x01  # little-endian payload
FLAG_REUSE: Final = 0x02  # CREATE §8.3.5.2
FLAG_REPLACE: Final = 0x04
FLAG_LAST_FRAGMENT: Final = 0x02  # FRAGMENT §8.3.5.14
FORMAT_MASK: Final = 0x0E  # WRITE_DATA / DATA data format §8.3.5.8
FORMAT_DATA: Final = 0x00

MAX_SUBMESSAGES: Final = 64  # a 512-byte MTU holds at most 508 / 4 = 127 headers; bound work


class SubmessageId(IntEnum):
    """§8.3.4.1."""

    CREATE_CLIENT = 0
    CREATE = 1
    GET_INFO = 2
    DELETE = 3
    STATUS_AGENT = 4
    STATUS = 5
    INFO = 6
    WRITE_DATA = 7
    READ_DATA = 8
    DATA = 9
    ACKNACK = 10
    HEARTBEAT = 11
    RESET = 12
    FRAGMENT = 13
    TIMESTAMP = 14
    TIMESTAMP_REPLY = 15
    PERFORMANCE = 16


class ObjectKind(IntEnum):
    """§7.7.2 ObjectKind (low nibble of an ObjectId)."""

    INVALID = 0x00
    PARTICIPANT = 0x01
    TOPIC = 0x02
    PUBLISHER = 0x03
    SUBSCRIBER = 0x04
    DATAWRITER = 0x05
    DATAREADER = 0x06
    REQUESTER = 0x07
    REPLIER = 0x08
    TYPE = 0x0A
    QOSPROFILE = 0x0B
    APPLICATION = 0x0C
    AGENT = 0x0D
    CLIENT = 0x0E


class Repr(IntEnum):
    """§7.7.3 representation formats."""

    REF = 0x01
    XML = 0x02
    BIN = 0x03


class Status(IntEnum):
    """§8.3.5.6 ResultStatus.status."""

    OK = 0x00
    OK_MATCHED = 0x01
    ERR_DDS_ERROR = 0x80
    ERR_MISMATCH = 0x81
    ERR_ALREADY_EXISTS = 0x82
    ERR_DENIED = 0x83
    ERR_UNKNOWN_REFERENCE = 0x84
    ERR_INVALID_DATA = 0x85
    ERR_INCOMPATIBLE = 0x86
    ERR_RESOURCES = 0x87


INFO_CONFIGURATION: Final = 0x01
INFO_ACTIVITY: Final = 0x02
OBJECT_ID_AGENT: Final = 0xFFFD  # id 0xFFF, kind AGENT: the GET_INFO target of PX4's ping
OBJECT_ID_CLIENT: Final = 0xFFFE  # id 0xFFF, kind CLIENT: DELETE of the session


def object_id(ident: int, kind: int) -> int:
    """§7.7.2: the 2-octet ObjectId is a 12-bit id and a 4-bit kind, big-endian."""
    return ((ident & 0xFFF) << 4) | (kind & 0xF)


def object_kind(oid: int) -> int:
    return oid & 0xF


def object_ident(oid: int) -> int:
    return oid >> 4


# ---- message header (§8.3.2) ---------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Header:
    session_id: int
    stream_id: int
    sequence_nr: int
    client_key: bytes | None = None  # exactly 4 octets when session_id < 0x80

    def encode(self) -> bytes:
        out = struct.pack("<BBH", self.session_id, self.stream_id, self.sequence_nr)
        if self.session_id < 0x80:
            if self.client_key is None or len(self.client_key) != 4:
                raise ValueError("a session id below 0x80 carries a 4-octet client key")
            out += self.client_key
        return out


# ---- shared parts ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Time:
    """§8.3.5.15 Time_t: seconds (i32) and nanoseconds (u32)."""

    seconds: int
    nanoseconds: int

    @classmethod
    def from_ns(cls, ns: int) -> Time:
        return cls(ns // 1_000_000_000, ns % 1_000_000_000)

    @property
    def ns(self) -> int:
        return self.seconds * 1_000_000_000 + self.nanoseconds


def _pull_time(r: Reader) -> Time:
    return Time(r.i32(), r.u32())


def _push_time(w: Writer, t: Time) -> None:
    w.i32(t.seconds)
    w.u32(t.nanoseconds)


def _pull_properties(r: Reader) -> tuple[tuple[str, str], ...] | None:
    if not r.boolean():
        return None
    n = r.u32()
    if n > 16:
        raise DecodeError(f"{n} properties")
    return tuple((r.string(), r.string()) for _ in range(n))


def _push_properties(w: Writer, props: tuple[tuple[str, str], ...] | None) -> None:
    w.boolean(props is not None)
    if props is not None:
        w.u32(len(props))
        for k, v in props:
            w.string(k)
            w.string(v)


# ---- submessages (§8.3.5) ---------------------------------------------------------------------


class _Sub:
    """Default flags: only E (little-endian), which eProsima always sets."""

    __slots__ = ()

    def flags(self) -> int:
        return FLAG_E


@dataclass(frozen=True, slots=True)
class CreateClient(_Sub):
    """§8.3.5.1 CREATE_CLIENT: CLIENT_Representation (+ eProsima's trailing u16 MTU)."""

    client_key: bytes
    session_id: int
    mtu: int = 512
    properties: tuple[tuple[str, str], ...] | None = None
    cookie: bytes = XRCE_COOKIE
    version: bytes = XRCE_VERSION
    vendor_id: bytes = b"\x01\x0f"
    sid = SubmessageId.CREATE_CLIENT

    def payload(self) -> bytes:
        w = Writer()
        w.raw(self.cookie + self.version + self.vendor_id + self.client_key)
        w.u8(self.session_id)
        _push_properties(w, self.properties)
        w.u16(self.mtu)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> CreateClient:
        cookie, version, vendor, key = r.raw(4), r.raw(2), r.raw(2), r.raw(4)
        session_id = r.u8()
        props = _pull_properties(r)
        mtu = r.u16()
        return cls(key, session_id, mtu, props, cookie, version, vendor)


@dataclass(frozen=True, slots=True)
class AgentRepresentation:
    """§7.8.2.2 AGENT_Representation."""

    cookie: bytes = XRCE_COOKIE
    version: bytes = XRCE_VERSION
    vendor_id: bytes = VENDOR_SWARMD
    properties: tuple[tuple[str, str], ...] | None = None

    def push(self, w: Writer) -> None:
        w.raw(self.cookie + self.version + self.vendor_id)
        _push_properties(w, self.properties)

    @classmethod
    def pull(cls, r: Reader) -> AgentRepresentation:
        cookie, version, vendor = r.raw(4), r.raw(2), r.raw(2)
        return cls(cookie, version, vendor, _pull_properties(r))


@dataclass(frozen=True, slots=True)
class StatusAgent(_Sub):
    """§8.3.5.4 STATUS_AGENT: the answer to CREATE_CLIENT."""

    status: int
    implementation_status: int
    agent: AgentRepresentation = field(default_factory=AgentRepresentation)
    sid = SubmessageId.STATUS_AGENT

    def payload(self) -> bytes:
        w = Writer()
        w.u8(self.status)
        w.u8(self.implementation_status)
        self.agent.push(w)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> StatusAgent:
        status, impl = r.u8(), r.u8()
        return cls(status, impl, AgentRepresentation.pull(r))


def _pull_request(r: Reader) -> tuple[int, int]:
    """BaseObjectRequest §8.3.5: request_id and object_id, two octet pairs (big-endian ids)."""
    raw = r.raw(4)
    return (raw[0] << 8) | raw[1], (raw[2] << 8) | raw[3]


def _push_request(w: Writer, request_id: int, oid: int) -> None:
    w.raw(bytes(((request_id >> 8) & 0xFF, request_id & 0xFF, (oid >> 8) & 0xFF, oid & 0xFF)))


@dataclass(frozen=True, slots=True)
class Create(_Sub):
    """§8.3.5.2 CREATE: an ObjectVariant by reference, XML or (eProsima) binary.

    ``representation`` is the reference or XML string (REF/XML) or the binary blob (BIN);
    ``parse_binary`` reads the blob. ``domain_id`` is present for a participant only,
    ``parent_id`` for every other kind.
    """

    request_id: int
    object_id: int
    kind: int
    repr_format: int
    representation: str | bytes
    domain_id: int | None = None
    parent_id: int | None = None
    reuse: bool = False
    replace: bool = False
    sid = SubmessageId.CREATE

    def flags(self) -> int:
        return FLAG_E | (FLAG_REUSE if self.reuse else 0) | (FLAG_REPLACE if self.replace else 0)

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.u8(self.kind)
        w.u8(self.repr_format)
        if isinstance(self.representation, str):
            w.string(self.representation)
        else:
            w.octets(self.representation)
        if self.kind == ObjectKind.PARTICIPANT:
            w.i16(self.domain_id or 0)
        elif self.parent_id is not None:
            w.raw(bytes(((self.parent_id >> 8) & 0xFF, self.parent_id & 0xFF)))
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Create:
        request_id, oid = _pull_request(r)
        # the variant's kind rules, not the id's nibble: PX4 numbers topic objects by ORB_ID,
        # and ids past 0xFFF wrap (vehicle_attitude arrives as 0x0000 with kind TOPIC); the
        # eProsima agent accepts that, and so must we or PX4's whole set-up fails
        kind, fmt = r.u8(), r.u8()
        rep: str | bytes
        if fmt in (Repr.REF, Repr.XML):
            rep = r.string()
        elif fmt == Repr.BIN:
            rep = r.octets()
        else:
            raise DecodeError(f"representation format {fmt}")
        domain_id = parent = None
        if kind == ObjectKind.PARTICIPANT:
            domain_id = r.i16()
        elif kind in (ObjectKind.APPLICATION, ObjectKind.QOSPROFILE, ObjectKind.TYPE):
            raise DecodeError(f"CREATE of kind {kind} not supported")
        else:
            raw = r.raw(2)
            parent = (raw[0] << 8) | raw[1]
        return cls(
            request_id, oid, kind, fmt, rep, domain_id, parent,
            bool(flags & FLAG_REUSE), bool(flags & FLAG_REPLACE),
        )  # fmt: skip


@dataclass(frozen=True, slots=True)
class GetInfo(_Sub):
    """§8.3.5.3 GET_INFO: PX4 pings with it (out of session, and in session while idle)."""

    request_id: int
    object_id: int
    info_mask: int
    sid = SubmessageId.GET_INFO

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.u32(self.info_mask)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> GetInfo:
        request_id, oid = _pull_request(r)
        return cls(request_id, oid, r.u32())


@dataclass(frozen=True, slots=True)
class Delete(_Sub):
    """§8.3.5.5 DELETE (of the client object: the session ends)."""

    request_id: int
    object_id: int
    sid = SubmessageId.DELETE

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Delete:
        return cls(*_pull_request(r))


@dataclass(frozen=True, slots=True)
class StatusReply(_Sub):
    """§8.3.5.6 STATUS: BaseObjectReply (the answer to CREATE/DELETE/...)."""

    request_id: int
    object_id: int
    status: int
    implementation_status: int = 0
    sid = SubmessageId.STATUS

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.u8(self.status)
        w.u8(self.implementation_status)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> StatusReply:
        request_id, oid = _pull_request(r)
        return cls(request_id, oid, r.u8(), r.u8())


@dataclass(frozen=True, slots=True)
class Locator:
    """§7.8.2.1 TransportLocator (small, medium, large or string)."""

    format: int
    address: bytes | str
    port: int = 0


_LOCATOR_SIZES: Final = {0: 2, 1: 4, 2: 16}


@dataclass(frozen=True, slots=True)
class Info(_Sub):
    """§8.3.5.7 INFO: a BaseObjectReply and optional AGENT configuration and activity.

    PX4's fork reads ``implementation_status`` as "the session is alive" and needs
    ``availability > 0`` (session.c ``read_submessage_info``), or it counts a missed ping.
    """

    request_id: int
    object_id: int
    status: int = 0
    implementation_status: int = 0
    agent: AgentRepresentation | None = None
    availability: int | None = None
    locators: tuple[Locator, ...] = ()
    sid = SubmessageId.INFO

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.u8(self.status)
        w.u8(self.implementation_status)
        w.boolean(self.agent is not None)
        if self.agent is not None:
            w.u8(ObjectKind.AGENT)
            self.agent.push(w)
        w.boolean(self.availability is not None)
        if self.availability is not None:
            w.u8(ObjectKind.AGENT)
            w.i16(self.availability)
            w.u32(len(self.locators))
            for loc in self.locators:
                w.u8(loc.format)
                if isinstance(loc.address, str):
                    w.string(loc.address)
                    continue
                w.raw(loc.address)
                if loc.format == 0:
                    w.u8(loc.port)
                elif loc.format == 1:
                    w.u16(loc.port)
                else:
                    w.u32(loc.port)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Info:
        request_id, oid = _pull_request(r)
        status, impl = r.u8(), r.u8()
        agent = None
        if r.boolean():
            kind = r.u8()
            if kind != ObjectKind.AGENT:
                raise DecodeError(f"INFO configuration of kind {kind} not supported")
            agent = AgentRepresentation.pull(r)
        availability = None
        locators: list[Locator] = []
        if r.boolean():
            kind = r.u8()
            if kind != ObjectKind.AGENT:
                raise DecodeError(f"INFO activity of kind {kind} not supported")
            availability = r.i16()
            n = r.u32()
            if n > 8:
                raise DecodeError(f"{n} locators")
            for _ in range(n):
                fmt = r.u8()
                if fmt == 3:
                    locators.append(Locator(fmt, r.string()))
                    continue
                if fmt not in _LOCATOR_SIZES:
                    raise DecodeError(f"locator format {fmt}")
                addr = r.raw(_LOCATOR_SIZES[fmt])
                port = r.u8() if fmt == 0 else r.u16() if fmt == 1 else r.u32()
                locators.append(Locator(fmt, addr, port))
        return cls(request_id, oid, status, impl, agent, availability, tuple(locators))


@dataclass(frozen=True, slots=True)
class DeliveryControl:
    """§8.3.5.9 DataDeliveryControl."""

    max_samples: int = 0xFFFF
    max_elapsed_time: int = 0
    max_bytes_per_second: int = 0
    min_pace_period: int = 0


@dataclass(frozen=True, slots=True)
class ReadData(_Sub):
    """§8.3.5.9 READ_DATA: a reader (or replier/requester) asks for its samples."""

    request_id: int
    object_id: int
    preferred_stream_id: int
    data_format: int = FORMAT_DATA
    content_filter: str | None = None
    delivery_control: DeliveryControl | None = None
    sid = SubmessageId.READ_DATA

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.u8(self.preferred_stream_id)
        w.u8(self.data_format)
        w.boolean(self.content_filter is not None)
        if self.content_filter is not None:
            w.string(self.content_filter)
        w.boolean(self.delivery_control is not None)
        if (dc := self.delivery_control) is not None:
            for v in (dc.max_samples, dc.max_elapsed_time, dc.max_bytes_per_second):
                w.u16(v)
            w.u16(dc.min_pace_period)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> ReadData:
        request_id, oid = _pull_request(r)
        stream, fmt = r.u8(), r.u8()
        cf = r.string() if r.boolean() else None
        dc = DeliveryControl(r.u16(), r.u16(), r.u16(), r.u16()) if r.boolean() else None
        return cls(request_id, oid, stream, fmt, cf, dc)


@dataclass(frozen=True, slots=True)
class _Sample(_Sub):
    """A sample with its BaseObjectRequest. FORMAT_DATA: ``data`` is the serialised sample
    (PX4: plain little-endian CDR, no encapsulation header); other formats stay unparsed."""

    request_id: int
    object_id: int
    data: bytes
    data_format: int = FORMAT_DATA

    def flags(self) -> int:
        return FLAG_E | (self.data_format & FORMAT_MASK)

    def payload(self) -> bytes:
        w = Writer()
        _push_request(w, self.request_id, self.object_id)
        w.raw(self.data)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Self:
        request_id, oid = _pull_request(r)
        return cls(request_id, oid, r.raw(r.remaining()), flags & FORMAT_MASK)


@dataclass(frozen=True, slots=True)
class WriteData(_Sample):
    """§8.3.5.8 WRITE_DATA: a client's writer publishes."""

    sid = SubmessageId.WRITE_DATA


@dataclass(frozen=True, slots=True)
class Data(_Sample):
    """§8.3.5.10 DATA: a sample for a READ_DATA (``request_id`` is that request's)."""

    sid = SubmessageId.DATA


@dataclass(frozen=True, slots=True)
class AckNack(_Sub):
    """§8.3.5.11 ACKNACK: ``first_unacked`` and a 16-bit NACK bitmap (bit i: first + i
    missing; eProsima puts bits 8..15 in the first octet)."""

    first_unacked: int
    nack_bitmap: int
    stream_id: int
    sid = SubmessageId.ACKNACK

    def payload(self) -> bytes:
        w = Writer()
        w.u16(self.first_unacked)
        w.raw(bytes(((self.nack_bitmap >> 8) & 0xFF, self.nack_bitmap & 0xFF)))
        w.u8(self.stream_id)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> AckNack:
        first = r.u16()
        bm = r.raw(2)
        return cls(first, (bm[0] << 8) | bm[1], r.u8())


@dataclass(frozen=True, slots=True)
class Heartbeat(_Sub):
    """§8.3.5.12 HEARTBEAT: the sender's first and last unacknowledged sequence numbers."""

    first_unacked: int
    last_unacked: int
    stream_id: int
    sid = SubmessageId.HEARTBEAT

    def payload(self) -> bytes:
        w = Writer()
        w.u16(self.first_unacked)
        w.u16(self.last_unacked)
        w.u8(self.stream_id)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Heartbeat:
        return cls(r.u16(), r.u16(), r.u8())


@dataclass(frozen=True, slots=True)
class Reset(_Sub):
    """§8.3.5.13 RESET (no payload)."""

    sid = SubmessageId.RESET

    def payload(self) -> bytes:
        return b""

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Reset:
        return cls()


@dataclass(frozen=True, slots=True)
class Fragment(_Sub):
    """§8.3.5.14 FRAGMENT: a piece of a message too big for the MTU (reliable streams)."""

    data: bytes
    last: bool = False
    sid = SubmessageId.FRAGMENT

    def flags(self) -> int:
        return FLAG_E | (FLAG_LAST_FRAGMENT if self.last else 0)

    def payload(self) -> bytes:
        return self.data

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Fragment:
        return cls(r.raw(r.remaining()), bool(flags & FLAG_LAST_FRAGMENT))


@dataclass(frozen=True, slots=True)
class Timestamp(_Sub):
    """§8.3.5.15 TIMESTAMP: the client's transmit time (PX4: its boot clock)."""

    transmit: Time
    sid = SubmessageId.TIMESTAMP

    def payload(self) -> bytes:
        w = Writer()
        _push_time(w, self.transmit)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> Timestamp:
        return cls(_pull_time(r))


@dataclass(frozen=True, slots=True)
class TimestampReply(_Sub):
    """§8.3.5.16 TIMESTAMP_REPLY: agent transmit, agent receive, client originate."""

    transmit: Time
    receive: Time
    originate: Time
    sid = SubmessageId.TIMESTAMP_REPLY

    def payload(self) -> bytes:
        w = Writer()
        for t in (self.transmit, self.receive, self.originate):
            _push_time(w, t)
        return w.getvalue()

    @classmethod
    def parse(cls, r: Reader, flags: int) -> TimestampReply:
        return cls(_pull_time(r), _pull_time(r), _pull_time(r))


@dataclass(frozen=True, slots=True)
class Unknown:
    """A submessage id this codec does not interpret (e.g. PERFORMANCE); kept verbatim."""

    submessage_id: int
    raw_flags: int
    data: bytes

    @property
    def sid(self) -> int:
        return self.submessage_id

    def flags(self) -> int:
        return self.raw_flags

    def payload(self) -> bytes:
        return self.data


Submessage = (
    CreateClient
    | StatusAgent
    | Create
    | GetInfo
    | Delete
    | StatusReply
    | Info
    | ReadData
    | WriteData
    | Data
    | AckNack
    | Heartbeat
    | Reset
    | Fragment
    | Timestamp
    | TimestampReply
    | Unknown
)

_PARSERS: Final = {
    SubmessageId.CREATE_CLIENT: CreateClient.parse,
    SubmessageId.CREATE: Create.parse,
    SubmessageId.GET_INFO: GetInfo.parse,
    SubmessageId.DELETE: Delete.parse,
    SubmessageId.STATUS_AGENT: StatusAgent.parse,
    SubmessageId.STATUS: StatusReply.parse,
    SubmessageId.INFO: Info.parse,
    SubmessageId.WRITE_DATA: WriteData.parse,
    SubmessageId.READ_DATA: ReadData.parse,
    SubmessageId.DATA: Data.parse,
    SubmessageId.ACKNACK: AckNack.parse,
    SubmessageId.HEARTBEAT: Heartbeat.parse,
    SubmessageId.RESET: Reset.parse,
    SubmessageId.FRAGMENT: Fragment.parse,
    SubmessageId.TIMESTAMP: Timestamp.parse,
    SubmessageId.TIMESTAMP_REPLY: TimestampReply.parse,
}


@dataclass(frozen=True, slots=True)
class Message:
    header: Header
    submessages: tuple[Submessage, ...]
    # octets after the last submessage, fewer than 4: eProsima's client rounds some messages up
    # to 4 and leaves whatever its buffer held there (its reader stops below 4 octets)
    padding: bytes = b""


def decode_header(data: bytes) -> tuple[Header, int]:
    """§8.3.2: the header and the offset of the first submessage."""
    if len(data) < 4:
        raise DecodeError(f"message of {len(data)} bytes has no header")
    session_id, stream_id, seq = struct.unpack_from("<BBH", data)
    if session_id < 0x80:
        if len(data) < 8:
            raise DecodeError("session id below 0x80 without its client key")
        return Header(session_id, stream_id, seq, bytes(data[4:8])), 8
    return Header(session_id, stream_id, seq), 4


def decode_submessage(sid: int, flags: int, payload: bytes) -> Submessage:
    """One submessage's payload (§8.3.5); ``DecodeError`` if it does not parse exactly."""
    parser = _PARSERS.get(sid)  # type: ignore[call-overload]
    if parser is None:
        return Unknown(sid, flags, payload)
    r = Reader(payload, little=bool(flags & FLAG_E))
    sub: Submessage = parser(r, flags)
    r.end()
    return sub


def split_submessages(data: bytes, offset: int) -> tuple[list[tuple[int, int, bytes]], bytes]:
    """§8.3.4: (id, flags, payload) of each submessage, each 4-aligned in the message, and
    the octets after the last one (fewer than 4, ignored as eProsima's agent ignores them)."""
    out: list[tuple[int, int, bytes]] = []
    pos = offset
    while pos < len(data):
        tail = data[pos:]
        if out and len(tail) < 4:
            return out, bytes(tail)
        pos += (-pos) % 4
        if pos + 4 > len(data):
            raise DecodeError(f"truncated submessage header at {pos}")
        sid, flags, length = struct.unpack_from("<BBH", data, pos)
        pos += 4
        if pos + length > len(data):
            raise DecodeError(f"submessage {sid} of {length} bytes, {len(data) - pos} left")
        out.append((sid, flags, bytes(data[pos : pos + length])))
        pos += length
        if len(out) > MAX_SUBMESSAGES:
            raise DecodeError("too many submessages")
    if not out:
        raise DecodeError("message without submessages")
    return out, b""


def decode_message(data: bytes) -> Message:
    """A whole datagram (§8.3.1: one transport datagram carries one message)."""
    header, offset = decode_header(data)
    parts, padding = split_submessages(data, offset)
    return Message(header, tuple(decode_submessage(s, f, p) for s, f, p in parts), padding)


def encode_submessage(sub: Submessage) -> bytes:
    payload = sub.payload()
    if len(payload) > 0xFFFF:
        raise ValueError("submessage payload over 65535 bytes")
    return struct.pack("<BBH", sub.sid, sub.flags(), len(payload)) + payload


def encode_message(
    header: Header, submessages: tuple[Submessage, ...] | list[Submessage], padding: bytes = b""
) -> bytes:
    out = bytearray(header.encode())
    for i, sub in enumerate(submessages):
        if i:
            out += b"\0" * ((-len(out)) % 4)
        out += encode_submessage(sub)
    return bytes(out) + padding
