"""The user-data UDP socket: the data plane's transport, nothing else.

Datagrams on the user unicast port (``Bundle.user_port``) go to a sink (the swarm's
``Driver.datagrams_received``, which feeds the ``SwarmCore`` and through it the
``DataPlane`` at ``loop.time()``); ``send`` is the driver's ``transmit``. The socket is read
like the SPDP sockets (``swarmd/udp.py``): up to ``READ_BATCH`` datagrams per wake-up, one
driver drain per batch, so a flood of forged user data (each refused by its MAC) costs the
refusal and not one event-loop turn per datagram (docs/security.md, "Flood"). Timers,
draining and re-entrancy are the driver's (``swarmd/driver.py``).
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

from swarmd.udp import RECV_BUFFER_BYTES, BatchedSocket, Datagram

BatchSink = Callable[[list[Datagram]], None]


def open_user_socket(port: int) -> socket.socket:
    """The user unicast socket on every address (a re-addressed interface keeps working).

    Its receive buffer is the SPDP sockets' (4 MiB): a commander hears N members at 1 Hz
    plus repairs, and under a flood what the kernel drops for want of buffer are real
    readiness reports and commands among the forgeries."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        s.bind(("", port))
        s.setblocking(False)
    except BaseException:
        s.close()
        raise
    return s


class UserDataSocket:
    """One bound UDP socket: batches of datagrams in to ``sink``, out through ``send``."""

    def __init__(
        self, sock: socket.socket, sink: BatchSink, loop: asyncio.AbstractEventLoop
    ) -> None:
        self.sink = sink
        # socket_error_user (ICMP errors: a peer's daemon gone, its lease will tell
        # discovery), tx_dropped_full_user (send buffer full: the reliable topics repair)
        self.counters: dict[str, int] = {}
        self.reader = BatchedSocket(sock, "user", self._batch, self._count, loop)

    @classmethod
    async def open(cls, port: int, sink: BatchSink) -> UserDataSocket:
        """Bind the user unicast port; ``OSError`` when it is taken."""
        return cls(open_user_socket(port), sink, asyncio.get_running_loop())

    def _batch(self, batch: list[Datagram], _name: str) -> None:
        self.sink(batch)

    def _count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    def send(self, data: bytes, addr: tuple[str, int]) -> None:
        self.reader.sendto(data, addr)

    def close(self) -> None:
        self.reader.close()
