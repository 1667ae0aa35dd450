"""Small pure timing helpers keyed by ``now``; each reports its next deadline, none
schedules anything (the engine folds their deadlines into its one ``get_timer()``).
"""

from __future__ import annotations

import heapq
import random
from collections import OrderedDict
from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Backoff:
    """``base * 2^k`` capped at ``cap``, stretched by U(1, 1 + jitter) so that peers which
    lost the same frame do not retry in lock step (zeroconf's probe jitter, RFC 6762 8.1)."""

    base_s: float
    cap_s: float
    jitter: float = 0.25

    def delay_s(self, attempt: int, rng: random.Random) -> float:
        plain = min(self.cap_s, self.base_s * (2.0 ** max(0, attempt - 1)))
        return plain * rng.uniform(1.0, 1.0 + self.jitter)


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


@dataclass(slots=True)
class LeaseQueue:
    """Lease deadlines of the discovered peers, earliest first, at O(1) per renewal.

    A renewal pushes a peer's deadline to ``now + lease``. Peers that advertise the same
    lease length therefore expire in the order they were last heard, so each length keeps
    an insertion-ordered table and a renewal moves the peer to its end. A small lazy heap
    holds each table's head deadline. (A heap of all peers would cost a log N operation on
    nearly every DATA(p): the next peer to renew is usually the one whose lease ends first.)
    Requires a non-decreasing ``now``, as everything keyed by ``now``.
    """

    _tables: dict[float, OrderedDict[int, float]] = field(default_factory=dict)
    _length_of: dict[int, float] = field(default_factory=dict)
    # (head deadline, length) of each table; stale entries are dropped by ``earliest``
    _heads: list[tuple[float, float]] = field(default_factory=list)
    # earliest()'s answer, kept until a table head changes (while a swarm is discovered,
    # new peers join the tails and the answer stands)
    _cached: tuple[float, int] | None = None
    _stale: bool = True

    def renew(self, index: int, lease_s: float, now: float) -> None:
        """Peer ``index`` was heard at ``now``; its lease (``lease_s`` long) restarts."""
        table = self._tables.get(lease_s)
        old = self._length_of.get(index)
        if table is not None and old == lease_s:
            # the usual case, a renewal at an unchanged lease length: move to the tail
            head = next(iter(table))
            table[index] = now + lease_s
            table.move_to_end(index)
            if head == index:
                self._head_changed(table, lease_s)
            return
        if old is not None:
            self.remove(index)  # it advertises another lease length now (old != lease_s)
        if table is None:
            table = self._tables[lease_s] = OrderedDict()
        table[index] = now + lease_s
        self._length_of[index] = lease_s
        if len(table) == 1:
            self._head_changed(table, lease_s)

    def deadline(self, index: int) -> float | None:
        """When peer ``index``'s lease ends, None if it has none running."""
        length = self._length_of.get(index)
        return None if length is None else self._tables[length][index]

    def remove(self, index: int) -> None:
        length = self._length_of.pop(index, None)
        if length is None:
            return
        table = self._tables[length]
        was_head = next(iter(table)) == index
        del table[index]
        if not table:
            del self._tables[length]
            self._stale = True
        elif was_head:
            self._head_changed(table, length)

    def earliest(self) -> tuple[float, int] | None:
        """(deadline, index) of the lease that ends first, None when no lease runs."""
        if not self._stale:
            return self._cached
        self._stale = False
        heads = self._heads
        while heads:
            deadline, length = heads[0]
            table = self._tables.get(length)
            if table is not None:
                index = next(iter(table))
                if table[index] == deadline:
                    self._cached = (deadline, index)
                    return self._cached
            heapq.heappop(heads)
        self._cached = None
        return None

    def _head_changed(self, table: OrderedDict[int, float], length: float) -> None:
        heapq.heappush(self._heads, (table[next(iter(table))], length))
        self._stale = True
