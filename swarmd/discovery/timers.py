"""Small pure timing helpers keyed by ``now``; each reports its next deadline, none
schedules anything (the engine folds their deadlines into its one ``get_timer()``).
"""

from __future__ import annotations

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

    def arm(self, at: float) -> None:
        if not self.exhausted and (self.due is None or at < self.due):
            self.due = at

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
    an insertion-ordered table and a renewal moves the peer to its end; the earliest
    deadline is the smallest head over the (few) lengths in use. A heap would cost a log N
    operation on every DATA(p), since the next peer to renew is nearly always the one whose
    lease ends first. Requires a non-decreasing ``now``, as everything keyed by ``now``.
    """

    _by_length: dict[float, OrderedDict[int, float]] = field(default_factory=dict)
    _length_of: dict[int, float] = field(default_factory=dict)

    def renew(self, index: int, lease_s: float, now: float) -> None:
        """Peer ``index`` was heard at ``now``; its lease (``lease_s`` long) restarts."""
        old = self._length_of.get(index)
        if old is not None and old != lease_s:
            self._drop(index, old)
        self._length_of[index] = lease_s
        table = self._by_length.get(lease_s)
        if table is None:
            table = self._by_length[lease_s] = OrderedDict()
        table[index] = now + lease_s
        table.move_to_end(index)

    def remove(self, index: int) -> None:
        old = self._length_of.pop(index, None)
        if old is not None:
            self._drop(index, old)

    def earliest(self) -> tuple[float, int] | None:
        """(deadline, index) of the lease that ends first, None when no lease runs."""
        best: tuple[float, int] | None = None
        for table in self._by_length.values():
            index, deadline = next(iter(table.items()))
            if best is None or (deadline, index) < best:
                best = (deadline, index)
        return best

    def _drop(self, index: int, length: float) -> None:
        table = self._by_length[length]
        del table[index]
        if not table:
            del self._by_length[length]
