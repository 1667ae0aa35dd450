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
from dataclasses import dataclass
from typing import Final

from swarmd.xrce.buffer import DecodeError, Reader
from swarmd.xrce.ids import (
    FLAG_E,
    FLAG_LAST_FRAGMENT,
    FLAG_REPLACE,
    FLAG_REUSE,
    FORMAT_DATA,
    FORMAT_MASK,
    INFO_ACTIVITY,
    INFO_CONFIGURATION,
    MAX_SUBMESSAGES,
    OBJECT_ID_AGENT,
    OBJECT_ID_CLIENT,
    SESSION_ID_NONE_WITH_KEY,
    SESSION_ID_NONE_WITHOUT_KEY,
    STREAM_BEST_EFFORT_MIN,
    STREAM_NONE,
    STREAM_RELIABLE_MIN,
    VENDOR_SWARMD,
    XRCE_COOKIE,
    XRCE_VERSION,
    ObjectKind,
    Repr,
    Status,
    SubmessageId,
    object_id,
    object_ident,
    object_kind,
)
from swarmd.xrce.submessages import (
    AckNack,
    AgentRepresentation,
    Create,
    CreateClient,
    Data,
    Delete,
    DeliveryControl,
    Fragment,
    GetInfo,
    Heartbeat,
    Info,
    Locator,
    ReadData,
    Reset,
    StatusAgent,
    StatusReply,
    Time,
    Timestamp,
    TimestampReply,
    Unknown,
    WriteData,
)

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


# the codec's public names, wherever they are defined (callers import them from here)
__all__ = [
    "AckNack",
    "AgentRepresentation",
    "Create",
    "CreateClient",
    "Data",
    "DecodeError",
    "Delete",
    "DeliveryControl",
    "FLAG_E",
    "FLAG_LAST_FRAGMENT",
    "FLAG_REPLACE",
    "FLAG_REUSE",
    "FORMAT_DATA",
    "FORMAT_MASK",
    "Fragment",
    "GetInfo",
    "Header",
    "Heartbeat",
    "INFO_ACTIVITY",
    "INFO_CONFIGURATION",
    "Info",
    "Locator",
    "MAX_SUBMESSAGES",
    "Message",
    "OBJECT_ID_AGENT",
    "OBJECT_ID_CLIENT",
    "ObjectKind",
    "ReadData",
    "Repr",
    "Reset",
    "SESSION_ID_NONE_WITHOUT_KEY",
    "SESSION_ID_NONE_WITH_KEY",
    "STREAM_BEST_EFFORT_MIN",
    "STREAM_NONE",
    "STREAM_RELIABLE_MIN",
    "Status",
    "StatusAgent",
    "StatusReply",
    "Submessage",
    "SubmessageId",
    "Time",
    "Timestamp",
    "TimestampReply",
    "Unknown",
    "VENDOR_SWARMD",
    "WriteData",
    "XRCE_COOKIE",
    "XRCE_VERSION",
    "decode_header",
    "decode_message",
    "decode_submessage",
    "encode_message",
    "encode_submessage",
    "object_id",
    "object_ident",
    "object_kind",
    "split_submessages",
]
