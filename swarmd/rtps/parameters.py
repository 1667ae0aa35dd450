"""Parameter lists (spec 9.4.2.11): ``pid:u16, length:u16, value[length]`` until PID_SENTINEL.

A list is kept as raw ``Parameter`` values in wire order with its byte order, so a decoder
can skip what it does not understand and an encoder reproduces the bytes it owns. Typed
values (locators, durations, strings) are pulled by the helpers below.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Final, NamedTuple

from swarmd.rtps.buffer import Reader, Writer
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import LOCATOR_SIZE, Locator
from swarmd.rtps.types import Duration


class Pid:
    """Parameter ids (spec table 9.12/9.13, wireshark packet-rtps.c)."""

    PAD: Final = 0x0000
    SENTINEL: Final = 0x0001
    PARTICIPANT_LEASE_DURATION: Final = 0x0002
    TOPIC_NAME: Final = 0x0005
    TYPE_NAME: Final = 0x0007
    DOMAIN_ID: Final = 0x000F
    PROTOCOL_VERSION: Final = 0x0015
    VENDORID: Final = 0x0016
    RELIABILITY: Final = 0x001A
    LIVELINESS: Final = 0x001B
    DURABILITY: Final = 0x001D
    HISTORY: Final = 0x0040
    USER_DATA: Final = 0x002C
    UNICAST_LOCATOR: Final = 0x002F
    MULTICAST_LOCATOR: Final = 0x0030
    DEFAULT_UNICAST_LOCATOR: Final = 0x0031
    METATRAFFIC_UNICAST_LOCATOR: Final = 0x0032
    METATRAFFIC_MULTICAST_LOCATOR: Final = 0x0033
    PARTICIPANT_MANUAL_LIVELINESS_COUNT: Final = 0x0034
    EXPECTS_INLINE_QOS: Final = 0x0043
    PARTICIPANT_BUILTIN_ENDPOINTS: Final = 0x0044
    DEFAULT_MULTICAST_LOCATOR: Final = 0x0048
    PARTICIPANT_GUID: Final = 0x0050
    BUILTIN_ENDPOINT_SET: Final = 0x0058
    PROPERTY_LIST: Final = 0x0059
    ENDPOINT_GUID: Final = 0x005A
    ENTITY_NAME: Final = 0x0062
    KEY_HASH: Final = 0x0070
    STATUS_INFO: Final = 0x0071
    DOMAIN_TAG: Final = 0x4014

    VENDOR_SPECIFIC_FLAG: Final = 0x8000
    MUST_UNDERSTAND_FLAG: Final = 0x4000


# Fast DDS rejects PID_ENTITY_NAME longer than 256 octets (ParameterSerializer.hpp), and so
# does ``value_string`` (ENTITY_NAME, DOMAIN_TAG): a foreign participant's name is kept in
# the foreign table and shown in every ``swarmctl status`` (review 16: 64 KiB names made the
# status longer than swarmctl takes). swarmd's own names are at most 129 octets (bundle).
MAX_STRING_OCTETS: Final = 256


class Parameter(NamedTuple):
    """One parameter as on the wire. A NamedTuple, not a dataclass: a DATA(p) holds ~20 of
    them and tuple construction is several times cheaper than a frozen dataclass's."""

    pid: int
    value: bytes  # as on the wire, including the padding to a multiple of 4


@dataclass(frozen=True, slots=True)
class ParameterList:
    params: tuple[Parameter, ...]
    little: bool = True

    def get(self, pid: int) -> Parameter | None:
        for p in self.params:
            if p.pid == pid:
                return p
        return None

    def get_all(self, pid: int) -> list[Parameter]:
        return [p for p in self.params if p.pid == pid]


# NamedTuple's generated __new__ is a Python-level function; tuple.__new__ skips it.
_new_parameter = tuple.__new__
_PARAM_HEADER = {True: struct.Struct("<HH"), False: struct.Struct(">HH")}


