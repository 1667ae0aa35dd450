"""Batched reading of the daemon's UDP sockets: SPDP (multicast and unicast metatraffic) and
user data. Daemon tier: the sans-IO cores never see a socket.

asyncio's datagram transport reads one datagram per wake-up (a full event-loop turn, an
epoll call and a 256 KiB receive buffer each), and under a flood that bookkeeping, not the
core's refusal, was most of the daemon's cost (docs/security.md, "Flood"). ``BatchedSocket``
reads up to ``READ_BATCH`` datagrams per wake-up and hands them on together, so the driver
drains once per batch (``Driver.datagrams_received``).
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from typing import Final

Datagram = tuple[bytes, tuple[str, int]]

# The receive buffers. The kernel charges a datagram's whole buffer (~1-2 KiB for a 300-byte
# DATA(p)), not its payload: 4 MiB holds ~2,000-4,000 datagrams, ~0.5 s of a 5,000/s flood,
# so a daemon that falls behind for a moment (a busy drone CPU) catches up instead of the
# kernel dropping real peers' datagrams among the forgeries. The kernel caps it at
# net.core.rmem_max (Linux's default 208 KiB; docs/security.md says to raise it).
RECV_BUFFER_BYTES: Final = 4 << 20
# Datagrams read from one socket per loop wake-up before anything else runs: one epoll
# round trip and one driver drain per batch instead of per datagram, while timers and the
# control socket still run between batches.
READ_BATCH: Final = 64
MAX_DATAGRAM: Final = 65_535  # a UDP payload's limit: recvfrom allocates no more


def rcvbuf_capped(granted: int) -> bool:
    """Whether the kernel gave less receive buffer than ``RECV_BUFFER_BYTES`` asked for.

    ``getsockopt(SO_RCVBUF)`` answers twice what was granted (socket(7): the kernel doubles
    the request for its bookkeeping), and a request above ``net.core.rmem_max`` is cut to
    it."""
    return granted < 2 * RECV_BUFFER_BYTES


class BatchedSocket:
    """One non-blocking UDP socket read in batches; ``name`` only labels the counters.

    ``read_ready`` (the loop's reader callback) reads up to ``READ_BATCH`` datagrams and
    calls ``on_batch(batch, name)`` once. Sending is a plain non-blocking ``sendto``: a full
    send buffer or an ICMP error is counted (asyncio's transport would queue the first and
    report the second; discovery repeats its datagrams and the reliable data plane repairs
    what is lost)."""

    def __init__(
        self,
        sock: socket.socket,
        name: str,
        on_batch: Callable[[list[Datagram], str], None],
        count: Callable[[str], None],
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.sock = sock
        self.name = name
        self.on_batch = on_batch
        self.count = count
        self.loop = loop
        self._fd = sock.fileno()
        loop.add_reader(self._fd, self.read_ready)

    def read_ready(self) -> None:
        batch: list[Datagram] = []
        recvfrom = self.sock.recvfrom
        for _ in range(READ_BATCH):
            try:
                batch.append(recvfrom(MAX_DATAGRAM))
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable from a peer that left, and the like
                self.count(f"socket_error_{self.name}")
                break
        if batch:
            self.on_batch(batch, self.name)

    def sendto(self, data: bytes, addr: tuple[str, int]) -> None:
        try:
            self.sock.sendto(data, addr)
        except (BlockingIOError, InterruptedError):
            self.count(f"tx_dropped_full_{self.name}")
        except OSError:  # ENOBUFS on a saturated channel, an unreachable network
            self.count(f"socket_error_{self.name}")

    def close(self) -> None:
        if self.sock.fileno() >= 0:
            self.loop.remove_reader(self._fd)
            self.sock.close()
