"""RTPS messages: the 20-byte header and the submessages swarmd speaks.

Understood: INFO_TS, INFO_DST, DATA, HEARTBEAT, ACKNACK, GAP. Recognised and skipped
(kept as ``SkippedSubmessage`` with id and length): DATA_FRAG, PAD, INFO_SRC, INFO_REPLY,
NACK_FRAG, HEARTBEAT_FRAG, security and vendor-specific submessages. DDSI-RTPS 2.5 section
8.3 and 9.4; ids from cyclonedds ``ddsi_protocol.h`` and wireshark ``packet-rtps.c``.

Invariant: ``decode_message`` raises ``DecodeError`` and nothing else, for any input. A
message that is cut exactly at a submessage boundary decodes to the submessages before the
cut; a cut anywhere else raises.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final

from swarmd.rtps.buffer import Reader, Writer
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.parameters import ParameterList, pull_parameter_list, push_parameter_list
from swarmd.rtps.types import (
    EntityId,
    GuidPrefix,
    ProtocolVersion,
    Time,
    VendorId,
    join_sequence_number,
    split_sequence_number,
)

HEADER_SIZE: Final = 20
MAGIC: Final = b"RTPS"
MAGIC_RTI: Final = b"RTPX"  # RTI's variant of the protocol id, also dissected by Wireshark


class SubmessageId:
    PAD: Final = 0x01
    ACKNACK: Final = 0x06
    HEARTBEAT: Final = 0x07
    GAP: Final = 0x08
    INFO_TS: Final = 0x09
    INFO_SRC: Final = 0x0C
    INFO_REPLY_IP4: Final = 0x0D
    INFO_DST: Final = 0x0E
    INFO_REPLY: Final = 0x0F
    NACK_FRAG: Final = 0x12
    HEARTBEAT_FRAG: Final = 0x13
    DATA: Final = 0x15
    DATA_FRAG: Final = 0x16


FLAG_E: Final = 0x01  # endianness: little-endian when set
# INFO_TS
FLAG_INVALIDATE: Final = 0x02
# DATA
FLAG_Q: Final = 0x02
FLAG_D: Final = 0x04
FLAG_K: Final = 0x08
FLAG_N: Final = 0x10
# HEARTBEAT / ACKNACK
FLAG_FINAL: Final = 0x02
FLAG_LIVELINESS: Final = 0x04

# readerId .. writerSN: what octetsToInlineQos counts in the standard DATA layout
DATA_OCTETS_TO_INLINE_QOS: Final = 16
# spec 9.4.2.6: a SequenceNumberSet holds at most 256 bits
MAX_SN_SET_BITS: Final = 256

_HEADER = struct.Struct(">4sBB2s12s")


@dataclass(frozen=True, slots=True)
class Header:
    protocol_version: ProtocolVersion
    vendor_id: VendorId
    guid_prefix: GuidPrefix


@dataclass(frozen=True, slots=True)
class InfoTs:
    """Source timestamp for the following submessages; ``None`` invalidates it (flag I)."""

    timestamp: Time | None


@dataclass(frozen=True, slots=True)
class InfoDst:
    """Destination participant of the following submessages; all zeros means everyone."""

    guid_prefix: GuidPrefix


@dataclass(frozen=True, slots=True)
class Data:
    reader_id: EntityId
    writer_id: EntityId
    writer_sn: int
    inline_qos: ParameterList | None = None
    serialized_payload: bytes | None = None  # including the 4-byte encapsulation header
    key: bool = False  # flag K: the payload is the serialized key, not data
    non_standard_payload: bool = False  # flag N (RTPS 2.3+)


@dataclass(frozen=True, slots=True)
class SequenceNumberSet:
    """bitmapBase and a bitmap of ``num_bits`` bits, MSB first in 32-bit words (spec 9.4.2.6)."""

    base: int
    num_bits: int
    words: tuple[int, ...] = ()

    @classmethod
    def of(
        cls, base: int, members: list[int] | tuple[int, ...], num_bits: int | None = None
    ) -> SequenceNumberSet:
        """Build a set with bit ``sn - base`` set for every member."""
        if num_bits is None:
            num_bits = (max(members) - base + 1) if members else 0
        if not 0 <= num_bits <= MAX_SN_SET_BITS:
            raise ValueError(f"SequenceNumberSet of {num_bits} bits exceeds {MAX_SN_SET_BITS}")
        words = [0] * ((num_bits + 31) // 32)
        for sn in members:
            i = sn - base
            if not 0 <= i < num_bits:
                raise ValueError(f"sequence number {sn} outside [{base}, {base + num_bits})")
            words[i // 32] |= 1 << (31 - i % 32)
        return cls(base, num_bits, tuple(words))

    def members(self) -> list[int]:
        out = []
        for i in range(self.num_bits):
            if self.words[i // 32] & (1 << (31 - i % 32)):
                out.append(self.base + i)
        return out


@dataclass(frozen=True, slots=True)
class Heartbeat:
    reader_id: EntityId
    writer_id: EntityId
    first_sn: int
    last_sn: int
    count: int
    final: bool = False
    liveliness: bool = False


@dataclass(frozen=True, slots=True)
class AckNack:
    reader_id: EntityId
    writer_id: EntityId
    reader_sn_state: SequenceNumberSet
    count: int
    final: bool = False


@dataclass(frozen=True, slots=True)
class Gap:
    reader_id: EntityId
    writer_id: EntityId
    gap_start: int
    gap_list: SequenceNumberSet


@dataclass(frozen=True, slots=True)
class SkippedSubmessage:
    """A submessage swarmd recognises (or not) but does not interpret, e.g. DATA_FRAG."""

    submessage_id: int
    flags: int
    body: bytes


Submessage = InfoTs | InfoDst | Data | Heartbeat | AckNack | Gap | SkippedSubmessage


@dataclass(frozen=True, slots=True)
class Message:
    header: Header
    submessages: tuple[Submessage, ...]


# --- decoding -------------------------------------------------------------------------------


def decode_header(data: bytes) -> Header:
    if len(data) < HEADER_SIZE:
        raise DecodeError(f"RTPS header needs {HEADER_SIZE} bytes, got {len(data)}")
    magic, major, minor, vendor, prefix = _HEADER.unpack_from(data, 0)
    if magic != MAGIC and magic != MAGIC_RTI:
        raise DecodeError(f"not an RTPS message (protocol id {magic!r})")
    if major != 2:
        raise DecodeError(f"unsupported RTPS major version {major}")
    return Header(ProtocolVersion(major, minor), VendorId(vendor), GuidPrefix(prefix))


def _pull_entity_id(r: Reader) -> EntityId:
    return EntityId(r.pull_bytes(4, "entity id"))


def _pull_sn(r: Reader) -> int:
    high = r.pull_i32("sequence number high")
    low = r.pull_u32("sequence number low")
    return join_sequence_number(high, low)


def _pull_sn_set(r: Reader) -> SequenceNumberSet:
    base = _pull_sn(r)
    num_bits = r.pull_u32("SequenceNumberSet numBits")
    if num_bits > MAX_SN_SET_BITS:
        raise DecodeError(f"SequenceNumberSet numBits {num_bits} exceeds {MAX_SN_SET_BITS}")
    words = tuple(r.pull_u32("SequenceNumberSet bitmap") for _ in range((num_bits + 31) // 32))
    return SequenceNumberSet(base, num_bits, words)


_DATA_HEAD = {True: struct.Struct("<HH4s4siI"), False: struct.Struct(">HH4s4siI")}
_DATA_HEAD_SIZE: Final = 20


def _decode_data(r: Reader, flags: int) -> Data:
    # Every SPDP sample passes here: one struct unpack for the fixed part, not six pulls.
    if flags & FLAG_D and flags & FLAG_K:
        raise DecodeError("DATA has both D and K flags set")
    if r.remaining() < _DATA_HEAD_SIZE:
        raise DecodeError(f"truncated DATA header: {r.remaining()} bytes")
    _extra, to_inline_qos, reader_id, writer_id, sn_high, sn_low = _DATA_HEAD[r.little].unpack_from(
        r.data, r.pos
    )
    if to_inline_qos < DATA_OCTETS_TO_INLINE_QOS:
        raise DecodeError(f"DATA octetsToInlineQos {to_inline_qos} < {DATA_OCTETS_TO_INLINE_QOS}")
    r.skip(4 + to_inline_qos, "DATA header extension")
    inline_qos = pull_parameter_list(r) if flags & FLAG_Q else None
    payload = None
    if flags & (FLAG_D | FLAG_K):
        payload = r.pull_bytes(r.remaining(), "DATA payload")
        if len(payload) < 4:
            raise DecodeError(f"DATA payload of {len(payload)} bytes lacks an encapsulation header")
    return Data(
        EntityId(reader_id),
        EntityId(writer_id),
        join_sequence_number(sn_high, sn_low),
        inline_qos,
        payload,
        key=bool(flags & FLAG_K),
        non_standard_payload=bool(flags & FLAG_N),
    )


def _decode_submessage(sm_id: int, flags: int, r: Reader) -> Submessage:
    if sm_id == SubmessageId.DATA:
        return _decode_data(r, flags)
    if sm_id == SubmessageId.INFO_TS:
        if flags & FLAG_INVALIDATE:
            return InfoTs(None)
        seconds = r.pull_u32("INFO_TS seconds")
        fraction = r.pull_u32("INFO_TS fraction")
        return InfoTs(Time(seconds, fraction))
    if sm_id == SubmessageId.INFO_DST:
        return InfoDst(GuidPrefix(r.pull_bytes(12, "INFO_DST guidPrefix")))
    if sm_id == SubmessageId.HEARTBEAT:
        return Heartbeat(
            _pull_entity_id(r),
            _pull_entity_id(r),
            _pull_sn(r),
            _pull_sn(r),
            r.pull_u32("HEARTBEAT count"),
            final=bool(flags & FLAG_FINAL),
            liveliness=bool(flags & FLAG_LIVELINESS),
        )
    if sm_id == SubmessageId.ACKNACK:
        return AckNack(
            _pull_entity_id(r),
            _pull_entity_id(r),
            _pull_sn_set(r),
            r.pull_u32("ACKNACK count"),
            final=bool(flags & FLAG_FINAL),
        )
    if sm_id == SubmessageId.GAP:
        return Gap(_pull_entity_id(r), _pull_entity_id(r), _pull_sn(r), _pull_sn_set(r))
    return SkippedSubmessage(sm_id, flags, r.pull_bytes(r.remaining()))


def decode_message(data: bytes) -> Message:
    """Decode one RTPS message (one UDP datagram).

    Raises ``DecodeError`` for anything malformed, and never any other exception.
    """
    try:
        return _decode_message(bytes(data))
    except DecodeError:
        raise
    except (ValueError, IndexError, struct.error, OverflowError) as exc:  # pragma: no cover
        # Defence in depth for the invariant; every path above is meant to raise DecodeError.
        raise DecodeError(f"malformed RTPS message: {exc}") from None


def _decode_message(data: bytes) -> Message:
    header = decode_header(data)
    submessages: list[Submessage] = []
    pos = HEADER_SIZE
    end = len(data)
    while pos < end:
        if end - pos < 4:
            raise DecodeError(f"truncated submessage header at offset {pos}")
        sm_id = data[pos]
        flags = data[pos + 1]
        little = bool(flags & FLAG_E)
        length = int.from_bytes(data[pos + 2 : pos + 4], "little" if little else "big")
        body_start = pos + 4
        if length == 0 and sm_id not in (SubmessageId.PAD, SubmessageId.INFO_TS):
            # spec 9.4.5.1.3: 0 means "extends to the end of the message"
            body_end = end
        else:
            body_end = body_start + length
            if body_end > end:
                raise DecodeError(
                    f"submessage 0x{sm_id:02x} at offset {pos} claims {length} bytes, "
                    f"{end - body_start} remain"
                )
        reader = Reader(data, body_start, body_end, little=little)
        submessages.append(_decode_submessage(sm_id, flags, reader))
        pos = body_end
    return Message(header, tuple(submessages))


# --- encoding -------------------------------------------------------------------------------


def encode_header(header: Header) -> bytes:
    v = header.protocol_version
    return _HEADER.pack(MAGIC, v.major, v.minor, header.vendor_id.value, header.guid_prefix.value)


def _push_sn(w: Writer, sn: int) -> None:
    high, low = split_sequence_number(sn)
    w.push_i32(high)
    w.push_u32(low)


def _push_sn_set(w: Writer, s: SequenceNumberSet) -> None:
    _push_sn(w, s.base)
    w.push_u32(s.num_bits)
    for word in s.words:
        w.push_u32(word)


def _encode_body(sm: Submessage, w: Writer) -> tuple[int, int]:
    """Write the body of ``sm`` into ``w``; return (submessage id, flags without E)."""
    if isinstance(sm, Data):
        if sm.key and sm.serialized_payload is None:
            raise ValueError("DATA with K flag needs a serialized key payload")
        w.push_u16(0)
        w.push_u16(DATA_OCTETS_TO_INLINE_QOS)
        w.push_bytes(sm.reader_id.value)
        w.push_bytes(sm.writer_id.value)
        _push_sn(w, sm.writer_sn)
        flags = 0
        if sm.inline_qos is not None:
            flags |= FLAG_Q
            push_parameter_list(w, sm.inline_qos)
        if sm.serialized_payload is not None:
            flags |= FLAG_K if sm.key else FLAG_D
            w.push_bytes(sm.serialized_payload)
            w.pad_to(0)
        if sm.non_standard_payload:
            flags |= FLAG_N
        return SubmessageId.DATA, flags
    if isinstance(sm, InfoTs):
        if sm.timestamp is None:
            return SubmessageId.INFO_TS, FLAG_INVALIDATE
        w.push_u32(sm.timestamp.seconds)
        w.push_u32(sm.timestamp.fraction)
        return SubmessageId.INFO_TS, 0
    if isinstance(sm, InfoDst):
        w.push_bytes(sm.guid_prefix.value)
        return SubmessageId.INFO_DST, 0
    if isinstance(sm, Heartbeat):
        w.push_bytes(sm.reader_id.value)
        w.push_bytes(sm.writer_id.value)
        _push_sn(w, sm.first_sn)
        _push_sn(w, sm.last_sn)
        w.push_u32(sm.count)
        return SubmessageId.HEARTBEAT, (FLAG_FINAL if sm.final else 0) | (
            FLAG_LIVELINESS if sm.liveliness else 0
        )
    if isinstance(sm, AckNack):
        w.push_bytes(sm.reader_id.value)
        w.push_bytes(sm.writer_id.value)
        _push_sn_set(w, sm.reader_sn_state)
        w.push_u32(sm.count)
        return SubmessageId.ACKNACK, FLAG_FINAL if sm.final else 0
    if isinstance(sm, Gap):
        w.push_bytes(sm.reader_id.value)
        w.push_bytes(sm.writer_id.value)
        _push_sn(w, sm.gap_start)
        _push_sn_set(w, sm.gap_list)
        return SubmessageId.GAP, 0
    raise TypeError(f"cannot encode {type(sm).__name__}")


def encode_submessage(sm: Submessage) -> bytes:
    """One submessage, little-endian (flag E set), with an exact octetsToNextHeader.

    A ``SkippedSubmessage`` is written back exactly as received, in its own byte order.
    """
    if isinstance(sm, SkippedSubmessage):
        order = "<" if sm.flags & FLAG_E else ">"
        return struct.pack(f"{order}BBH", sm.submessage_id, sm.flags, len(sm.body)) + sm.body
    body = Writer(little=True)
    sm_id, flags = _encode_body(sm, body)
    if len(body) > 0xFFFF:
        raise ValueError(f"submessage body of {len(body)} bytes exceeds 65535")
    return struct.pack("<BBH", sm_id, flags | FLAG_E, len(body)) + body.getvalue()


def encode_message(header: Header, submessages: tuple[Submessage, ...] | list[Submessage]) -> bytes:
    return encode_header(header) + b"".join(encode_submessage(sm) for sm in submessages)
