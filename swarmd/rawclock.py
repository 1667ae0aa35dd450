"""The daemon's event loop, on the clock the validity proof rests on (docs/dataplane.md,
"The clock it rests on").

Every ``now`` the cores see is ``loop.time()`` (``driver.py``), and a command's validity is
proved for clocks that each measure their own intervals within 100 ppm
(``swarmd.dataplane.validity.DRIFT_PPM``). asyncio's default ``loop.time()`` is
``time.monotonic()``, CLOCK_MONOTONIC, which NTP slews: chrony up to ``maxslewrate``
83,333 ppm by default, the kernel's ``adjtimex`` tick by +-10 %. CLOCK_MONOTONIC_RAW is the
crystal's count, never slewed nor stepped (clock_gettime(2)). So the daemon runs on a
selector loop whose ``time()`` reads it; asyncio schedules ``call_at``/``call_later``,
``sleep`` and timeouts on the loop's own ``time()``, so every deadline stays on one clock.

Linux stops CLOCK_MONOTONIC_RAW, like CLOCK_MONOTONIC, while the system is suspended; only
CLOCK_BOOTTIME counts the sleep (clock_gettime(2)). A member host put to sleep (a Jetson's
suspend) then read its elapsed time without the sleep, and a command that waited in its
socket buffer through the suspend ran as if no time had passed: a TAKEOFF a minute late,
after the commander had told the operator it could no longer run there (session 16
command review, ``tests/test_cmd_suspend.py``). So the loop's clock is the raw clock plus
the time the system has slept since boot, CLOCK_BOOTTIME minus CLOCK_MONOTONIC: both are
slewed alike, so their difference is only the sleep, as the kernel measured it.

Linux only, like the daemon (netlink, sd_notify, SO_BINDTODEVICE): CLOCK_MONOTONIC_RAW is
Linux's (since 2.6.28), CLOCK_BOOTTIME too (since 2.6.39).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


def raw_clock() -> float:
    """CLOCK_MONOTONIC_RAW plus the time the system has been suspended since boot (seconds):
    the crystal's count, never slewed nor stepped, that also counts a sleep."""
    # The order matters: a thread paused between two reads makes the sum stale by the pause
    # (BOOTTIME read first, MONOTONIC and RAW after it alike), never ahead of the next
    # call's. Stale by more than the pause, though, when NTP runs MONOTONIC faster than RAW
    # (the pause times the slew): an earlier call can then read later, so the loop's
    # ``time()`` never gives less than it gave (``RawClockEventLoop``; test_cmd_suspend.py).
    boot = time.clock_gettime(time.CLOCK_BOOTTIME)
    monotonic = time.clock_gettime(time.CLOCK_MONOTONIC)
    return time.clock_gettime(time.CLOCK_MONOTONIC_RAW) + (boot - monotonic)


class RawClockEventLoop(asyncio.SelectorEventLoop):
    """A selector event loop whose ``time()`` is ``raw_clock()``: CLOCK_MONOTONIC_RAW,
    suspends counted (seconds)."""

    _last: float = float("-inf")

    def time(self) -> float:
        # Never earlier than a time it already gave. The read order above only keeps the
        # sum from stepping back while MONOTONIC runs slower than RAW; NTP slews it either
        # way (chrony speeds it up while the system clock is behind, and corrects a slow
        # crystal for good), and then a pause between the BOOTTIME and MONOTONIC reads
        # makes the sum early by the pause times the slew: 0.3 ms for a 4 ms pause at
        # chrony's 8 % (tests/test_cmd_suspend.py, the slew either way). asyncio and the
        # cores read deadlines and elapsed times off this clock and assume it monotonic.
        now = raw_clock()
        if now > self._last:
            self._last = now
        return self._last


def run_on_raw_clock(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(main)`` on a ``RawClockEventLoop`` (the same runner: SIGINT handling,
    async generators and the default executor shut down at the end)."""
    with asyncio.Runner(loop_factory=RawClockEventLoop) as runner:
        return runner.run(main)
