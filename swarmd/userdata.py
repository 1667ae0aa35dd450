"""The user-data UDP socket: the data plane's transport, nothing else.

Datagrams on the user unicast port (``Bundle.user_port``) go to a sink (the swarm's
``Driver.datagram_received``, which feeds the ``SwarmCore`` and through it the
``DataPlane`` at ``loop.time()``); ``send`` is the driver's ``transmit``. Timers, draining
and re-entrancy are the driver's (``swarmd/driver.py``).
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from typing import Final

RECV_BUFFER_BYTES: Final = 1 << 20  # a commander hears N members at 1 Hz plus repairs

DatagramSink = Callable[[bytes, tuple[str, int]], None]


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


class UserDataSocket(asyncio.DatagramProtocol):
    """One bound UDP socket: datagrams in to ``sink``, out through ``send``."""

    def __init__(self, sink: DatagramSink) -> None:
        self.sink = sink
        self.transport: asyncio.DatagramTransport | None = None
        self.errors = 0  # ICMP errors (a peer's daemon gone: its lease will tell discovery)

    @classmethod
    async def open(cls, port: int, sink: DatagramSink) -> UserDataSocket:
        """Bind the user unicast port; ``OSError`` when it is taken."""
        loop = asyncio.get_running_loop()
        sock = open_user_socket(port)
        transport, protocol = await loop.create_datagram_endpoint(lambda: cls(sink), sock=sock)
        protocol.transport = transport
        return protocol

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.sink(data, addr)

    def error_received(self, exc: Exception) -> None:
        self.errors += 1

    def send(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.transport is not None:
            self.transport.sendto(data, addr)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None
