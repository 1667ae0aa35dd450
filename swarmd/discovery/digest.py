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


def encode_heard(indices: Iterable[int], swarm_size: int) -> bytes:
    """The bitmap listing ``indices`` (each in ``0 <= i < swarm_size``)."""
    out = bytearray(bitmap_size(swarm_size))
    for i in indices:
        if not 0 <= i < swarm_size:
            raise ValueError(f"participant index {i} outside the bundle's 0..{swarm_size - 1}")
        out[i >> 3] |= 1 << (i & 7)
    return bytes(out)


def lists(bitmap: bytes | None, index: int) -> bool:
    """Whether ``bitmap`` has the bit of participant ``index`` set (absent bitmap: no)."""
    if bitmap is None or index < 0 or (index >> 3) >= len(bitmap):
        return False
    return bool(bitmap[index >> 3] & (1 << (index & 7)))


def decode_heard(bitmap: bytes | None, swarm_size: int) -> frozenset[int]:
    """Every index below ``swarm_size`` that ``bitmap`` lists."""
    return frozenset(i for i in range(swarm_size) if lists(bitmap, i))
