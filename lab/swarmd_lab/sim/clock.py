"""The virtual clock: a heap of deadlines that time jumps between. No event loop, no sleeping.

Ties are broken by insertion order (a monotonically increasing sequence number), so a run
is a pure function of its inputs: the same seed replays the same events in the same order.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable

Callback = Callable[[], None]


class Timer:
    """A scheduled callback; ``cancel()`` makes the clock skip it (lazy deletion)."""

    __slots__ = ("at", "callback", "cancelled")

    def __init__(self, at: float, callback: Callback) -> None:
        self.at = at
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class VirtualClock:
    """``now`` only moves when ``run_next`` pops the earliest pending timer."""

    def __init__(self) -> None:
        self.now = 0.0
        self._heap: list[tuple[float, int, Timer]] = []
        self._seq = 0

    def call_at(self, at: float, callback: Callback) -> Timer:
        """Run ``callback`` at virtual time ``at`` (never earlier than ``now``)."""
        timer = Timer(max(at, self.now), callback)
        self._seq += 1
        heapq.heappush(self._heap, (timer.at, self._seq, timer))
        return timer

    def next_time(self) -> float | None:
        """When the earliest live timer fires, or None if nothing is pending."""
        heap = self._heap
        while heap and heap[0][2].cancelled:
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    def run_next(self) -> None:
        """Advance ``now`` to the earliest live timer and run it."""
        if self.next_time() is None:
            return
        at, _, timer = heapq.heappop(self._heap)
        self.now = at
        timer.callback()
