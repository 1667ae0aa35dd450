"""The daemon's SPDP sockets: batched reads and the receive buffer (docs/security.md, "Flood")."""

from __future__ import annotations

import asyncio
import socket

from swarmd.daemon import READ_BATCH, RECV_BUFFER_BYTES, BatchedSocket, rcvbuf_capped


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


def test_queued_datagrams_arrive_in_batches_in_order_with_their_sources() -> None:
    """150 datagrams already queued: read in batches of at most READ_BATCH, none lost or
    reordered, each with its sender's address; after close the fd has no reader."""

    async def main() -> None:
        loop = asyncio.get_running_loop()
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.bind(("127.0.0.1", 0))
        rx.setblocking(False)
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.bind(("127.0.0.1", 0))
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
