"""eProsima's binary object representations inside CREATE (Repr.BIN), as PX4 sends them.

DDS-XRCE 1.0 §7.7.3.3 leaves the binary form to the vendor; Micro XRCE-DDS defines
``OBJK_Topic_Binary``, ``OBJK_Publisher_Binary``, ``OBJK_DataWriter_Binary``, ... (its
``xrce_types.h``). Each blob is its own CDR stream, aligned from the blob's first octet.
Parsers raise ``DecodeError`` only; encoders produce what the eProsima client does (zeroed
padding), so ``encode_x(parse_x(b)) == b`` for every canonical blob.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.xrce.buffer import DecodeError, Reader, Writer

MAX_SEQUENCE = 16  # partitions / group data entries: PX4 sends none; bounds the work


@dataclass(frozen=True, slots=True)
class TopicBinary:
    topic_name: str
    type_name: str | None = None
    type_reference: str | None = None


def parse_topic(blob: bytes) -> TopicBinary:
    r = Reader(blob)
    name = r.string()
    ref = r.string() if r.boolean() else None
    typ = r.string() if r.boolean() else None
    r.end()
    return TopicBinary(name, typ, ref)


def encode_topic(t: TopicBinary) -> bytes:
    w = Writer()
    w.string(t.topic_name)
    w.boolean(t.type_reference is not None)
    if t.type_reference is not None:
        w.string(t.type_reference)
    w.boolean(t.type_name is not None)
    if t.type_name is not None:
        w.string(t.type_name)
    return w.getvalue()


@dataclass(frozen=True, slots=True)
class GroupBinary:
    """Publisher or subscriber: an optional name and partitions (PX4: neither)."""

    name: str | None = None
    partitions: tuple[str, ...] | None = None
    group_data: bytes | None = None


def parse_group(blob: bytes) -> GroupBinary:
    r = Reader(blob)
    name = r.string() if r.boolean() else None
    partitions: tuple[str, ...] | None = None
    group_data = None
    if r.boolean():
        if r.boolean():
            n = r.u32()
            if n > MAX_SEQUENCE:
                raise DecodeError(f"{n} partitions")
            partitions = tuple(r.string() for _ in range(n))
        if r.boolean():
            group_data = r.octets()
    r.end()
    return GroupBinary(name, partitions, group_data)


def encode_group(g: GroupBinary) -> bytes:
    w = Writer()
    w.boolean(g.name is not None)
    if g.name is not None:
        w.string(g.name)
    has_qos = g.partitions is not None or g.group_data is not None
    w.boolean(has_qos)
    if has_qos:
        w.boolean(g.partitions is not None)
        if g.partitions is not None:
            w.u32(len(g.partitions))
            for p in g.partitions:
                w.string(p)
        w.boolean(g.group_data is not None)
        if g.group_data is not None:
            w.octets(g.group_data)
    return w.getvalue()


# qos_flags bits (Micro XRCE-DDS ``xrce_types.h``). PX4's writers send 0x0A (best
# effort, keep last, transient local), its readers 0x02 (best effort, keep last, volatile).
QOS_RELIABLE = 0x01
QOS_HISTORY_KEEP_LAST = 0x02
QOS_OWNERSHIP_EXCLUSIVE = 0x04
QOS_DURABILITY_TRANSIENT_LOCAL = 0x08


@dataclass(frozen=True, slots=True)
class EndpointBinary:
    """DataWriter or DataReader: the topic it serves and its QoS (``writer`` picks the tail)."""

    topic_id: int
    writer: bool
    qos_flags: int | None = None
    history_depth: int | None = None
    deadline_ms: int | None = None
    lifespan_ms: int | None = None
    user_data: bytes | None = None
    ownership_strength: int | None = None  # writer
    time_based_filter_ms: int | None = None  # reader
    content_filter: str | None = None  # reader


def parse_endpoint(blob: bytes, *, writer: bool) -> EndpointBinary:
    r = Reader(blob)
    raw = r.raw(2)
    topic_id = (raw[0] << 8) | raw[1]
    if not r.boolean():
        r.end()
        return EndpointBinary(topic_id, writer)
    flags = r.u16()
    depth = r.u16() if r.boolean() else None
    deadline = r.u32() if r.boolean() else None
    lifespan = r.u32() if r.boolean() else None
    user_data = r.octets() if r.boolean() else None
    strength = tbf = None
    cf = None
    if writer:
        strength = r.u64() if r.boolean() else None
    else:
        tbf = r.u64() if r.boolean() else None
        cf = r.string() if r.boolean() else None
    r.end()
    return EndpointBinary(
        topic_id, writer, flags, depth, deadline, lifespan, user_data, strength, tbf, cf
    )


def encode_endpoint(e: EndpointBinary) -> bytes:
    w = Writer()
    w.raw(bytes(((e.topic_id >> 8) & 0xFF, e.topic_id & 0xFF)))
    w.boolean(e.qos_flags is not None)
    if e.qos_flags is None:
        return w.getvalue()
    w.u16(e.qos_flags)
    for v in (e.history_depth,):
        w.boolean(v is not None)
        if v is not None:
            w.u16(v)
    for v in (e.deadline_ms, e.lifespan_ms):
        w.boolean(v is not None)
        if v is not None:
            w.u32(v)
    w.boolean(e.user_data is not None)
    if e.user_data is not None:
        w.octets(e.user_data)
    if e.writer:
        w.boolean(e.ownership_strength is not None)
        if e.ownership_strength is not None:
            w.u64(e.ownership_strength)
    else:
        w.boolean(e.time_based_filter_ms is not None)
        if e.time_based_filter_ms is not None:
            w.u64(e.time_based_filter_ms)
        w.boolean(e.content_filter is not None)
        if e.content_filter is not None:
            w.string(e.content_filter)
    return w.getvalue()


@dataclass(frozen=True, slots=True)
class ServiceBinary:
    """Requester or replier: the service and its request/reply types and topics."""

    service_name: str
    request_type: str
    reply_type: str
    request_topic_name: str | None = None
    reply_topic_name: str | None = None


def parse_service(blob: bytes) -> ServiceBinary:
    r = Reader(blob)
    name, req, rep = r.string(), r.string(), r.string()
    rq = r.string() if r.boolean() else None
    rr = r.string() if r.boolean() else None
    r.end()
    return ServiceBinary(name, req, rep, rq, rr)


def encode_service(s: ServiceBinary) -> bytes:
    w = Writer()
    for v in (s.service_name, s.request_type, s.reply_type):
        w.string(v)
    for o in (s.request_topic_name, s.reply_topic_name):
        w.boolean(o is not None)
        if o is not None:
            w.string(o)
    return w.getvalue()