def pull_parameter_list(reader: Reader) -> ParameterList:
    """Read parameters up to and including PID_SENTINEL; a list without one is truncated."""
    # The hot path of every SPDP decode: bounds are checked inline rather than through
    # Reader's per-field pulls (3x faster on a 15-parameter Cyclone DATA(p)).
    data, pos, end, little = reader.data, reader.pos, reader.end, reader.little
    unpack = _PARAM_HEADER[little].unpack_from
    params: list[Parameter] = []
    while True:
        if pos + 4 > end:
            raise DecodeError(f"parameter list truncated at offset {pos} (no PID_SENTINEL)")
        pid, length = unpack(data, pos)
        pos += 4
        if pid == Pid.SENTINEL:
            # the sentinel's length field is to be ignored (spec 9.4.2.11)
            reader.pos = pos
            return ParameterList(tuple(params), little)
        if length % 4:
            raise DecodeError(f"parameter 0x{pid:04x} length {length} is not a multiple of 4")
        if pos + length > end:
            raise DecodeError(
                f"truncated parameter 0x{pid:04x}: needs {length} bytes, {end - pos} remain"
            )
        if pid != Pid.PAD:
            params.append(_new_parameter(Parameter, (pid, data[pos : pos + length])))
        pos += length


def push_parameter_list(writer: Writer, params: ParameterList | tuple[Parameter, ...]) -> None:
    items = params.params if isinstance(params, ParameterList) else params
    for p in items:
        value = p.value
        if len(value) % 4:
            value = value + bytes(-len(value) % 4)
        if len(value) > 0xFFFF:
            raise ValueError(f"parameter 0x{p.pid:04x} value of {len(value)} bytes is too long")
        writer.push_u16(p.pid)
        writer.push_u16(len(value))
        writer.push_bytes(value)
    writer.push_u16(Pid.SENTINEL)
    writer.push_u16(0)


# --- typed values -------------------------------------------------------------------------


# Typed values are read with precompiled structs straight from the parameter's bytes: this
# is the inner loop of every SPDP decode, and a Reader per value costs a third of the time.
_U32V = {True: struct.Struct("<I"), False: struct.Struct(">I")}
_I32V = {True: struct.Struct("<i"), False: struct.Struct(">i")}
_DURATION = {True: struct.Struct("<iI"), False: struct.Struct(">iI")}
_LOCATOR = {True: struct.Struct("<iI16s"), False: struct.Struct(">iI16s")}


def _need(param: Parameter, size: int, what: str) -> None:
    if len(param.value) < size:
        raise DecodeError(
            f"parameter 0x{param.pid:04x} ({what}) has {len(param.value)} bytes, needs {size}"
        )


def value_u32(param: Parameter, little: bool) -> int:
    _need(param, 4, "u32")
    value: int = _U32V[little].unpack_from(param.value)[0]
    return value


def value_i32(param: Parameter, little: bool) -> int:
    _need(param, 4, "i32")
    value: int = _I32V[little].unpack_from(param.value)[0]
    return value


def pack_u32(value: int, little: bool = True) -> bytes:
    return value.to_bytes(4, "little" if little else "big")


def pack_i32(value: int, little: bool = True) -> bytes:
    return value.to_bytes(4, "little" if little else "big", signed=True)


def value_duration(param: Parameter, little: bool) -> Duration:
    _need(param, 8, "duration")
    seconds, fraction = _DURATION[little].unpack_from(param.value)
    return Duration(seconds, fraction)


def pack_duration(value: Duration, little: bool = True) -> bytes:
    return pack_i32(value.seconds, little) + pack_u32(value.fraction, little)


def value_locator(param: Parameter, little: bool) -> Locator:
    _need(param, LOCATOR_SIZE, "locator")
    kind, port, address = _LOCATOR[little].unpack_from(param.value)
    return Locator(kind, port, address)


