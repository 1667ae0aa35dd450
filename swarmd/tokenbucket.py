"""The token bucket every budget of swarmd is made of (a leaf: it imports nothing of swarmd).

``rate`` tokens a second accrue up to ``burst``; a bucket is a pure function of the ``now``
it is asked at (style.md rule 6: it schedules nothing, it refills when asked). The
signature-check budgets (``swarmd.auth.budget``), the foreign-participant and
unknown-outcome report budgets, the XRCE key-check budget (``swarmd.xrce.keycheck``) and the
sender-uid lookup's budget of seconds of work (``swarmd.senderuid``) are all this one class.
"""

from __future__ import annotations


class TokenBucket:
    """``rate`` tokens a second, at most ``burst`` saved; ``take(now)`` spends one.

    ``has_token``/``spend`` split ``take`` for a caller that must find a token in two
    buckets before it spends either (``swarmd.xrce.keycheck``); ``is_full`` tells a bucket
    that is the same as a fresh one (forgetting it loses nothing)."""

    __slots__ = ("_at", "_tokens", "burst", "rate")

    def __init__(self, rate: float, burst: float, now: float) -> None:
        self.rate = rate
        self.burst = burst
        self._tokens = burst
        self._at = now

    def take(self, now: float) -> bool:
        # the refill inlined: this runs for every SPDP datagram that reaches a signature check
        if now > self._at:
            self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
            self._at = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False

    def has_token(self, now: float) -> bool:
        self._refill(now)
        return self._tokens >= 1.0

    def is_full(self, now: float) -> bool:
        self._refill(now)
        return self._tokens >= self.burst

    def spend(self, amount: float = 1.0) -> None:
        """Spend the token ``has_token`` just found, or ``amount`` of what ``balance`` gave:
        a bucket of seconds of work spent by each call's measured cost
        (``swarmd.senderuid``) may go below zero, a debt the refill pays first."""
        self._tokens -= amount

    def balance(self, now: float) -> float:
        """What is saved at ``now`` (below zero while a debt is being paid)."""
        self._refill(now)
        return self._tokens

    def _refill(self, now: float) -> None:
        if now > self._at:
            self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate)
            self._at = now
