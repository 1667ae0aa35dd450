"""Freshness: a per-sender counter that only grows, and the receiver's replay window.

Each authenticated datagram carries ``Freshness(epoch, seq)``: ``epoch`` is the sender's boot
epoch (persisted, durably raised before its first send: ``swarmd.auth.epoch``), ``seq`` a
counter that starts at 1 in every epoch. Ordered lexicographically, so anything a sender
sent in an earlier life is older than anything it sends now, whatever happened to the
receiver's memory of the sequence numbers.

A receiver keeps one ``ReplayWindow`` per sender: the highest value accepted and a bitmap
of the ``WINDOW`` values below it in the same epoch. A value is fresh when it is above the
highest, or inside the window and not yet seen (datagrams may arrive out of order: multicast
and unicast take different paths). Anything older, or seen, is a replay.

The window only moves on ``accept``, which the caller runs *after* the datagram's
authenticator verified: a forged value, however high, moves nothing (issue 10, "verify
before any state change").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

U32_MAX: Final = 0xFFFFFFFF
# Values below the highest accepted that still count, per sender. 64 covers the reordering
# of a sender's SPDP (a few a second) and user data bursts alike; the bitmap is one int.
WINDOW: Final = 64


@dataclass(frozen=True, slots=True, order=True)
class Freshness:
    """(boot epoch, sequence) of one authenticated datagram; u32 each, compared in order."""

    epoch: int
    seq: int

    def __post_init__(self) -> None:
        if not (0 <= self.epoch <= U32_MAX and 0 <= self.seq <= U32_MAX):
            raise ValueError(f"freshness {self.epoch}/{self.seq} outside u32")

    def pack(self) -> bytes:
        """8 bytes, little-endian (the byte order of swarmd's parameter lists)."""
        return self.epoch.to_bytes(4, "little") + self.seq.to_bytes(4, "little")

    @classmethod
    def unpack(cls, data: bytes) -> Freshness:
        if len(data) != 8:
            raise ValueError("freshness is 8 bytes")
        return cls(int.from_bytes(data[:4], "little"), int.from_bytes(data[4:], "little"))


class CounterExhausted(RuntimeError):
    """2^32 - 1 datagrams in one epoch: the daemon must restart (a new epoch) to send more."""


class SendCounter:
    """This node's sending side: ``next()`` gives a value no earlier datagram carried.

    One counter per node and channel; ``epoch`` comes from ``swarmd.auth.epoch.next_epoch``.
    At 1,000 datagrams/s a u32 lasts 49 days; running out raises rather than wrapping (a
    wrapped value would be refused by every receiver as a replay)."""

    __slots__ = ("_epoch", "_seq")

    def __init__(self, epoch: int, seq: int = 0) -> None:
        if not 0 <= epoch <= U32_MAX:
            raise ValueError(f"epoch {epoch} outside u32")
        self._epoch = epoch
        self._seq = seq

    @property
    def epoch(self) -> int:
        return self._epoch

    def next(self) -> Freshness:
        if self._seq >= U32_MAX:
            raise CounterExhausted(f"sequence exhausted in epoch {self._epoch}")
        self._seq += 1
        return Freshness(self._epoch, self._seq)


class ReplayWindow:
    """One sender's accepted values: the highest, and a bitmap of the ``WINDOW`` below it.

    Fixed size whatever the sender does (the cap is the bitmap), so a table of them is
    bounded by the number of senders the caller admits (bundle participants only)."""

    __slots__ = ("_bits", "_high")

    def __init__(self) -> None:
        self._high: Freshness | None = None
        self._bits = 0  # bit i set: value (high.epoch, high.seq - i) was accepted

    @property
    def high(self) -> Freshness | None:
        """The highest value accepted, None before the first."""
        return self._high

    def is_fresh(self, f: Freshness) -> bool:
        """Whether ``f`` would be accepted; changes nothing."""
        return self.is_fresh_at(f.epoch, f.seq)

    def is_fresh_at(self, epoch: int, seq: int) -> bool:
        """``is_fresh`` on the two numbers as read off the wire, before any object is built
        (the replay check is the cheap refusal a flood of replays meets: docs/security.md)."""
        high = self._high
        if high is None or epoch > high.epoch:
            return True
        if epoch < high.epoch:
            return False
        if seq > high.seq:
            return True
        back = high.seq - seq
        return back < WINDOW and not (self._bits >> back) & 1

    def restore(self, high: Freshness) -> None:
        """Start from a persisted highest value: it and the ``WINDOW`` values below it count
        as seen (what was between them is unknown after a restart, so refused: a sender's
        real datagrams are above ``high``)."""
        self._high, self._bits = high, (1 << WINDOW) - 1

    def accept(self, f: Freshness) -> bool:
        """Record ``f`` (call only after its datagram verified); False if it was not fresh."""
        if not self.is_fresh(f):
            return False
        high = self._high
        if high is None or f.epoch > high.epoch:
            self._high, self._bits = f, 1
        elif f.seq > high.seq:
            shift = f.seq - high.seq
            self._bits = ((self._bits << shift) | 1) & ((1 << WINDOW) - 1) if shift < WINDOW else 1
            self._high = f
        else:
            self._bits |= 1 << (high.seq - f.seq)
        return True
