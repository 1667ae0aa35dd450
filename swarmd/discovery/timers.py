"""Small pure timing helpers keyed by ``now``; each reports its next deadline, none
schedules anything (the engine folds their deadlines into its one ``get_timer()``).
"""

from __future__ import annotations

import heapq
import random
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol


@dataclass(frozen=True, slots=True)
class Backoff:
    """``base * 2^k`` capped at ``cap``, stretched by U(1, 1 + jitter) so that peers which
    lost the same frame do not retry in lock step (zeroconf's probe jitter, RFC 6762 8.1)."""

    base_s: float
    cap_s: float
    jitter: float = 0.25

    def delay_s(self, attempt: int, rng: random.Random) -> float:
        plain = min(self.cap_s, self.base_s * (2.0 ** max(0, attempt - 1)))
        # rng.uniform(1, 1 + jitter) as random.py defines it, a + (b - a) * random(): the
        # same draw without uniform's Python frame (~10^6 retries per 1000-drone run)
        high = 1.0 + self.jitter
        return plain * (1.0 + (high - 1.0) * rng.random())

    def plain_s(self, attempt: int) -> float:
        """``base * 2^(attempt - 1)`` capped at ``cap``, without the jitter (no draw): a
        spacing whose cue is already jittered (the lost_us rule answers a peer's own
        frames, ``seek.SoughtBy``). ``delay_s`` computes the same inline (hot path)."""
        return min(self.cap_s, self.base_s * (2.0 ** max(0, attempt - 1)))


@dataclass(slots=True)
class RetrySchedule:
    """When a frame is next owed to one peer, and how many were sent for the current need.

    ``arm`` keeps the earliest deadline; ``sent`` counts an attempt and clears the deadline
    (the engine re-arms it with ``Backoff`` while the need persists); ``reset`` forgets the
    attempts once the need is met, so the next need starts fresh.
    """

    max_attempts: int
    due: float | None = None
    attempts: int = 0

    def arm(self, at: float) -> bool:
        """Keep the earlier of ``at`` and the current deadline; True if the deadline moved."""
        due = self.due
        if self.attempts < self.max_attempts and (due is None or at < due):
            self.due = at
            return True
        return False

    def sent(self) -> None:
        self.attempts += 1
        self.due = None

    def reset(self) -> None:
        self.due = None
        self.attempts = 0

    def leave_one_attempt(self) -> None:
        """Allow exactly one more attempt for the current need, however many were spent
        (none or all): one answer, not a new series of retries (the lost_us rule,
        ``receive.py``; ``reset`` still starts the next need fresh)."""
        self.attempts = self.max_attempts - 1

    @property
    def exhausted(self) -> bool:
        return self.attempts >= self.max_attempts

    def deadline(self) -> float | None:
        return self.due


@dataclass(slots=True)
class MinInterval:
    """Allows one action per ``interval_s``: the rate limit on answering repeats."""

    interval_s: float
    last: float | None = None

    def permits(self, now: float) -> bool:
        return self.last is None or now - self.last >= self.interval_s

    def mark(self, now: float) -> None:
        self.last = now

    def next_allowed(self) -> float | None:
        return None if self.last is None else self.last + self.interval_s


class WindowRate:
    """How often something happened: a total, and events per second over the last
    ``window_s`` (issue 20: "the renewal/vouch rate following the link quality").

    Pure, keyed by ``now``: ``mark`` keeps the times inside the window (at most ``cap``,
    oldest dropped, so a peer flooding what we count cannot grow memory: the rate then
    reads at most ``cap / window_s``); ``per_s`` changes nothing, so ``status()`` stays a
    pure function of the state. Before a whole window has passed since ``start`` the rate
    is over the time elapsed, not the whole window."""

    __slots__ = ("_start", "_times", "total", "window_s")

    def __init__(self, window_s: float, cap: int, start: float) -> None:
        self.window_s = window_s
        self.total = 0
        self._start = start
        self._times: deque[float] = deque(maxlen=cap)

    def mark(self, now: float) -> None:
        self.total += 1
        times = self._times
        times.append(now)
        since = now - self.window_s
        while times[0] <= since:
            times.popleft()

    def per_s(self, now: float) -> float:
        """Events per second in (now - window_s, now]."""
        span = min(self.window_s, now - self._start)
        if span <= 0.0:
            return 0.0
        since = now - span
        return sum(1 for t in self._times if since < t <= now) / span


