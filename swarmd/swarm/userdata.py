"""The data plane's asyncio adapter: one UDP socket, one timer, aioquic's shape (rule 11).

Every input — a datagram on the user unicast port (``Bundle.user_port``), the timer, or a
call from the owner (``peer_up``/``peer_down`` from discovery, ``publish_readiness``,
``send_command``, ``report_outcome``) — goes to the sans-IO ``DataPlane`` with
``loop.time()`` as ``now`` and is followed by the same steps: drain events to the owner's
handler, send what the plane queued, re-arm the single ``TimerHandle`` at
``plane.get_timer()``.

A handler may call back in (a member answering a command queues an outcome while its
``CommandReceived`` is being handled); such nested calls do not recurse, they ask the
running drain to go round once more, so events keep their order and every queued datagram
leaves before the timer is re-armed.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from typing import Any, Final

from swarmd.dataplane import DataPlane, DataPlaneEvent
from swarmd.dataplane.types import Command, CommandResult, Readiness

RECV_BUFFER_BYTES: Final = 1 << 20  # a commander hears N members at 1 Hz plus repairs

EventHandler = Callable[[DataPlaneEvent], None]


def open_user_socket(port: int) -> socket.socket:
    """The user unicast socket on every address (a re-addressed interface keeps working)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        s.bind(("", port))
        s.setblocking(False)
    except BaseException:
        s.close()
        raise
    return s


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, adapter: UserDataAdapter) -> None:
        self.adapter = adapter

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.adapter.datagram_received(data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable: a peer's daemon is gone; its lease will tell discovery
        self.adapter.counters["socket_errors"] += 1


class UserDataAdapter:
    """Drives one ``DataPlane`` on one UDP socket in the running loop."""

    def __init__(self, plane: DataPlane, on_event: EventHandler, *, log: Any) -> None:
        self.plane = plane
        self.on_event = on_event
        self.log = log
        self.counters: dict[str, int] = {"socket_errors": 0, "handler_errors": 0, "tx_closed": 0}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_deadline: float | None = None
        self._draining = False
        self._again = False
        self._closed = False

    async def open(self, port: int) -> None:
        """Bind the user unicast port; ``OSError`` when it is taken."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        sock = open_user_socket(port)
        transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self), sock=sock)
        self._transport = transport

    def close(self) -> None:
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    @property
    def now(self) -> float:
        return self._loop.time() if self._loop is not None else 0.0

    # ---- inputs ---------------------------------------------------------------------------

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self._closed:
            return
        self.plane.receive_datagram(data, addr, self.now)
        self._after_input()

    def peer_up(self, name: str, locator: tuple[str, int], epoch: int) -> None:
        self.plane.peer_up(name, locator, self.now, epoch=epoch)
        self._after_input()

    def peer_down(self, name: str) -> None:
        self.plane.peer_down(name, self.now)
        self._after_input()

    def publish_readiness(self, sample: Readiness) -> int:
        sn = self.plane.publish_readiness(sample, self.now)
        self._after_input()
        return sn

    def send_command(self, command: Command) -> int:
        sn = self.plane.send_command(command, self.now)
        self._after_input()
        return sn

    def report_outcome(self, command_id: int, result: CommandResult, reason: str) -> int:
        sn = self.plane.report_outcome(command_id, result, self.now, reason)
        self._after_input()
        return sn

    def _on_timer(self) -> None:
        self._timer = None
        self._timer_deadline = None
        if self._closed:
            return
        self.plane.handle_timer(self.now)
        self._after_input()

    # ---- outputs --------------------------------------------------------------------------

    def _after_input(self) -> None:
        if self._draining:
            self._again = True  # a handler called back in: the running drain goes round again
            return
        self._draining = True
        try:
            while True:
                self._again = False
                self._transmit()
                while (event := self.plane.next_event()) is not None:
                    try:
                        self.on_event(event)
                    except Exception:  # a handler bug must not stop the data plane
                        self.counters["handler_errors"] += 1
                        self.log.exception("dataplane_handler_failed", event=type(event).__name__)
                self._transmit()
                if not self._again:
                    break
        finally:
            self._draining = False
        self._arm_timer()

    def _transmit(self) -> None:
        for payload, dest in self.plane.datagrams_to_send():
            if self._transport is None:
                self.counters["tx_closed"] += 1
                continue
            self._transport.sendto(payload, dest)

    def _arm_timer(self) -> None:
        deadline = self.plane.get_timer()
        if deadline == self._timer_deadline or self._loop is None:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if deadline is not None and not self._closed:
            self._timer = self._loop.call_at(deadline, self._on_timer)
        self._timer_deadline = deadline

    def status(self) -> dict[str, Any]:
        out = self.plane.status(self.now)
        out["adapter"] = dict(self.counters)
        return out
