"""DDS-XRCE 1.0 submessages (OMG formal/20-02-01 §8.3.5) as PX4's client uses them: each a
frozen dataclass with ``parse(reader, flags)`` and ``payload()``; the message codec
(``swarmd.xrce.message``) frames them. Binary object representations are eProsima's
``*_Binary`` types (Micro XRCE-DDS ``xrce_types``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Self

from swarmd.xrce.buffer import DecodeError, Reader, Writer
from swarmd.xrce.ids import (
    FLAG_E,
    FLAG_LAST_FRAGMENT,
    FLAG_REPLACE,
    FLAG_REUSE,
    FORMAT_DATA,
    FORMAT_MASK,
    VENDOR_SWARMD,
    XRCE_COOKIE,
    XRCE_VERSION,
    ObjectKind,
    Repr,
    SubmessageId,
)

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
