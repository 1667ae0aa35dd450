"""A little-endian CDR cursor for DDS-XRCE payloads.

DDS-XRCE 1.0 (OMG formal/20-02-01) §8.3.5: a submessage payload is XCDR-serialised with the
endianness its header's E flag names; every primitive is aligned to its own size relative to
the start of the payload (the eProsima client and agent align relative to the buffer
origin, and payloads always start 4-aligned, so the two agree up to 4-byte types; XRCE
payloads hold nothing wider than 4 bytes except the u64 time-based filter, read relative to
the binary blob it sits in). Every read checks its length first and raises ``DecodeError``.
"""

from __future__ import annotations

import struct
from typing import Final


class DecodeError(ValueError):
    """Raised for any input the XRCE codec cannot decode.

    Invariant of ``swarmd.xrce``: decoders raise ``DecodeError`` and nothing else, for any
    input whatsoever. Any other exception escaping a decoder is a bug.
    """


MAX_STRING: Final = 4096  # longer than any XML profile PX4 sends (~450 B); a bound, not a limit


class Reader:
    """Reads primitives from ``data`` aligned relative to ``origin``."""

    __slots__ = ("data", "pos", "origin", "little")

    def __init__(self, data: bytes, pos: int = 0, *, little: bool = True) -> None:
        self.data = data
        self.pos = pos
        self.origin = pos
        self.little = little

    def align(self, n: int) -> None:
        self.pos += (-(self.pos - self.origin)) % n

    def remaining(self) -> int:
        return len(self.data) - self.pos

    def raw(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise DecodeError(f"need {n} bytes at {self.pos}, have {len(self.data) - self.pos}")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def _unpack(self, fmt: str, size: int) -> int:
        self.align(size)
        value: int = struct.unpack((("<" if self.little else ">") + fmt), self.raw(size))[0]
        return value

    def u8(self) -> int:
        return self.raw(1)[0]

    def boolean(self) -> bool:
        v = self.u8()
        if v > 1:
            raise DecodeError(f"bool octet {v}")
        return v == 1

    def u16(self) -> int:
        return self._unpack("H", 2)

    def i16(self) -> int:
        return self._unpack("h", 2)

    def u32(self) -> int:
        return self._unpack("I", 4)

    def i32(self) -> int:
        return self._unpack("i", 4)

    def u64(self) -> int:
        return self._unpack("Q", 8)

    def octets(self) -> bytes:
        """``sequence<octet>``: u32 length, then the bytes."""
        n = self.u32()
        if n > self.remaining():
            raise DecodeError(f"sequence of {n} octets, {self.remaining()} left")
        return self.raw(n)

    def string(self) -> str:
        """CDR string: u32 length including the NUL, the bytes, the NUL."""
        n = self.u32()
        if n == 0 or n > MAX_STRING or n > self.remaining():
            raise DecodeError(f"string length {n}")
        raw = self.raw(n)
        if raw[-1] != 0:
            raise DecodeError("string without its NUL")
        try:
            return raw[:-1].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise DecodeError(f"string not UTF-8: {exc.reason}") from None

    def end(self) -> None:
        if self.pos != len(self.data):
            raise DecodeError(f"{len(self.data) - self.pos} trailing bytes")


class Writer:
    """Builds little-endian CDR aligned relative to the start of its own buffer."""

    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray()

    def align(self, n: int) -> None:
        self.buf += b"\0" * ((-len(self.buf)) % n)

    def raw(self, data: bytes) -> None:
        self.buf += data

    def u8(self, v: int) -> None:
        self.buf.append(v & 0xFF)

    def boolean(self, v: bool) -> None:
        self.buf.append(1 if v else 0)

    def u16(self, v: int) -> None:
        self.align(2)
        self.buf += struct.pack("<H", v & 0xFFFF)

    def i16(self, v: int) -> None:
        self.align(2)
        self.buf += struct.pack("<h", v)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", v & 0xFFFFFFFF)

    def i32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<i", v)

    def u64(self, v: int) -> None:
        self.align(8)
        self.buf += struct.pack("<Q", v)

    def octets(self, data: bytes) -> None:
        self.u32(len(data))
        self.buf += data

    def string(self, s: str) -> None:
        raw = s.encode("utf-8") + b"\0"
        self.u32(len(raw))
        self.buf += raw

    def getvalue(self) -> bytes:
        return bytes(self.buf)
