"""The daemon's UDP sockets (SPDP and user data): batched reads and the receive buffer
(docs/security.md, "Flood")."""

from __future__ import annotations

import asyncio
import socket

from swarmd.udp import READ_BATCH, RECV_BUFFER_BYTES, BatchedSocket, rcvbuf_capped
from swarmd.userdata import UserDataSocket


def test_rcvbuf_capped_reads_the_kernels_doubled_answer() -> None:
    """getsockopt answers twice the grant (socket(7)): a full grant is not "capped", a
    request the kernel cut (here: a small one on purpose) is."""
    assert not rcvbuf_capped(2 * RECV_BUFFER_BYTES)
    assert rcvbuf_capped(2 * RECV_BUFFER_BYTES - 1)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 64 * 1024)
        granted = s.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        assert granted == 2 * 64 * 1024  # the doubling rcvbuf_capped relies on
        assert rcvbuf_capped(granted)


def _loopback_pair() -> tuple[socket.socket, socket.socket]:
    """(receiver, sender) on loopback; the receiver non-blocking, as the daemon's are."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx.bind(("127.0.0.1", 0))
    return rx, tx


def test_queued_datagrams_arrive_in_batches_in_order_with_their_sources() -> None:
    """150 datagrams already queued: read in batches of at most READ_BATCH, none lost or
    reordered, each with its sender's address; after close the fd has no reader."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        rx, tx = _loopback_pair()
        for i in range(150):
            tx.sendto(i.to_bytes(2, "big"), rx.getsockname())
        batches: list[list[tuple[bytes, tuple[str, int]]]] = []
        done = asyncio.Event()

        def on_batch(batch: list[tuple[bytes, tuple[str, int]]], via: str) -> None:
            assert via == "multicast"
            batches.append(batch)
            if sum(map(len, batches)) >= 150:
                done.set()

        reader = BatchedSocket(rx, "multicast", on_batch, lambda _c: None, loop)
        await asyncio.wait_for(done.wait(), 10.0)
        got = [d for b in batches for d in b]
        assert [int.from_bytes(d, "big") for d, _ in got] == list(range(150))
        assert {src for _, src in got} == {tx.getsockname()}
        assert max(map(len, batches)) <= READ_BATCH and len(batches) >= 3
        reader.close()
        tx.close()
        assert rx.fileno() == -1

    asyncio.run(main())


def test_user_data_socket_reads_queued_datagrams_in_batches() -> None:
    """The user-data socket (swarmd/userdata.py) reads like the SPDP sockets: datagrams
    queued before the loop runs reach the sink in fewer wake-ups than datagrams, one
    wake-up takes at most READ_BATCH, none lost or reordered (it read one per wake-up: a
    forged-MAC flood cost a full event-loop turn each)."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        rx, tx = _loopback_pair()
        n = 3 * READ_BATCH + 10
        wakeups: list[int] = []
        got: list[tuple[bytes, tuple[str, int]]] = []
        done = asyncio.Event()

        def sink(batch: list[tuple[bytes, tuple[str, int]]]) -> None:
            wakeups.append(len(batch))
            got.extend(batch)
            if len(got) >= n:
                done.set()

        user = UserDataSocket(rx, sink, loop)
        for i in range(n):  # all queued before the loop can wake the reader
            tx.sendto(i.to_bytes(2, "big"), rx.getsockname())
        user.reader.read_ready()  # one readiness callback: bounded by the cap
        assert wakeups == [READ_BATCH]
        await asyncio.wait_for(done.wait(), 10.0)
        assert [int.from_bytes(d, "big") for d, _ in got] == list(range(n))
        assert {src for _, src in got} == {tx.getsockname()}
        assert max(wakeups) <= READ_BATCH
        assert len(wakeups) < n
        user.send(b"back", tx.getsockname())
        assert tx.recvfrom(16) == (b"back", rx.getsockname())
        user.close()
        tx.close()
        assert rx.fileno() == -1

    asyncio.run(main())
