"""Parameter lists (spec 9.4.2.11): ``pid:u16, length:u16, value[length]`` until PID_SENTINEL.

A list is kept as raw ``Parameter`` values in wire order with its byte order, so a decoder
can skip what it does not understand and an encoder reproduces the bytes it owns. Typed
values (locators, durations, strings) are pulled by the helpers below.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

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


# Fast DDS rejects PID_ENTITY_NAME longer than 256 octets (ParameterSerializer.hpp)
MAX_STRING_OCTETS: Final = 256


@dataclass(frozen=True, slots=True)
class Parameter:
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


def pull_parameter_list(reader: Reader) -> ParameterList:
    """Read parameters up to and including PID_SENTINEL; a list without one is truncated."""
    params: list[Parameter] = []
    while True:
        pid = reader.pull_u16("parameter id")
        length = reader.pull_u16("parameter length")
        if pid == Pid.SENTINEL:
            # the sentinel's length field is to be ignored (spec 9.4.2.11)
            return ParameterList(tuple(params), reader.little)
        if length % 4:
            raise DecodeError(f"parameter 0x{pid:04x} length {length} is not a multiple of 4")
        value = reader.pull_bytes(length, f"parameter 0x{pid:04x}")
        if pid != Pid.PAD:
            params.append(Parameter(pid, value))


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


def _reader(param: Parameter, little: bool) -> Reader:
    return Reader(param.value, little=little)


def value_u32(param: Parameter, little: bool) -> int:
    return _reader(param, little).pull_u32(f"parameter 0x{param.pid:04x}")


def value_i32(param: Parameter, little: bool) -> int:
    return _reader(param, little).pull_i32(f"parameter 0x{param.pid:04x}")


def pack_u32(value: int, little: bool = True) -> bytes:
    return value.to_bytes(4, "little" if little else "big")


def pack_i32(value: int, little: bool = True) -> bytes:
    return value.to_bytes(4, "little" if little else "big", signed=True)


def value_duration(param: Parameter, little: bool) -> Duration:
    r = _reader(param, little)
    seconds = r.pull_i32("duration seconds")
    fraction = r.pull_u32("duration fraction")
    return Duration(seconds, fraction)


def pack_duration(value: Duration, little: bool = True) -> bytes:
    return pack_i32(value.seconds, little) + pack_u32(value.fraction, little)


def value_locator(param: Parameter, little: bool) -> Locator:
    r = _reader(param, little)
    if param.value and len(param.value) < LOCATOR_SIZE:
        raise DecodeError(f"locator parameter 0x{param.pid:04x} has {len(param.value)} bytes")
    kind = r.pull_i32("locator kind")
    port = r.pull_u32("locator port")
    address = r.pull_bytes(16, "locator address")
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


def value_string(param: Parameter, little: bool) -> str:
    return pull_cdr_string(_reader(param, little), f"parameter 0x{param.pid:04x}")


def pack_string(value: str, little: bool = True) -> bytes:
    w = Writer(little=little)
    push_cdr_string(w, value)
    return w.getvalue()


def value_octets(param: Parameter, little: bool) -> bytes:
    """An octet sequence: u32 count then the octets (USER_DATA, GROUP_DATA, ...)."""
    r = _reader(param, little)
    n = r.pull_u32(f"parameter 0x{param.pid:04x} count")
    return r.pull_bytes(n, f"parameter 0x{param.pid:04x} octets")


def pack_octets(value: bytes, little: bool = True) -> bytes:
    raw = pack_u32(len(value), little) + value
    return raw + bytes(-len(raw) % 4)


def value_properties(param: Parameter, little: bool) -> tuple[tuple[str, str], ...]:
    """PID_PROPERTY_LIST: a sequence of (name, value) string pairs; binary properties ignored."""
    r = _reader(param, little)
    n = r.pull_u32("property count")
    if n > len(param.value) // 8:
        raise DecodeError(f"property count {n} cannot fit in {len(param.value)} bytes")
    out: list[tuple[str, str]] = []
    for _ in range(n):
        name = pull_cdr_string(r, "property name")
        r.align(0)
        value = pull_cdr_string(r, "property value")
        r.align(0)
        out.append((name, value))
    return tuple(out)


def pack_properties(props: tuple[tuple[str, str], ...], little: bool = True) -> bytes:
    w = Writer(little=little)
    w.push_u32(len(props))
    for name, value in props:
        push_cdr_string(w, name)
        push_cdr_string(w, value)
    return w.getvalue()
