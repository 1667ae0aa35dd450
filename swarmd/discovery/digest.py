"""The "heard" digest: which bundle participants the sender has heard (swarmd PID 0x8a02).

A bitmap over bundle participant indices, ``ceil(N / 8)`` octets, bit ``i % 8`` of octet
``i // 8`` set when index ``i`` is heard (least significant bit of octet 0 = index 0; see
docs/wire.md). 25 octets cover a 200-drone swarm. Receivers read only the bits of indices
the bundle has: a short bitmap lists nobody past its end, extra octets are ignored.
"""

from __future__ import annotations

from collections.abc import Iterable


def bitmap_size(swarm_size: int) -> int:
    return (swarm_size + 7) // 8


class HeardBitmap:
    """The digest a node sends, kept up to date one participant at a time (the engine marks a
    peer on discovery and unmarks it on loss instead of rebuilding N bits per send)."""

    __slots__ = ("_bits", "_size", "count")

    def __init__(self, swarm_size: int) -> None:
        self._size = swarm_size
        self._bits = bytearray(bitmap_size(swarm_size))
        self.count = 0  # participants listed (the engine: peers discovered)

    def mark(self, index: int) -> None:
        """List participant ``index`` (``0 <= index < swarm_size``)."""
        if not 0 <= index < self._size:
            raise ValueError(f"participant index {index} outside the bundle's 0..{self._size - 1}")
        bit = 1 << (index & 7)
        if not self._bits[index >> 3] & bit:
            self._bits[index >> 3] |= bit
            self.count += 1

    def unmark(self, index: int) -> None:
        bit = 1 << (index & 7)
        if 0 <= index < self._size and self._bits[index >> 3] & bit:
            self._bits[index >> 3] &= ~bit
            self.count -= 1

    def to_bytes(self) -> bytes:
        return bytes(self._bits)


def encode_heard(indices: Iterable[int], swarm_size: int) -> bytes:
    """The bitmap listing ``indices`` (each in ``0 <= i < swarm_size``)."""
    bitmap = HeardBitmap(swarm_size)
    for i in indices:
        bitmap.mark(i)
    return bitmap.to_bytes()


def lists(bitmap: bytes | None, index: int) -> bool:
    """Whether ``bitmap`` has the bit of participant ``index`` set (absent bitmap: no).

    The engine asks this of every DATA(p) it receives (is our own bit set?), so it stays one
    short expression."""
    octet = index >> 3
    return (
        bitmap is not None and 0 <= octet < len(bitmap) and (bitmap[octet] >> (index & 7)) & 1 == 1
    )


def decode_heard(bitmap: bytes | None, swarm_size: int) -> frozenset[int]:
    """Every index below ``swarm_size`` that ``bitmap`` lists."""
    return frozenset(i for i in range(swarm_size) if lists(bitmap, i))
