"""What the agent and the client engines share: output queue, events, drop counting, and the
receive side of a session's streams (DDS-XRCE 1.0 §8.4)."""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from typing import Final

from swarmd.xrce.buffer import DecodeError
from swarmd.xrce.events import Address, PacketDropped, XrceEvent
from swarmd.xrce.message import (
    AckNack,
    Header,
    Heartbeat,
    Submessage,
    encode_message,
    split_submessages,
)
from swarmd.xrce.streams import BestEffortIn, ReliableIn

MAX_EVENTS: Final = 4096  # undrained events kept; the driver drains after every input

Parts = list[tuple[int, int, bytes]]


class Endpoint:
    """Base of ``XrceAgent`` and ``XrceClient``: the sans-IO output side of the protocol."""

    def __init__(self) -> None:
        self._out: list[tuple[bytes, Address]] = []
        self._events: deque[XrceEvent] = deque()
        self.dropped: Counter[str] = Counter()
        self.events_lost = 0
        # repairs sent as a stand-in: the message had expired (a command frame given up)
        self.stand_ins = 0

    def datagrams_to_send(self) -> list[tuple[bytes, Address]]:
        out, self._out = self._out, []
        return out

    def next_event(self) -> XrceEvent | None:
        return self._events.popleft() if self._events else None

    def _drop(self, source: Address, reason: str) -> None:
        self.dropped[reason.split(":", 1)[0]] += 1
        self._emit(PacketDropped(source, reason))

    def _emit(self, event: XrceEvent) -> None:
        if len(self._events) >= MAX_EVENTS:
            self._events.popleft()
            self.events_lost += 1
        self._events.append(event)


def receive_stream(
    header: Header,
    data: bytes,
    offset: int,
    parts: Parts,
    *,
    reliable: dict[int, ReliableIn],
    best_effort: dict[int, BestEffortIn],
    handle: Callable[[Parts], None],
    reply: Callable[[Header, list[Submessage]], None],
) -> bool:
    """Route one in-session message by stream (§8.4): stream 0 and new best-effort messages
    go to ``handle`` at once; reliable ones in order, then an ACKNACK goes to ``reply``.
    Returns False for a stale best-effort message (dropped)."""
    stream = header.stream_id
    if stream == 0:
        handle(parts)
        return True
    if stream < 0x80:
        if not best_effort.setdefault(stream, BestEffortIn()).accept(header.sequence_nr):
            return False
        handle(parts)
        return True
    rin = reliable.setdefault(stream, ReliableIn())
    for body in rin.receive(header.sequence_nr, data[offset:]):
        try:
            bparts, _pad = split_submessages(body, 0)
        except DecodeError:  # pragma: no cover - the same bytes were split once already
            continue
        handle(bparts)
    first, bitmap = rin.acknack()
    reply(header, [AckNack(first, bitmap, stream)])
    return True


def stand_in(header: Header) -> bytes:
    """A reliable message that does nothing, to send at ``header``'s sequence number in
    place of one that expired (``streams.ReliableOut``): a HEARTBEAT naming that message
    alone. The receiver takes it in order as any message and answers an ACKNACK; Micro
    XRCE-DDS's client (``read_submessage_heartbeat``) and ours note the stream's last
    sequence number, nothing else. The sequence is filled, so what waits behind it moves.
    """
    seq = header.sequence_nr
    return encode_message(header, [Heartbeat(seq, seq, header.stream_id)])
