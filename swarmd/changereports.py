"""Which of a peer's changes are logged: a per-key budget with a suppressed counter.

A captured member's genuine traffic can change what the log reports as fast as its
verification budget lets it (review 16: a readiness verdict per sample at the commander;
session 16, h-insider16: its locators and its ROS 2 liveness word, up to 4 log lines a
signed datagram). An honest peer changes these a few times a flight. ``ChangeReports``
reports every change of a key's value within ``rate`` a second (burst ``burst``) and counts
the rest (``suppressed``); a key whose latest change was held back is listed by ``held``,
so a caller with a tick can report it later and end the log on the current value. Pure
(style.md rule 6): one ``TokenBucket`` per key, refilled at the ``now`` it is asked at; the
caller bounds the keys (bundle peers only).

``LineBudget`` is the same budget for lines that are events rather than values (review 18:
the ROS 2 relay's per-change lines, a node's new life, a peer's node back): every one is
news, so none is skipped as "the same again"; the one logged after a pause says how many
of its key were held back since the last.
"""

from __future__ import annotations

from typing import Generic, TypeVar

from swarmd.tokenbucket import TokenBucket

K = TypeVar("K")
V = TypeVar("V")


class ChangeReports(Generic[K, V]):
    """Each key's changes reported within ``rate`` a second (burst ``burst``), the rest
    counted (``suppressed``)."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate = rate
        self.burst = burst
        self._budgets: dict[K, TokenBucket] = {}
        self._said: dict[K, V] = {}  # the last value reported, per key
        self._held: set[K] = set()  # keys whose latest change was not reported
        self.suppressed = 0

    def changed(self, key: K, value: V, now: float, *, retry: bool = False) -> bool:
        """``key``'s value changed to ``value``: report it now? ``retry``: a tick asking
        again for a held change (not counted twice)."""
        if key in self._said and self._said[key] == value:
            self._held.discard(key)  # back to what the log says already
            return False
        budget = self._budgets.get(key)
        if budget is None:
            budget = self._budgets[key] = TokenBucket(self.rate, self.burst, now)
        if not budget.take(now):
            self.suppressed += 0 if retry else 1
            self._held.add(key)
            return False
        self._said[key] = value
        self._held.discard(key)
        return True

    def held(self) -> list[K]:
        """Keys whose latest change was held back (report them again when the budget
        allows). Sorted by ``repr``: keys need not be orderable."""
        return sorted(self._held, key=repr)


class LineBudget(Generic[K]):
    """Each key's lines within ``rate`` a second (burst ``burst``); the rest held back and
    counted (``suppressed``, and per key until its next line)."""

    def __init__(self, rate: float, burst: float) -> None:
        self.rate = rate
        self.burst = burst
        self._budgets: dict[K, TokenBucket] = {}
        self._held: dict[K, int] = {}  # lines of the key held back since its last one
        self.suppressed = 0

    def take(self, key: K, now: float) -> int | None:
        """None: hold this line back (counted); else log it, with the number of ``key``'s
        lines held back since its last one."""
        budget = self._budgets.get(key)
        if budget is None:
            budget = self._budgets[key] = TokenBucket(self.rate, self.burst, now)
        if not budget.take(now):
            self._held[key] = self._held.get(key, 0) + 1
            self.suppressed += 1
            return None
        return self._held.pop(key, 0)
