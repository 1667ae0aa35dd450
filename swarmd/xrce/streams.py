"""Reliable and best-effort stream state (DDS-XRCE 1.0 §8.4), and bounded FRAGMENT reassembly.

Sequence numbers are u16 and wrap (§8.3.2.3): they are compared with serial-number
arithmetic (RFC 1982 with SERIAL_BITS = 16), as eProsima's ``seq_num.c`` does: ``a`` is
before ``b`` when ``(b - a) mod 2^16`` is in 1..2^15-1.

Reliable streams (§8.4.2): the receiver delivers in order, keeps out-of-order messages in a
small window and answers HEARTBEAT with ACKNACK (first unacked + a 16-bit NACK bitmap); the
sender keeps every unacknowledged message, retransmits the ones NACKed and sends HEARTBEAT
on a timer while anything is unacknowledged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

SEQ_MOD: Final = 1 << 16
SEQ_HALF: Final = 1 << 15
# Out-of-order messages a reliable input stream holds (PX4's own history is 4). Caps memory
# a peer can pin with a window of far-future sequence numbers.
MAX_RELIABLE_WINDOW: Final = 16
# Unacknowledged messages a reliable output stream keeps; beyond it the oldest is dropped
# (a client that never ACKs cannot grow the agent's memory).
MAX_RELIABLE_HISTORY: Final = 64
# Bytes one FRAGMENT reassembly may hold. Stops the "endless fragments" memory exhaustion:
# a peer sending non-last FRAGMENTs forever; PX4's largest message (a participant XML
# profile, ~500 B) fits many times over.
MAX_REASSEMBLY: Final = 16 * 1024


def seq_add(a: int, n: int) -> int:
    return (a + n) % SEQ_MOD


def seq_diff(a: int, b: int) -> int:
    """``a - b`` as a signed distance in -2^15..2^15-1."""
    d = (a - b) % SEQ_MOD
    return d - SEQ_MOD if d >= SEQ_HALF else d


def seq_lt(a: int, b: int) -> bool:
    """``a`` before ``b`` in serial-number order."""
    return seq_diff(b, a) > 0


@dataclass(slots=True)
class ReliableIn:
    """A reliable input stream: in-order delivery, a bounded reorder window."""

    expected: int = 0  # eProsima streams start at 0 (last handled = 0xFFFF)
    held: dict[int, bytes] = field(default_factory=dict)
    duplicates: int = 0
    out_of_window: int = 0

    def receive(self, seq: int, body: bytes) -> list[bytes]:
        """Accept message ``seq``; return every message now deliverable, in order."""
        d = seq_diff(seq, self.expected)
        if d < 0 or seq in self.held:
            self.duplicates += 1
            return []
        if d >= MAX_RELIABLE_WINDOW:
            self.out_of_window += 1
            return []
        if d > 0:
            self.held[seq] = body
            return []
        out = [body]
        self.expected = seq_add(self.expected, 1)
        while self.expected in self.held:
            out.append(self.held.pop(self.expected))
            self.expected = seq_add(self.expected, 1)
        return out

    def on_heartbeat(self, first: int, last: int) -> None:
        """The sender no longer has anything before ``first``: skip the gap (§8.4.2)."""
        if seq_lt(self.expected, first) and seq_diff(first, self.expected) < SEQ_HALF:
            for s in list(self.held):
                if seq_lt(s, first):
                    del self.held[s]
            self.expected = first

    def acknack(self, last_known: int | None = None) -> tuple[int, int]:
        """(first unacked, NACK bitmap): bit i set when ``expected + i`` is missing."""
        top = last_known
        for s in self.held:
            if top is None or seq_lt(top, s):
                top = s
        bitmap = 0
        if top is not None:
            span = min(seq_diff(top, self.expected) + 1, 16)
            for i in range(span):
                if seq_add(self.expected, i) not in self.held:
                    bitmap |= 1 << i
        return self.expected, bitmap


@dataclass(slots=True)
class ReliableOut:
    """A reliable output stream: history of unacknowledged messages by sequence number.

    A message pushed with an *expiry* (a time, and a stand-in: another message of the same
    sequence number that does nothing) is sent again as itself only before that time; a
    repair asked for later sends the stand-in. A command frame is worth repeating only
    while its sender still waits for its answer: later, the repeat would deliver the
    command after its sender gave it up (docs/security.md, "A command frame delivered
    late"). The message cannot simply be dropped: Micro XRCE-DDS's client ignores a
    HEARTBEAT's first sequence number (``uxr_process_heartbeat``), so a gap in a reliable
    stream is never skipped and every later message would wait behind it.
    """

    next_seq: int = 0
    history: dict[int, bytes] = field(default_factory=dict)  # seq -> whole datagram
    # seq -> (until when the message itself may be sent again, its stand-in)
    expiry: dict[int, tuple[float, bytes]] = field(default_factory=dict)
    evicted: int = 0
    expired: int = 0  # repairs that sent a stand-in, not the late message

    def push(self, build: bytes, expiry: tuple[float, bytes] | None = None) -> int:
        seq = self.next_seq
        self.next_seq = seq_add(seq, 1)
        self.history[seq] = build
        if expiry is not None:
            self.expiry[seq] = expiry
        while len(self.history) > MAX_RELIABLE_HISTORY:
            oldest = min(self.history, key=lambda s: seq_diff(s, self.next_seq))
            del self.history[oldest]
            self.expiry.pop(oldest, None)
            self.evicted += 1
        return seq

    def first_unacked(self) -> int:
        if not self.history:
            return self.next_seq
        return min(self.history, key=lambda s: seq_diff(s, self.next_seq))

    def on_acknack(self, first_unacked: int, bitmap: int, now: float) -> list[bytes]:
        """Forget what is acknowledged; return the NACKed messages to send again (a stand-in
        for each one past its expiry at ``now``)."""
        if seq_diff(first_unacked, self.next_seq) > 0:
            return []  # acknowledges what we never sent: forged or confused, ignore
        for s in list(self.history):
            if seq_lt(s, first_unacked):
                del self.history[s]
                self.expiry.pop(s, None)
        out = []
        for i in range(16):
            if bitmap & (1 << i):
                seq = seq_add(first_unacked, i)
                body = self.history.get(seq)
                if body is None:
                    continue
                until = self.expiry.get(seq)
                if until is not None and now >= until[0]:
                    body = self.history[seq] = until[1]  # from now on, only the stand-in
                    del self.expiry[seq]
                    self.expired += 1
                out.append(body)
        return out

    def heartbeat(self) -> tuple[int, int] | None:
        """(first, last) unacknowledged, or None when all is acknowledged."""
        if not self.history:
            return None
        return self.first_unacked(), seq_add(self.next_seq, -1)


@dataclass(slots=True)
class BestEffortIn:
    """Best-effort input (§8.4.1): deliver only what is newer than the last delivered."""

    last: int | None = None
    stale: int = 0

    def accept(self, seq: int) -> bool:
        if self.last is not None and not seq_lt(self.last, seq):
            self.stale += 1
            return False
        self.last = seq
        return True


@dataclass(slots=True)
class Reassembly:
    """FRAGMENT payloads of one reliable stream, joined when the LAST flag arrives (§8.3.5.14)."""

    buf: bytearray = field(default_factory=bytearray)
    overflows: int = 0

    def add(self, data: bytes, last: bool) -> bytes | None:
        if len(self.buf) + len(data) > MAX_REASSEMBLY:
            self.buf.clear()
            self.overflows += 1
            return None
        self.buf += data
        if not last:
            return None
        out = bytes(self.buf)
        self.buf.clear()
        return out
