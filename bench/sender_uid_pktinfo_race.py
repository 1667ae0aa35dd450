"""How often a spoof by ``IP_PKTINFO`` passes when the spoofer closes its socket at once
(docs/security.md, "The local user", residual (6)): user ``nobody`` binds a node's port at
another address (``127.0.0.2:P``, or ``[2001:db8::7]:P`` by ``IPV6_FREEBIND`` for
``--family 6``), sends one datagram naming the node's address as its source, and closes
the socket; ``--wait-ms`` after the bind first (a socket held that long before it sends).
``--count`` such datagrams, one every ``--period-ms``. This process holds the node's
socket and a receiving one, and looks each datagram's source up as the daemon does
(``SenderUids``, netlink, taking the node's user, on the real clock: the node found and
kept first). Prints how many passed as the node's. Needs root and setpriv; loopback only.

    .venv/bin/python bench/sender_uid_pktinfo_race.py [--family 4] [--count 200]
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "lab")]

from swarmd_lab.pktinfo import nobody_spoofs  # noqa: E402

from swarmd.senderuid import TTL_S, SenderUids  # noqa: E402

MAX_COUNT = 2_000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", type=int, choices=(4, 6), default=4)
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--period-ms", type=float, default=20.0)
    parser.add_argument("--wait-ms", type=float, default=0.0)
    args = parser.parse_args()
    if os.geteuid() != 0:
        sys.exit("needs root (setpriv to user nobody)")
    count = min(args.count, MAX_COUNT)
    node_host, bind = ("127.0.0.1", "127.0.0.2") if args.family == 4 else ("::1", "2001:db8::7")
    family = socket.AF_INET if args.family == 4 else socket.AF_INET6
    with (
        socket.socket(family, socket.SOCK_DGRAM) as node,
        socket.socket(family, socket.SOCK_DGRAM) as daemon,
    ):
        node.bind((node_host, 0))
        daemon.bind((node_host, 0))
        daemon.settimeout(2.0)
        port, dest = node.getsockname()[1], daemon.getsockname()[1]
        uids = SenderUids(netlink=True, keep_uids={os.geteuid()})
        node.sendto(b"node", (node_host, dest))
        _data, source = daemon.recvfrom(64)
        assert uids.uid_of(source) == os.geteuid()  # found and kept
        answers: Counter[str] = Counter()
        started = time.monotonic()
        with nobody_spoofs(
            bind, port, (node_host, dest), node_host, count=count,
            period_ms=args.period_ms, wait_ms=args.wait_ms,
        ) as spoofer:  # fmt: skip
            try:
                for _ in range(count):
                    _data, source = daemon.recvfrom(64)
                    uid = uids.uid_of(source)
                    answers["node's" if uid == os.geteuid() else str(uid)] += 1
            except TimeoutError:
                answers["lost"] += count - sum(answers.values())
            finally:
                spoofer.kill()
        elapsed = time.monotonic() - started
    print(f"# {' '.join(sys.argv)}  (TTL_S = {TTL_S}; {elapsed:.1f} s)")
    passed, denied = answers["node's"], answers["None"]
    other = count - passed - denied
    shared, queries = uids.counters["port_shared"], uids.counters["port_queries"]
    print(
        f"spoofs: {count}, passed as the node's: {passed}, nobody's (None): {denied}, "
        f"other: {other}; port_shared: {shared}, port queries: {queries}"
    )


if __name__ == "__main__":
    main()
