"""Cursor buffers over bytes with a selectable byte order.

RTPS sets endianness per submessage (flag E) and per parameter list (encapsulation id),
so the reader carries its own byte order and can be re-pointed cheaply. Every pull
checks the remaining length first and raises ``DecodeError``; nothing else escapes.
"""

from __future__ import annotations

import struct

from swarmd.rtps.errors import DecodeError

_U16 = {True: struct.Struct("<H"), False: struct.Struct(">H")}
_U32 = {True: struct.Struct("<I"), False: struct.Struct(">I")}
_I32 = {True: struct.Struct("<i"), False: struct.Struct(">i")}


class Reader:
    """Reads primitives from ``data[pos:end]`` in the byte order given by ``little``."""

    __slots__ = ("data", "end", "little", "pos")

    def __init__(self, data: bytes, pos: int = 0, end: int | None = None, *, little: bool) -> None:
        self.data = data
        self.pos = pos
        self.end = len(data) if end is None else end
        self.little = little

    def remaining(self) -> int:
        return self.end - self.pos

    def eof(self) -> bool:
        return self.pos >= self.end

    def _need(self, n: int, what: str) -> int:
        pos = self.pos
        if n < 0 or pos + n > self.end:
            raise DecodeError(
                f"truncated {what}: need {n} bytes at offset {pos}, have {self.end - pos}"
            )
        self.pos = pos + n
        return pos

    def pull_bytes(self, n: int, what: str = "bytes") -> bytes:
        pos = self._need(n, what)
        return self.data[pos : pos + n]

    def pull_u8(self, what: str = "u8") -> int:
        return self.data[self._need(1, what)]

    def pull_u16(self, what: str = "u16") -> int:
        value: int = _U16[self.little].unpack_from(self.data, self._need(2, what))[0]
        return value

    def pull_u32(self, what: str = "u32") -> int:
        value: int = _U32[self.little].unpack_from(self.data, self._need(4, what))[0]
        return value

    def pull_i32(self, what: str = "i32") -> int:
        value: int = _I32[self.little].unpack_from(self.data, self._need(4, what))[0]
        return value

    def skip(self, n: int, what: str = "padding") -> None:
        self._need(n, what)

    def align(self, base: int, alignment: int = 4) -> None:
        """Skip padding so that ``pos - base`` becomes a multiple of ``alignment``."""
        pad = (-(self.pos - base)) % alignment
        if pad:
            self._need(min(pad, self.remaining()), "alignment")


class Writer:
    """Appends primitives to a bytearray in the byte order given by ``little``."""

    __slots__ = ("buf", "little")

    def __init__(self, *, little: bool = True) -> None:
        self.buf = bytearray()
        self.little = little

    def __len__(self) -> int:
        return len(self.buf)

    def push_bytes(self, value: bytes) -> None:
        self.buf += value

    def push_u8(self, value: int) -> None:
        self.buf.append(value)

    def push_u16(self, value: int) -> None:
        self.buf += _U16[self.little].pack(value)

    def push_u32(self, value: int) -> None:
        self.buf += _U32[self.little].pack(value)

    def push_i32(self, value: int) -> None:
        self.buf += _I32[self.little].pack(value)

    def pad_to(self, base: int, alignment: int = 4) -> None:
        self.buf += bytes((-(len(self.buf) - base)) % alignment)

    def patch_u16(self, offset: int, value: int) -> None:
        _U16[self.little].pack_into(self.buf, offset, value)

    def getvalue(self) -> bytes:
        return bytes(self.buf)
