"""Small pure timing helpers keyed by ``now``; each reports its next deadline, none
schedules anything (the engine folds their deadlines into its one ``get_timer()``).
"""

from __future__ import annotations

import random
from dataclasses import dataclass


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