@dataclass(slots=True)
class Periodic:
    """A jittered period (lease renewals): next = last + period * U(1 - jitter, 1)."""

    period_s: float
    jitter: float
    due: float | None = None

    def restart(self, now: float, rng: random.Random) -> None:
        self.due = now + self.period_s * rng.uniform(1.0 - self.jitter, 1.0)

    def reschedule(self, period_s: float, last: float, rng: random.Random) -> None:
        """Take a new period (Q changed), counting from the ``last`` renewal."""
        self.period_s = period_s
        self.restart(last, rng)

    def stop(self) -> None:
        self.due = None

    def deadline(self) -> float | None:
        return self.due


class Leased(Protocol):
    """What ``LeaseQueue`` keeps on each leased object (the engine's ``Peer``): its deadline
    lives on the object the receive path touches anyway, not in a table of its own."""

    index: int  # distinct per object: orders equal deadlines, never compared further
    lease_until: float | None  # the running lease's deadline, None if none runs
    lease_queued: float | None  # the deadline of its live heap entry (<= lease_until)


@dataclass(slots=True)
class LeaseQueue:
    """Lease deadlines of the discovered peers, earliest first, at O(1) per renewal.

    A renewal only writes the peer's new deadline (``now + lease``) on the peer
    (``Leased.lease_until``). A heap holds one live entry per peer, (deadline when queued,
    index, peer), which may be earlier than the peer's real deadline; ``earliest`` brings
    the head up to date, re-queueing a head whose peer was renewed since at its real
    deadline. So a peer costs one O(log N) heap step per lease it lives through, not one
    per DATA(p): while a 1000-drone swarm announces, a peer is heard many times per lease,
    and the receive path (~3M renewals per simulated minute) is bound by memory, so a
    renewal touches nothing but the peer. A renewal that brings a deadline forward (a
    shorter advertised lease) queues a new entry at once; entries that no longer match
    ``lease_queued`` are dropped when they reach the head.
    Requires a non-decreasing ``now``, as everything keyed by ``now``.
    """

    # (deadline, index, peer). Equal (deadline, index) means the same peer (the index is
    # distinct per object): a removed peer renewed at the same deadline has two entries,
    # which heapq then finds equal by identity and never orders by the peer. No tie-break
    # counter: it was one more int object per entry, read on every re-queue (~770,000 of
    # them in a simulated 1000-drone minute; docs/discovery.md, "Cost per datagram").
    _heap: list[tuple[float, int, Leased]] = field(default_factory=list)
    # earliest()'s answer, kept until it may have changed
    _cached: tuple[float, int] | None = None
    _stale: bool = False

    def renew(self, peer: Leased, lease_s: float, now: float) -> None:
        """``peer`` was heard at ``now``; its lease (``lease_s`` long) restarts."""
        until = peer.lease_until = now + lease_s
        queued = peer.lease_queued
        if queued is None or until < queued:
            peer.lease_queued = until
            heapq.heappush(self._heap, (until, peer.index, peer))
            self._stale = True
        elif (cached := self._cached) is not None and cached[1] == peer.index:
            self._stale = True  # the earliest lease moved later: another may be first now

    def remove(self, peer: Leased) -> None:
        """``peer``'s lease stops (its heap entry is dropped when it reaches the head)."""
        if peer.lease_until is None:
            return
        peer.lease_until = peer.lease_queued = None
        if (cached := self._cached) is not None and cached[1] == peer.index:
            self._stale = True

    def earliest(self) -> tuple[float, int] | None:
        """(deadline, index) of the lease that ends first, None when no lease runs."""
        if not self._stale:
            return self._cached
        self._stale = False
        heap = self._heap
        while heap:
            at, index, peer = heap[0]
            if peer.lease_queued != at:
                heapq.heappop(heap)  # removed, or superseded by an earlier deadline
                continue
            real = peer.lease_until
            if real == at:
                self._cached = (at, index)
                return self._cached
            assert real is not None  # noqa: S101 - lease_queued set implies lease_until set
            # renewed since it was queued: every other live entry is at or before its own
            # peer's deadline, so re-queueing this one keeps the head the true minimum
            heapq.heapreplace(heap, (real, index, peer))
            peer.lease_queued = real
        self._cached = None
        return None
