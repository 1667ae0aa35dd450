"""What one forged SPDP datagram costs the daemon, per refusal path, through its read path.

    .venv/bin/python bench/flood_cost.py [--count 2000] [--repeat 5]

``bench/auth.py`` times ``DiscoveryEngine.receive_datagram`` alone; a daemon also pays the
socket read, the event loop's wake-up and the driver's drain per input. Here a real UDP
socket on loopback is filled with ``--count`` datagrams of one kind, then the daemon's
reader (``swarmd.udp.BatchedSocket`` feeding a ``Driver`` around an authenticated engine)
drains it; CPU time (``time.process_time``) per datagram, median of ``--repeat`` runs. The
"asyncio, one per wake-up" rows are the read path before batching (asyncio's datagram
transport calling ``Driver.datagram_received`` once per datagram). Only reports; no test
asserts on it.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd_lab.testing import auth_for, engine_for, make_bundle, peer_datagram  # noqa: E402

from swarmd.driver import Driver  # noqa: E402
from swarmd.udp import READ_BATCH, BatchedSocket  # noqa: E402


def kinds(count: int) -> dict[str, list[bytes]]:
    bundle = make_bundle(10)
    stranger = make_bundle(10, swarm="forger")
    genuine = peer_datagram(bundle, 1, auth=auth_for(bundle, 1, epoch=7))
    forger = auth_for(bundle, 2, epoch=1000)
    return {
        "unknown prefix (foreign budget spent)": [
            peer_datagram(stranger, 1 + i % 9, sequence_number=1 + i) for i in range(count)
        ],
        "member prefix, replayed freshness": [genuine] * count,
        "member prefix, newer freshness, budget refusal": [
            peer_datagram(bundle, 1, auth=forger) for _ in range(count)
        ],
    }


class _Counter:
    def __init__(self, driver: Driver[bytes, Any, Any]) -> None:
        self.driver = driver
        self.received = 0

    def batch(self, batch: list[tuple[bytes, tuple[str, int]]], _via: str) -> None:
        self.received += len(batch)
        self.driver.datagrams_received(batch)


class _OnePerWakeup(asyncio.DatagramProtocol):
    def __init__(self, counter: _Counter) -> None:
        self.counter = counter

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.counter.received += 1
        self.counter.driver.datagram_received(data, addr)


async def drain(datagrams: list[bytes], batched: bool) -> float:
    """CPU seconds per datagram to read and refuse ``datagrams`` already queued."""
    bundle = make_bundle(10)
    engine = engine_for(bundle, 0, auth=auth_for(bundle, 0))
    loop = asyncio.get_running_loop()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    driver: Driver[bytes, Any, Any] = Driver(
        engine, transmit=lambda _out: None, on_event=lambda _e: None, name="bench"
    )
    counter = _Counter(driver)
    # warm the engine's budgets to their steady state (spent), as a flood would
    for d in datagrams[:300]:
        engine.receive_datagram(d, ("127.0.0.1", 1), loop.time())
    for d in datagrams:
        tx.sendto(d, rx.getsockname())
    tx.close()
    t0 = time.process_time()
    if batched:
        reader = BatchedSocket(rx, "multicast", counter.batch, lambda _c: None, loop)
        close: Callable[[], None] = reader.close
    else:
        transport, _ = await loop.create_datagram_endpoint(lambda: _OnePerWakeup(counter), sock=rx)
        close = transport.close
    while counter.received < len(datagrams):  # noqa: ASYNC110 - the loop's turns are the cost
        await asyncio.sleep(0)
    cpu = time.process_time() - t0
    close()
    driver.close()
    return cpu / len(datagrams)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=2000)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    rows = []
    for kind, datagrams in kinds(args.count).items():
        for batched in (False, True):
            runs = [asyncio.run(drain(datagrams, batched)) * 1e6 for _ in range(args.repeat)]
            rows.append(
                {
                    "kind": kind,
                    "reader": (
                        f"batched ({READ_BATCH} per wake-up)"
                        if batched
                        else "asyncio, one per wake-up"
                    ),
                    "us_per_datagram": round(statistics.median(runs), 1),
                    "min": round(min(runs), 1),
                    "max": round(max(runs), 1),
                }
            )
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("| forged datagram | read path | CPU us per datagram, median (min..max) |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['kind']} | {r['reader']} | {r['us_per_datagram']} ({r['min']}..{r['max']}) |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
