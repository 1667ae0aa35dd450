"""RTPS readers for user data: best-effort and reliable (stateful, spec 8.4.12).

Theory of operation (reliable reader, DDSI-RTPS 2.5 section 8.4.12 "Reliable StatefulReader"):

* One ``WriterProxy`` per matched remote writer. ``next_expected`` is the lowest SN not yet
  delivered or declared irrelevant; everything below it has been handed up exactly once.
* DATA at or above ``next_expected`` is buffered (at most ``MAX_BUFFERED_SAMPLES``), then
  every contiguous run from ``next_expected`` is delivered in SN order. DATA below it, or
  already buffered, is a duplicate and dropped: this is the per-SN dedup.
* HEARTBEAT ``[first, last]``: SNs below ``first`` are no longer available, so the reader
  moves past them (8.4.12.2.5 "irrelevant"); it answers with an ACKNACK whose base is
  ``next_expected`` and whose bitmap lists the SNs still missing up to ``last`` (at most 256,
  spec 9.4.2.6). A HEARTBEAT whose count and last SN are both not newer than what was seen is
  a duplicate or a reordered old one and is ignored (8.3.7.5 "count").
* GAP marks SNs irrelevant: they advance ``next_expected`` without delivering anything.

The best-effort reader delivers a sample only if its SN is above every SN seen from that
writer (keep-last-1: an older sample arriving late is stale, not news).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

from swarmd.dataplane.outgoing import Outgoing
from swarmd.rtps.message import MAX_SN_SET_BITS, AckNack, Data, Gap, Heartbeat, SequenceNumberSet
from swarmd.rtps.types import Guid

# Out-of-order samples held per writer while a hole is repaired. Stops a writer (or a forger
# of its GUID) from growing reader memory by sending SNs far ahead of the hole.
MAX_BUFFERED_SAMPLES: Final = 64
# A reader answers a writer's HEARTBEATs at most this often (review 16). Each ACKNACK goes to
# the writer's participant's signed locator, a victim of a captured member's choice where
# the bundle pins no address, and is larger than the HEARTBEAT that drew it: without a bound
# a captured member's HEARTBEATs drew one each, at any rate (the twin of the writer's
# ACKNACK_REPLY_RATE). An honest writer HEARTBEATs at most every HEARTBEAT_PERIOD_S (0.2 s):
# twice that pace, as the writer's bound is. Past it the HEARTBEAT still moves the reader
# (skips, deliveries); only its answer waits for the next HEARTBEAT (DDSI-RTPS 8.4.12.1:
# a reader may delay its response, heartbeatResponseDelay). Spent once per writer per
# datagram received (the plane answers only a datagram's last HEARTBEAT of each writer).
HEARTBEAT_REPLY_RATE: Final = 10.0
HEARTBEAT_REPLY_BURST: Final = 4.0


@dataclass(frozen=True, slots=True)
class Delivered:
    """A sample handed up in SN order; ``payload`` is None for a DATA without data (K flag)."""

    writer: Guid
    sn: int
    payload: bytes | None


@dataclass(slots=True)
class ReaderCounters:
    delivered: int = 0
    duplicates: int = 0
    stale: int = 0
    buffer_full: int = 0
    skipped: int = 0  # SNs passed over because the writer no longer has them (lost for good)
    gapped: int = 0
    heartbeats_stale: int = 0
    heartbeats_unanswered: int = 0  # past HEARTBEAT_REPLY_RATE: taken, not answered
    acknacks_sent: int = 0


@dataclass(frozen=True, slots=True)
class ReaderResult:
    delivered: list[Delivered] = field(default_factory=list)
    replies: list[Outgoing] = field(default_factory=list)
    dropped: str | None = None  # reason when the submessage was not acted on


_IRRELEVANT: Final = b""  # buffer marker for a GAPped SN (a real payload is >= 4 octets)


@dataclass(slots=True)
class BestEffortReader:
    """Delivers the newest sample of each matched writer, never an older one."""

    guid: Guid
    highest: dict[Guid, int] = field(default_factory=dict)  # matched writer -> highest SN seen
    counters: ReaderCounters = field(default_factory=ReaderCounters)

    def add_writer(self, writer: Guid) -> None:
        self.highest.setdefault(writer, 0)

    def remove_writer(self, writer: Guid) -> None:
        self.highest.pop(writer, None)

    def matched(self, writer: Guid) -> bool:
        return writer in self.highest

    def on_data(self, writer: Guid, data: Data) -> ReaderResult:
        if data.writer_sn <= self.highest[writer]:
            self.counters.stale += 1
            return ReaderResult(dropped="stale_sample")
        self.highest[writer] = data.writer_sn
        self.counters.delivered += 1
        return ReaderResult([Delivered(writer, data.writer_sn, _payload(data))])

    def on_heartbeat(self, writer: Guid, hb: Heartbeat) -> ReaderResult:
        return ReaderResult()  # a best-effort reader never acknowledges (spec 8.4.11)

    def may_answer(self, writer: Guid, now: float) -> bool:
        return False  # it never has an answer to send

    def on_gap(self, writer: Guid, gap: Gap) -> ReaderResult:
        return ReaderResult()


@dataclass(slots=True)
class WriterProxy:
    """What a reliable reader knows about one remote writer (spec 8.4.10.4)."""

    guid: Guid
    next_expected: int = 1
    buffer: dict[int, bytes | None] = field(default_factory=dict)  # SN -> payload, out of order
    last_heartbeat_count: int = 0
    last_heartbeat_sn: int = 0  # highest lastSN announced
    acknack_count: int = 0
    # answers to its HEARTBEATs left (a token bucket: HEARTBEAT_REPLY_RATE), as of reply_at
    reply_tokens: float = HEARTBEAT_REPLY_BURST
    reply_at: float | None = None


class ReliableReader:
    """Reliable stateful reader: in-order, exactly-once-per-SN delivery. See the module doc."""

    def __init__(self, guid: Guid) -> None:
        self.guid = guid
        self.proxies: dict[Guid, WriterProxy] = {}
        self.counters = ReaderCounters()
        # ACKNACK counts outlive a proxy: the writer may not have noticed the unmatch and
        # would ignore counts that start from 1 again. Keys are bundle GUIDs, so bounded.
        self._acknack_counts: dict[Guid, int] = {}

    def add_writer(self, writer: Guid) -> None:
        if writer not in self.proxies:
            proxy = WriterProxy(writer, acknack_count=self._acknack_counts.get(writer, 0))
            self.proxies[writer] = proxy

    def remove_writer(self, writer: Guid) -> None:
        proxy = self.proxies.pop(writer, None)
        if proxy is not None:
            self._acknack_counts[writer] = proxy.acknack_count

    def matched(self, writer: Guid) -> bool:
        return writer in self.proxies

    def on_data(self, writer: Guid, data: Data) -> ReaderResult:
        proxy = self.proxies[writer]
        sn = data.writer_sn
        if sn < proxy.next_expected or sn in proxy.buffer:
            self.counters.duplicates += 1
            return ReaderResult(dropped="duplicate_sample")
        if sn != proxy.next_expected and len(proxy.buffer) >= MAX_BUFFERED_SAMPLES:
            # Full: keep the SNs closest to the hole, they are delivered first; the one
            # evicted (or refused) is simply requested again by a later ACKNACK.
            self.counters.buffer_full += 1
            highest = max(proxy.buffer)
            if sn > highest:
                return ReaderResult(dropped="reorder_buffer_full")
            del proxy.buffer[highest]
        payload = _payload(data)
        proxy.buffer[sn] = payload
        return ReaderResult(self._drain(proxy))

    def on_gap(self, writer: Guid, gap: Gap) -> ReaderResult:
        proxy = self.proxies[writer]
        end = gap.gap_list.base  # [gap_start, base) is irrelevant, plus the bitmap members
        if gap.gap_start <= proxy.next_expected < end:
            self._skip_to(proxy, end, counted_as="gapped")
        elif proxy.next_expected < gap.gap_start and end - gap.gap_start <= MAX_SN_SET_BITS:
            for sn in range(gap.gap_start, end):
                self._mark_irrelevant(proxy, sn)
        for sn in gap.gap_list.members():
            self._mark_irrelevant(proxy, sn)
        return ReaderResult(self._drain(proxy))

    def on_heartbeat(self, writer: Guid, hb: Heartbeat) -> ReaderResult:
        proxy = self.proxies[writer]
        if hb.count <= proxy.last_heartbeat_count and hb.last_sn <= proxy.last_heartbeat_sn:
            self.counters.heartbeats_stale += 1
            return ReaderResult(dropped="stale_heartbeat")
        # A newer incarnation restarts its count at 1 but announces higher SNs: still fresh.
        proxy.last_heartbeat_count = hb.count
        proxy.last_heartbeat_sn = max(proxy.last_heartbeat_sn, hb.last_sn)
        delivered: list[Delivered] = []
        if hb.first_sn > proxy.next_expected:
            # Samples already buffered below first_sn were received: hand them up before
            # moving past the ones the writer no longer has.
            delivered += self._skip_to(proxy, hb.first_sn, counted_as="skipped")
        delivered += self._drain(proxy)
        top = min(hb.last_sn, proxy.next_expected + MAX_SN_SET_BITS - 1)
        missing = [sn for sn in range(proxy.next_expected, top + 1) if sn not in proxy.buffer]
        if not missing and hb.final:
            return ReaderResult(delivered)
        proxy.acknack_count += 1
        self.counters.acknacks_sent += 1
        acknack = AckNack(
            self.guid.entity_id,
            writer.entity_id,
            SequenceNumberSet.of(proxy.next_expected, missing),
            count=proxy.acknack_count,
            final=not missing,
        )
        return ReaderResult(delivered, [Outgoing(writer.prefix, acknack)])

    def may_answer(self, writer: Guid, now: float) -> bool:
        """Whether the ACKNACK ``on_heartbeat`` made for ``writer`` may go out now: one
        token of the writer's answer budget (``HEARTBEAT_REPLY_RATE``); the caller sends
        at most one per writer per datagram received. Refused, it is counted
        (``heartbeats_unanswered``) and the next HEARTBEAT is answered instead."""
        proxy = self.proxies.get(writer)
        if proxy is None:
            return False
        if proxy.reply_at is not None and now > proxy.reply_at:
            refill = (now - proxy.reply_at) * HEARTBEAT_REPLY_RATE
            proxy.reply_tokens = min(HEARTBEAT_REPLY_BURST, proxy.reply_tokens + refill)
        proxy.reply_at = now if proxy.reply_at is None else max(proxy.reply_at, now)
        if proxy.reply_tokens < 1.0:
            self.counters.heartbeats_unanswered += 1
            return False
        proxy.reply_tokens -= 1.0
        return True

    # --- helpers ----------------------------------------------------------------------------

    def _mark_irrelevant(self, proxy: WriterProxy, sn: int) -> None:
        if sn >= proxy.next_expected and sn not in proxy.buffer:
            if len(proxy.buffer) < MAX_BUFFERED_SAMPLES:
                proxy.buffer[sn] = _IRRELEVANT

    def _skip_to(self, proxy: WriterProxy, new_next: int, counted_as: str) -> list[Delivered]:
        """Deliver what is buffered below ``new_next`` in order and move past the rest."""
        out: list[Delivered] = []
        below = sorted(s for s in proxy.buffer if s < new_next)
        for sn in below:
            payload = proxy.buffer.pop(sn)
            if payload != _IRRELEVANT:
                out.append(Delivered(proxy.guid, sn, payload))
        passed = new_next - proxy.next_expected - len(below)
        self.counters.gapped += len(below) - len(out)
        if counted_as == "gapped":
            self.counters.gapped += passed
        else:
            self.counters.skipped += passed
        self.counters.delivered += len(out)
        proxy.next_expected = new_next
        return out

    def _drain(self, proxy: WriterProxy) -> list[Delivered]:
        out: list[Delivered] = []
        while proxy.next_expected in proxy.buffer:
            sn = proxy.next_expected
            payload = proxy.buffer.pop(sn)
            if payload == _IRRELEVANT:
                self.counters.gapped += 1
            else:
                out.append(Delivered(proxy.guid, sn, payload))
            proxy.next_expected += 1
        self.counters.delivered += len(out)
        return out


def _payload(data: Data) -> bytes | None:
    # K (key only) or no payload at all: the SN still counts, the application gets nothing
    if data.key or data.serialized_payload is None:
        return None
    return data.serialized_payload
