"""The one asyncio driver: runs any sans-IO core of swarmd on the event loop.

Every core (``DiscoveryEngine``, ``DataPlane``, ``SwarmCore``, ``VehicleCore``) speaks the
same driving protocol (``SansIOCore``, after aioquic's ``QuicConnection``, style.md rules
2 and 11): inputs ``receive_datagram(data, source, now)`` and ``handle_timer(now)``, outputs
``datagrams_to_send()``, ``get_timer()`` and ``next_event()``. ``Driver`` is the only code
that turns that into I/O:

- an input (a datagram from a transport, or any call into the core through ``call``) runs
  with ``now = loop.time()``, then the driver drains: send every output through
  ``transmit``, hand every event to ``on_event``, send again (a handler may have given the
  core more to do), and re-arm the core's one ``TimerHandle`` at ``get_timer()`` when, and
  only when, the deadline changed;
- the timer fires ``handle_timer(max(deadline, loop.time()))``: asyncio may wake a timer a
  little early (its clock resolution), and a core handed a ``now`` before its own deadline
  would do nothing and ask for the same deadline again (aioquic's adapter guards alike);
- a handler that calls back into the core while the driver drains does not recurse: the
  running drain goes round once more;
- a core raising is a bug, not bad input (the cores promise not to raise on anything a
  peer sends): the driver counts it, logs it and keeps the loop alive.

The driver knows no transport: ``transmit`` is the caller's (``transport.sendto`` for UDP,
``backend.send`` for a flight controller). Used by ``swarmd.daemon`` (discovery, the swarm
core) and ``swarmd.px4.bridge`` (the vehicle core); tests drive the same cores without it,
on hand-set time and on ``swarmd_lab.memnet.MemNet`` (virtual time, one network for all).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

from swarmd.sansio import SansIOCore

__all__ = ["Driver", "SansIOCore"]

InT = TypeVar("InT")
OutT = TypeVar("OutT")
EvT = TypeVar("EvT")
R = TypeVar("R")


class Driver(Generic[InT, OutT, EvT]):
    """Drives one ``SansIOCore`` on the running loop (see the module docstring)."""

    def __init__(
        self,
        core: SansIOCore[InT, OutT, EvT],
        *,
        transmit: Callable[[OutT], None],
        on_event: Callable[[EvT], None],
        name: str,
        log: Any = None,
        loop: asyncio.AbstractEventLoop | None = None,
        on_core_error: Callable[[], None] | None = None,
    ) -> None:
        """``on_core_error`` is called (after the driver's own count and log line) when the
        core raises: the owner's counter for a bug that must not stop the loop."""
        self.core = core
        self.transmit = transmit
        self.on_event = on_event
        self.name = name
        self.log = log
        self.on_core_error = on_core_error
        self.loop = loop or asyncio.get_running_loop()
        self.counters: dict[str, int] = {"core_errors": 0, "handler_errors": 0}
        self._timer: asyncio.TimerHandle | None = None
        self._deadline: float | None = None
        self._draining = False
        self._again = False
        self.closed = False

    def now(self) -> float:
        return self.loop.time()

    # ---- inputs -------------------------------------------------------------------------

    def datagram_received(
        self, data: InT, source: Any, receive: Callable[[InT, Any, float], None] | None = None
    ) -> None:
        """One datagram (or observation) for the core, at ``loop.time()``; ``receive`` as
        in ``datagrams_received``."""
        if self.closed:
            return
        try:
            (receive or self.core.receive_datagram)(data, source, self.loop.time())
        except Exception:  # the core promises not to raise on input: a bug, keep running
            self._count_error("core_errors", "core_receive_failed")
        self.drain()

    def datagrams_received(
        self,
        batch: Iterable[tuple[InT, Any]],
        receive: Callable[[InT, Any, float], None] | None = None,
    ) -> None:
        """Several datagrams read at one wake-up, each with its source, then one drain.

        The same ``now`` for all (they were read at the same instant): what the core sends
        or reports in answer goes out once per batch, not once per datagram, so a flood's
        cost is the core's refusal and not the driver's bookkeeping (docs/security.md,
        "Flood"). ``receive``: the adapter's way into the core instead of its
        ``receive_datagram`` (one that attaches what the adapter knows of the sender, such
        as its local user: swarmd.senderuid)."""
        if self.closed:
            return
        now = self.loop.time()
        receive = receive or self.core.receive_datagram
        for data, source in batch:
            try:
                receive(data, source, now)
            except Exception:  # the core promises not to raise on input: a bug, keep running
                self._count_error("core_errors", "core_receive_failed")
        self.drain()

    def call(self, action: Callable[[float], R]) -> R | None:
        """Run ``action(now)`` on the core (a request, a peer going up), then drain; its
        result. A closed driver is inert: the action does not run and the answer is None
        (shutdown races, such as a vehicle task cancelled while its owner stops, land here;
        a core that is no longer driven must not change, nor queue what nobody sends)."""
        if self.closed:
            return None
        try:
            return action(self.loop.time())
        finally:
            self.drain()

    # ---- outputs ------------------------------------------------------------------------

    def drain(self) -> None:
        """Send, dispatch events, send again; re-arm the timer. Re-entrant calls loop."""
        if self._draining:
            self._again = True
            return
        self._draining = True
        try:
            while True:
                self._again = False
                self._send()
                while (event := self.core.next_event()) is not None:
                    try:
                        self.on_event(event)
                    except Exception:  # a handler bug must not stop the core
                        self._count_error("handler_errors", "event_handler_failed")
                self._send()
                if not self._again:
                    break
        finally:
            self._draining = False
        self._arm()

    def close(self) -> None:
        """Stop the timer and drop further input and calls; outputs still queued are not
        sent."""
        self.closed = True
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._deadline = None

    @property
    def deadline(self) -> float | None:
        """The armed timer's deadline (for health checks: a timer far overdue = a starved
        loop)."""
        return self._deadline

    # ---- internals ----------------------------------------------------------------------

    def _send(self) -> None:
        for out in self.core.datagrams_to_send():
            if self.closed:
                continue
            self.transmit(out)

    def _arm(self) -> None:
        deadline = None if self.closed else self.core.get_timer()
        if deadline == self._deadline:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if deadline is not None:
            self._timer = self.loop.call_at(deadline, self._fire)
        self._deadline = deadline

    def _fire(self) -> None:
        deadline, self._timer, self._deadline = self._deadline, None, None
        if self.closed or deadline is None:
            return
        # the early-wake guard: never hand the core a time before the deadline it asked for
        now = max(deadline, self.loop.time())
        try:
            self.core.handle_timer(now)
        except Exception:
            self._count_error("core_errors", "core_timer_failed")
        self.drain()

    def _count_error(self, counter: str, event: str) -> None:
        self.counters[counter] += 1
        if self.log is not None:
            self.log.exception(event, core=self.name)
        if counter == "core_errors" and self.on_core_error is not None:
            self.on_core_error()
