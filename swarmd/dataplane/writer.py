"""RTPS writers for user data: best-effort (stateless push) and reliable (stateful, spec 8.4.9).

Theory of operation (reliable writer, DDSI-RTPS 2.5 section 8.4.9 "Reliable StatefulWriter"):

* One ``ReaderProxy`` per matched remote reader, created when discovery reports the peer.
  A VOLATILE writer treats every sample written before the match as irrelevant to that
  reader (``relevant_from``); TRANSIENT_LOCAL makes the whole history relevant.
* A reader lost (``remove_reader``) and matched again in the same life (``add_reader(...,
  resume=True)``: the owner knows the reader's boot epoch did not change) gets its proxy
  back, not a new volatile one: what it acknowledged stays irrelevant to it, and every sample
  written since that is still in the history (the owner withdraws what stopped being valid)
  is handed over at once. DDSI-RTPS 2.5 8.4.7.5 leaves which changes are relevant to a
  reader to the writer (``ChangeForReader.is_relevant``); DDS 1.4 2.2.3.4 (DURABILITY) and
  2.2.3.16 (LIFESPAN) give the model: to a reader matched before, in the same life, the
  writer offers what TRANSIENT_LOCAL with a LIFESPAN would (samples not yet expired), to a
  new reader it stays VOLATILE. A reader whose life changed is ``forget_reader``-ed: the
  owner learns which samples it never acknowledged (docs/dataplane.md, "Rejoining while a
  command is valid").
* ``write`` stores the sample in a keep-last-N history and pushes DATA to every proxy, with a
  HEARTBEAT piggy-backed in the same datagram so the reader acknowledges at once.
* While a proxy has unacknowledged samples the writer HEARTBEATs it periodically; the period
  grows by half on every heartbeat that no ACKNACK answers (up to ``max_period_s``) and drops back
  to the base period on any fresh ACKNACK, so a lossy but live reader is repaired at full
  pace while one that vanished without discovery noticing costs a few packets, not a stream.
* A heartbeat that follows an unanswered one carries the oldest unacked samples again
  (at most ``MAX_EAGER_RESEND``): on a lossy link the DATA was probably lost too.
* An ACKNACK acknowledges everything below its bitmap base and requests the bitmap's
  members: each is resent as DATA if still in history and relevant, or covered by a GAP
  (evicted from keep-last history, or written before a volatile match; spec 8.4.9.2.8).
  A reader's requests are answered at most ``ACKNACK_REPLY_RATE`` times a second (burst
  ``ACKNACK_REPLY_BURST``; spec 8.4.7.1 leaves it to the writer, nackSuppressionDuration):
  the acknowledgement still counts, only the answer waits for the next HEARTBEAT's ACKNACK.
* Heartbeats are sent per reader (INFO_DST-directed, unicast) and announce
  ``[max(first in history, relevant_from), last written]``.
* A sample may carry one payload for every reader, or one copy per reader
  (``SamplePayload``): still one sample, one SN, acknowledged and repaired per reader as
  above, but each reader is sent (and the plane MACs) only its own copy. A reader the
  sample has no copy for is not addressed by it: the SN is irrelevant to it and it gets a
  GAP, as for a sample written before a volatile match (spec 8.4.9.2.8). The data plane
  uses this for commands, so that a command's size does not grow with the swarm
  (docs/dataplane.md, "One copy per member").

Sequence numbers start at ``(incarnation << 32) + 1``: a restarted writer (new incarnation)
continues above every number its previous life used, so readers never see a sequence number
go backwards and need no restart heuristics (docs/dataplane.md, "Writer restarts").
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Final

from swarmd.dataplane.outgoing import Outgoing
from swarmd.rtps.message import MAX_SN_SET_BITS, AckNack, Data, Gap, Heartbeat, SequenceNumberSet
from swarmd.rtps.types import Guid, GuidPrefix

HEARTBEAT_PERIOD_S: Final = 0.2  # first retry of an unacknowledged sample (Cyclone: 100 ms)
# Backoff while heartbeats go unanswered. At 30 % loss a heartbeat/ACKNACK round trip fails
# half the time, so doubling up to seconds stalls live readers; x1.5 up to 1 s still limits a
# reader that vanished unnoticed to about one heartbeat a second until its lease expires.
HEARTBEAT_BACKOFF: Final = 1.5
MAX_HEARTBEAT_PERIOD_S: Final = 1.0
# Unacked samples pushed again with a heartbeat that follows an unanswered one; small, so a
# dead reader costs little and a big history is still repaired through ACKNACK.
MAX_EAGER_RESEND: Final = 4
# Heartbeats a reader may leave unanswered by a fresh-count ACKNACK before an old-count one is
# taken as a restarted reader rather than a reordered duplicate.
STALE_ACKNACK_HEARTBEATS: Final = 3
MAX_INCARNATION: Final = (1 << 31) - 1  # SequenceNumber_t.high is an int32 (spec 9.3.2)
MAX_HISTORY_DEPTH: Final = 1024  # keep-last N bound a bundle may ask for; caps writer memory
# Proxies of lost readers kept for a resume. Only readers of bundle participants that
# discovery reported up are ever matched, so the bundle bounds it; the cap is a backstop.
MAX_LOST_READERS: Final = 4096
# Answers (repairs, GAPs) to one reader's ACKNACKs, a second, and how many may come at once.
# A reader ACKNACKs each HEARTBEAT (at most every HEARTBEAT_PERIOD_S, 5/s, plus the ones
# piggy-backed on writes and repairs), so an honest one never waits on it. It stops a
# captured member (docs/security-history.md, "Network paths end to end"): every one of its fresh
# ACKNACKs was answered at once, to the locator it signed (any unicast address: a victim),
# 2.5x its own bytes at any rate (tests/test_dataplane_acknack_flood.py).
ACKNACK_REPLY_RATE: Final = 20.0
ACKNACK_REPLY_BURST: Final = 4.0


# One sample's serialized payload: the same octets for every reader, or one copy per reader
# keyed by the reader's GUID prefix (a reader with no copy is not addressed by the sample).
SamplePayload = bytes | Mapping[GuidPrefix, bytes]


def payload_for(payload: SamplePayload, reader: Guid) -> bytes | None:
    """The octets of ``payload`` that go to ``reader``; None when it is not addressed."""
    if isinstance(payload, bytes):
        return payload
    return payload.get(reader.prefix)


def first_sequence_number(incarnation: int) -> int:
    """The first SN of a writer in life ``incarnation`` (0 = the standard 1)."""
    if not 0 <= incarnation <= MAX_INCARNATION:
        raise ValueError(f"incarnation {incarnation} outside 0..{MAX_INCARNATION}")
    return (incarnation << 32) + 1


@dataclass(slots=True)
class ReaderProxy:
    """What a reliable writer knows about one remote reader (spec 8.4.7.5)."""

    guid: Guid
    relevant_from: int  # SNs below are irrelevant to this reader (volatile match point)
    acked: int  # every SN <= acked is acknowledged
    last_acknack_count: int = 0
    heartbeats_unanswered: int = 0  # heartbeats since the last accepted ACKNACK
    period_s: float = HEARTBEAT_PERIOD_S
    next_heartbeat: float = 0.0
    # answers to its ACKNACKs left (a token bucket: ACKNACK_REPLY_RATE), as of reply_at
    reply_tokens: float = ACKNACK_REPLY_BURST
    reply_at: float = 0.0


@dataclass(slots=True)
class WriterCounters:
    written: int = 0
    data_sent: int = 0
    data_resent: int = 0
    heartbeats_sent: int = 0
    gaps_sent: int = 0
    acknacks_received: int = 0
    acknacks_stale: int = 0
    acknacks_unanswered: int = 0  # fresh ACKNACKs past ACKNACK_REPLY_RATE: counted, not answered
    evicted_unacked: int = 0
    withdrawn: int = 0  # samples removed before every reader had them (validity ended)
    resumed: int = 0  # readers matched again in the same life, handed what they missed
    handed_over: int = 0  # samples pushed to resumed readers at their return
    lost_evicted: int = 0  # lost readers' proxies dropped by MAX_LOST_READERS


@dataclass(slots=True)
class BestEffortWriter:
    """Stateless best-effort writer: each sample goes once to every matched reader."""

    guid: Guid
    next_sn: int = 1
    readers: dict[Guid, None] = field(default_factory=dict)
    counters: WriterCounters = field(default_factory=WriterCounters)

    @property
    def last_sn(self) -> int:
        return self.next_sn - 1

    def add_reader(self, reader: Guid, now: float, *, resume: bool = False) -> list[Outgoing]:
        self.readers[reader] = None  # nothing kept, nothing to hand over (spec 8.4.7.1)
        return []

    def remove_reader(self, reader: Guid) -> None:
        self.readers.pop(reader, None)

    def forget_reader(self, reader: Guid) -> list[int]:
        return []

    def matched(self, reader: Guid) -> bool:
        return reader in self.readers

    def write(self, payload: SamplePayload, now: float) -> tuple[int, list[Outgoing]]:
        sn = self.next_sn
        self.next_sn += 1
        self.counters.written += 1
        out = [
            Outgoing(r.prefix, Data(r.entity_id, self.guid.entity_id, sn, None, copy))
            for r in self.readers
            if (copy := payload_for(payload, r)) is not None
        ]
        self.counters.data_sent += len(out)
        return sn, out

    def on_acknack(self, reader: Guid, acknack: AckNack, now: float) -> list[Outgoing]:
        # a best-effort writer keeps no state to repair from (spec 8.4.7.1)
        return []

    def on_timer(self, now: float) -> list[Outgoing]:
        return []

    def deadline(self) -> float | None:
        return None


class ReliableWriter:
    """Reliable stateful writer with keep-last-``depth`` history. See the module docstring."""

    def __init__(
        self,
        guid: Guid,
        *,
        depth: int,
        transient_local: bool = False,
        incarnation: int = 0,
        period_s: float = HEARTBEAT_PERIOD_S,
        max_period_s: float = MAX_HEARTBEAT_PERIOD_S,
    ) -> None:
        if not 1 <= depth <= MAX_HISTORY_DEPTH:
            raise ValueError(f"history depth {depth} outside 1..{MAX_HISTORY_DEPTH}")
        self.guid = guid
        self.depth = depth
        self.transient_local = transient_local
        self.period_s = period_s
        self.max_period_s = max_period_s
        self.first_ever = first_sequence_number(incarnation)
        self.last_sn = self.first_ever - 1
        self.history: OrderedDict[int, SamplePayload] = OrderedDict()
        self.proxies: dict[Guid, ReaderProxy] = {}
        self._lost: OrderedDict[Guid, ReaderProxy] = OrderedDict()  # see remove_reader
        self.heartbeat_count = 0
        self.counters = WriterCounters()

    # --- matching ---------------------------------------------------------------------------

    def add_reader(self, reader: Guid, now: float, *, resume: bool = False) -> list[Outgoing]:
        """Match a remote reader; a second call for the same reader keeps its state.

        ``resume``: the reader was lost (``remove_reader``) and is back in the same life,
        so it takes up its old place: samples it acknowledged stay irrelevant to it, those
        written since (and still held) are pushed now, at most ``MAX_EAGER_RESEND`` of
        them, the rest on its ACKNACK. Otherwise a reader lost before starts afresh."""
        if reader in self.proxies:
            return []
        lost = self._lost.pop(reader, None)
        if resume and lost is not None:
            # Everything it acknowledged it holds (the same reader, the same life): making
            # it irrelevant means a reader that reset its own proxy gets a GAP, not a copy.
            lost.relevant_from = max(lost.relevant_from, lost.acked + 1)
            lost.heartbeats_unanswered = 0
            lost.period_s = self.period_s
            self.proxies[reader] = lost
            self.counters.resumed += 1
            if not self._unacked(lost):
                return []
            out = self._push_unacked(lost)
            self.counters.handed_over += sum(isinstance(o.submessage, Data) for o in out)
            out.append(self._heartbeat(lost))
            lost.next_heartbeat = now + lost.period_s
            return out
        relevant_from = self.first_ever if self.transient_local else self.last_sn + 1
        proxy = ReaderProxy(reader, relevant_from=relevant_from, acked=relevant_from - 1)
        self.proxies[reader] = proxy
        if self._unacked(proxy):  # transient-local history to hand over: announce it now
            proxy.next_heartbeat = now
            return self._heartbeat_due(proxy, now)
        return []

    def remove_reader(self, reader: Guid) -> None:
        """Unmatch a reader; its proxy is kept for a resume (``add_reader``) or a
        ``forget_reader``, whichever the owner decides when the reader is seen again."""
        proxy = self.proxies.pop(reader, None)
        if proxy is None:
            return
        self._lost[reader] = proxy
        self._lost.move_to_end(reader)
        while len(self._lost) > MAX_LOST_READERS:
            self._lost.popitem(last=False)
            self.counters.lost_evicted += 1

    def forget_reader(self, reader: Guid) -> list[int]:
        """Drop a lost reader's kept place (it came back in another life, so it starts
        afresh): the SNs still held that were addressed to it and that it never
        acknowledged, oldest first. They will not reach it."""
        lost = self._lost.pop(reader, None)
        if lost is None:
            return []
        return [
            sn
            for sn, stored in self.history.items()
            if sn > lost.acked
            and sn >= lost.relevant_from
            and payload_for(stored, reader) is not None
        ]

    def matched(self, reader: Guid) -> bool:
        return reader in self.proxies

    # --- writing ----------------------------------------------------------------------------

    def write(self, payload: SamplePayload, now: float) -> tuple[int, list[Outgoing]]:
        self.last_sn += 1
        sn = self.last_sn
        self.counters.written += 1
        self.history[sn] = payload
        while len(self.history) > self.depth:
            old, _ = self.history.popitem(last=False)
            self.counters.evicted_unacked += sum(
                1 for p in self.proxies.values() if p.relevant_from <= old and p.acked < old
            )
        out: list[Outgoing] = []
        for proxy in self.proxies.values():
            copy = payload_for(payload, proxy.guid)
            if copy is None:  # not addressed to this reader: tell it the SN is irrelevant
                out.append(self._gap(proxy, [sn]))
            else:
                out.append(self._data(proxy, sn, copy))
                self.counters.data_sent += 1
            out.append(self._heartbeat(proxy))
            proxy.period_s = self.period_s
            proxy.next_heartbeat = now + self.period_s
        return sn, out

    def withdraw(self, sn: int) -> bool:
        """Remove ``sn`` from the history: never sent again. A reader that still lacks it
        learns from the next heartbeat (``first`` moves past it) or a GAP on its ACKNACK
        that it is irrelevant (spec 8.4.9.2.8), exactly as for a keep-last eviction."""
        if self.history.pop(sn, None) is None:
            return False
        self.counters.withdrawn += 1
        return True

    @property
    def first_available(self) -> int:
        return next(iter(self.history)) if self.history else self.last_sn + 1

    # --- inputs -----------------------------------------------------------------------------

    def on_acknack(self, reader: Guid, acknack: AckNack, now: float) -> list[Outgoing]:
        """Acknowledge, then repair what the reader asks for (spec 8.4.9.2.8)."""
        proxy = self.proxies.get(reader)
        if proxy is None:
            return []
        self.counters.acknacks_received += 1
        if (
            acknack.count <= proxy.last_acknack_count
            and proxy.heartbeats_unanswered < STALE_ACKNACK_HEARTBEATS
        ):
            # a duplicate or a reordered older ACKNACK (spec 8.3.7.1 "count")
            self.counters.acknacks_stale += 1
            return []
        # Old counts that keep coming while heartbeats go unanswered mean the reader's
        # process restarted with the same bundle GUID and counts from 1 again: resync.
        proxy.last_acknack_count = acknack.count
        proxy.heartbeats_unanswered = 0
        state = acknack.reader_sn_state
        # a base beyond last_sn would acknowledge samples never written: clamp, don't trust
        proxy.acked = min(max(proxy.acked, state.base - 1), self.last_sn)
        # Any fresh ACKNACK proves the reader alive: back to the short period, so a lossy
        # link is repaired at full pace and only a silent reader is backed off.
        proxy.period_s = self.period_s
        proxy.next_heartbeat = now + self.period_s
        out: list[Outgoing] = []
        irrelevant: list[int] = []
        requested = list(state.members())  # at most MAX_SN_SET_BITS (the codec's bound)
        if not requested:
            return out  # a pure acknowledgement asks for nothing: no answer, no token spent
        if now > proxy.reply_at:
            refill = (now - proxy.reply_at) * ACKNACK_REPLY_RATE
            proxy.reply_tokens = min(ACKNACK_REPLY_BURST, proxy.reply_tokens + refill)
            proxy.reply_at = now
        if proxy.reply_tokens < 1.0:
            # Past the reader's answer rate: acknowledged above, answered at the next
            # HEARTBEAT's ACKNACK (due by now + period_s).
            self.counters.acknacks_unanswered += 1
            return out
        proxy.reply_tokens -= 1.0
        for sn in requested:
            # resend even below ``acked``: a reader that restarted lost what it had acked
            if sn > self.last_sn:
                continue
            stored = self.history.get(sn)
            payload = None if stored is None else payload_for(stored, proxy.guid)
            if payload is None or sn < proxy.relevant_from:
                irrelevant.append(sn)
            else:
                out.append(self._data(proxy, sn, payload))
                self.counters.data_resent += 1
        if irrelevant:
            out.append(self._gap(proxy, irrelevant))
        if out:
            out.append(self._heartbeat(proxy))
        return out

    def on_timer(self, now: float) -> list[Outgoing]:
        out: list[Outgoing] = []
        for proxy in self.proxies.values():
            if self._unacked(proxy) and proxy.next_heartbeat <= now:
                out += self._heartbeat_due(proxy, now)
        return out

    def deadline(self) -> float | None:
        pending = [p.next_heartbeat for p in self.proxies.values() if self._unacked(p)]
        return min(pending) if pending else None

    # --- helpers ----------------------------------------------------------------------------

    def _unacked(self, proxy: ReaderProxy) -> bool:
        return proxy.acked < self.last_sn

    def _heartbeat_due(self, proxy: ReaderProxy, now: float) -> list[Outgoing]:
        proxy.next_heartbeat = now + proxy.period_s
        proxy.period_s = min(proxy.period_s * HEARTBEAT_BACKOFF, self.max_period_s)
        out: list[Outgoing] = []
        if proxy.heartbeats_unanswered > 0:
            # The last heartbeat went unanswered: the DATA most likely never arrived either.
            # Resending the oldest unacked samples with this heartbeat repairs in one datagram
            # instead of a HEARTBEAT -> ACKNACK -> DATA round trip (three chances to lose).
            out = self._push_unacked(proxy)
            self.counters.data_resent += sum(isinstance(o.submessage, Data) for o in out)
        out.append(self._heartbeat(proxy))
        return out

    def _push_unacked(self, proxy: ReaderProxy) -> list[Outgoing]:
        """DATA for the oldest unacked samples relevant to ``proxy`` (at most
        ``MAX_EAGER_RESEND``), and a GAP for the ones among them that are not for it."""
        first = max(proxy.acked + 1, proxy.relevant_from)
        out: list[Outgoing] = []
        irrelevant: list[int] = []
        for sn, stored in self.history.items():
            if sn < first or len(out) >= MAX_EAGER_RESEND:
                continue
            copy = payload_for(stored, proxy.guid)
            if copy is None:
                irrelevant.append(sn)
            else:
                out.append(self._data(proxy, sn, copy))
        if irrelevant:  # its GAP was lost too: say again that these are not for it
            out.append(self._gap(proxy, irrelevant))
        return out

    def _data(self, proxy: ReaderProxy, sn: int, payload: bytes) -> Outgoing:
        r = proxy.guid
        return Outgoing(r.prefix, Data(r.entity_id, self.guid.entity_id, sn, None, payload))

    def _heartbeat(self, proxy: ReaderProxy) -> Outgoing:
        self.heartbeat_count += 1
        self.counters.heartbeats_sent += 1
        proxy.heartbeats_unanswered += 1
        first = max(self.first_available, proxy.relevant_from)
        hb = Heartbeat(
            proxy.guid.entity_id,
            self.guid.entity_id,
            first_sn=first,
            last_sn=self.last_sn,
            count=self.heartbeat_count,
        )
        return Outgoing(proxy.guid.prefix, hb)

    def _gap(self, proxy: ReaderProxy, irrelevant: list[int]) -> Outgoing:
        """One GAP: the contiguous run from the lowest irrelevant SN, then a bitmap."""
        irrelevant.sort()
        start = irrelevant[0]
        end = start
        while end + 1 in irrelevant:
            end += 1
        base = end + 1
        rest = [sn for sn in irrelevant if sn > end and sn - base < MAX_SN_SET_BITS]
        self.counters.gaps_sent += 1
        gap = Gap(
            proxy.guid.entity_id,
            self.guid.entity_id,
            gap_start=start,
            gap_list=SequenceNumberSet.of(base, rest),
        )
        return Outgoing(proxy.guid.prefix, gap)