def pack_locator(value: Locator, little: bool = True) -> bytes:
    return pack_i32(value.kind, little) + pack_u32(value.port, little) + value.address


def pull_cdr_string(reader: Reader, what: str) -> str:
    """A CDR string: u32 length including the NUL, the octets, the NUL."""
    n = reader.pull_u32(f"{what} length")
    if n == 0:
        # Some stacks send length 0 for an empty string; tolerate it (no NUL follows).
        return ""
    raw = reader.pull_bytes(n, what)
    if raw[-1] != 0:
        raise DecodeError(f"{what} is not NUL-terminated")
    try:
        return raw[:-1].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError(f"{what} is not valid UTF-8: {exc.reason}") from None


def push_cdr_string(writer: Writer, value: str, base: int = 0) -> None:
    raw = value.encode("utf-8") + b"\x00"
    writer.push_u32(len(raw))
    writer.push_bytes(raw)
    writer.pad_to(base)


def _string_at(data: bytes, pos: int, little: bool, what: str) -> tuple[str, int]:
    """The CDR string at ``pos`` and the 4-aligned offset after it."""
    if pos + 4 > len(data):
        raise DecodeError(f"truncated {what} length at offset {pos}")
    n: int = _U32V[little].unpack_from(data, pos)[0]
    pos += 4
    if n == 0:
        return "", pos
    end = pos + n
    if end > len(data):
        raise DecodeError(f"{what} claims {n} bytes, {len(data) - pos} remain")
    if data[end - 1] != 0:
        raise DecodeError(f"{what} is not NUL-terminated")
    try:
        text = data[pos : end - 1].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DecodeError(f"{what} is not valid UTF-8: {exc.reason}") from None
    return text, end + (-end % 4)


def value_string(param: Parameter, little: bool) -> str:
    """A CDR string parameter of at most ``MAX_STRING_OCTETS`` octets (its NUL aside)."""
    n = value_u32(param, little)  # its octets and their NUL
    if n > MAX_STRING_OCTETS + 1:
        raise DecodeError(
            f"parameter 0x{param.pid:04x}: a string of {n - 1} octets, over {MAX_STRING_OCTETS}"
        )
    return _string_at(param.value, 0, little, f"parameter 0x{param.pid:04x}")[0]


def pack_string(value: str, little: bool = True) -> bytes:
    w = Writer(little=little)
    push_cdr_string(w, value)
    return w.getvalue()


def value_octets(param: Parameter, little: bool) -> bytes:
    """An octet sequence: u32 count then the octets (USER_DATA, GROUP_DATA, ...)."""
    n = value_u32(param, little)
    if 4 + n > len(param.value):
        raise DecodeError(
            f"parameter 0x{param.pid:04x} claims {n} octets, has {len(param.value) - 4}"
        )
    return param.value[4 : 4 + n]


def pack_octets(value: bytes, little: bool = True) -> bytes:
    raw = pack_u32(len(value), little) + value
    return raw + bytes(-len(raw) % 4)


def value_properties(param: Parameter, little: bool) -> tuple[tuple[str, str], ...]:
    """PID_PROPERTY_LIST: a sequence of (name, value) string pairs; binary properties ignored."""
    data = param.value
    n = value_u32(param, little)
    if n > len(data) // 8:
        raise DecodeError(f"property count {n} cannot fit in {len(data)} bytes")
    pos = 4
    out: list[tuple[str, str]] = []
    for _ in range(n):
        name, pos = _string_at(data, pos, little, "property name")
        value, pos = _string_at(data, pos, little, "property value")
        out.append((name, value))
    return tuple(out)


def pack_properties(props: tuple[tuple[str, str], ...], little: bool = True) -> bytes:
    w = Writer(little=little)
    w.push_u32(len(props))
    for name, value in props:
        push_cdr_string(w, name)
        push_cdr_string(w, value)
    return w.getvalue()
