"""The daemon's event loop, on the clock the validity proof rests on (docs/dataplane.md,
"The clock").

Every ``now`` the cores see is ``loop.time()`` (``driver.py``), and a command's validity is
proved for clocks that each measure their own intervals within 100 ppm
(``swarmd.dataplane.validity.DRIFT_PPM``). asyncio's default ``loop.time()`` is
``time.monotonic()``, CLOCK_MONOTONIC, which NTP slews: chrony up to ``maxslewrate``
83,333 ppm by default, the kernel's ``adjtimex`` tick by +-10 %. CLOCK_MONOTONIC_RAW is the
crystal's count, never slewed nor stepped (clock_gettime(2)). So the daemon runs on a
selector loop whose ``time()`` reads it; asyncio schedules ``call_at``/``call_later``,
``sleep`` and timeouts on the loop's own ``time()``, so every deadline stays on one clock.

Linux only, like the daemon (netlink, sd_notify, SO_BINDTODEVICE): CLOCK_MONOTONIC_RAW is
Linux's (since 2.6.28).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


class RawClockEventLoop(asyncio.SelectorEventLoop):
    """A selector event loop whose ``time()`` is CLOCK_MONOTONIC_RAW (seconds)."""

    def time(self) -> float:
        return time.clock_gettime(time.CLOCK_MONOTONIC_RAW)


def run_on_raw_clock(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(main)`` on a ``RawClockEventLoop`` (the same runner: SIGINT handling,
    async generators and the default executor shut down at the end)."""
    with asyncio.Runner(loop_factory=RawClockEventLoop) as runner:
        return runner.run(main)
