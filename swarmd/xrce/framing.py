"""Serial framing for XRCE over a UART (PX4 ``UXRCE_DDS_CFG`` = a TELEM port).

DDS-XRCE 1.0 §11.2 leaves stream transports to the implementation; Micro XRCE-DDS's
``stream_framing_protocol.c`` (the code PX4 links) frames each message as

    0x7E | src addr | dst addr | len lo | len hi | payload | crc lo | crc hi

where every octet after the leading flag that equals 0x7E or 0x7D is sent as 0x7D followed
by the octet XOR 0x20, and the CRC is CRC-16/ARC (reflected polynomial 0xA001, initial 0)
over the unescaped payload only. ``Deframer`` is a sans-IO byte-stream parser: feed it bytes,
it returns whole messages and counts what it dropped.
"""

from __future__ import annotations

from typing import Final

FLAG: Final = 0x7E
ESC: Final = 0x7D
XOR: Final = 0x20
MAX_FRAME_PAYLOAD: Final = 512  # PX4's MTU (UXR_CONFIG_SERIAL_TRANSPORT_MTU); longer = noise


def _table() -> tuple[int, ...]:
    out = []
    for i in range(256):
        crc = i
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        out.append(crc)
    return tuple(out)


_CRC_TABLE: Final = _table()


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16/ARC as ``uxr_update_crc`` computes it."""
    for b in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ b) & 0xFF]
    return crc


def _escape(data: bytes) -> bytes:
    out = bytearray()
    for b in data:
        if b in (FLAG, ESC):
            out += bytes((ESC, b ^ XOR))
        else:
            out.append(b)
    return bytes(out)


def frame(payload: bytes, *, src: int = 0, dst: int = 0) -> bytes:
    """One framed message (``uxr_write_framed_msg``)."""
    if len(payload) > 0xFFFF:
        raise ValueError("frame payload over 65535 bytes")
    crc = crc16(payload)
    body = bytes((src, dst, len(payload) & 0xFF, len(payload) >> 8)) + payload
    return bytes((FLAG,)) + _escape(body + bytes((crc & 0xFF, crc >> 8)))


class Deframer:
    """Byte stream in, (src, dst, payload) out. Bad CRCs, oversize lengths and stray bytes
    are counted in ``dropped`` and resynchronise on the next 0x7E; memory is bounded by
    ``MAX_FRAME_PAYLOAD``."""

    def __init__(self, max_payload: int = MAX_FRAME_PAYLOAD) -> None:
        self.max_payload = max_payload
        self._buf = bytearray()  # unescaped octets of the frame being read
        self._in_frame = False
        self._escaped = False
        self.dropped = 0
        self.frames = 0

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        out: list[tuple[int, int, bytes]] = []
        for b in data:
            if b == FLAG:
                if self._in_frame and self._buf:
                    self.dropped += 1  # a new frame began before this one completed
                self._in_frame, self._escaped = True, False
                self._buf.clear()
                continue
            if not self._in_frame:
                continue  # noise between frames
            if b == ESC and not self._escaped:
                self._escaped = True
                continue
            if self._escaped:
                b ^= XOR
                self._escaped = False
            self._buf.append(b)
            got = self._check()
            if got is not None:
                out.append(got)
        return out

    def _check(self) -> tuple[int, int, bytes] | None:
        buf = self._buf
        if len(buf) < 4:
            return None
        length = buf[2] | (buf[3] << 8)
        if length > self.max_payload:
            self._reset_drop()
            return None
        if len(buf) < 4 + length + 2:
            return None
        payload = bytes(buf[4 : 4 + length])
        crc = buf[4 + length] | (buf[5 + length] << 8)
        src, dst = buf[0], buf[1]
        self._in_frame = False
        buf.clear()
        if crc != crc16(payload):
            self.dropped += 1
            return None
        self.frames += 1
        return src, dst, payload

    def _reset_drop(self) -> None:
        self.dropped += 1
        self._in_frame = False
        self._buf.clear()
