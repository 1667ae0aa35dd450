"""What telling local senders apart costs (swarmd.senderuid; docs/security.md,
"Telling local users apart"): the socket-table lookup per datagram, per table read, and
under a flood of fresh ports. Loopback only, bounded in count. Prints markdown.

    .venv/bin/python bench/sender_uid.py [--sockets 0,200,2000] [--count 20000]

For each extra socket count (opened here on 127.0.0.1 and ::1 before measuring, as other
processes' sockets would be):

1. a hit: ``uid_of`` for a source whose socket is in the table read (the steady case: a node
   or PX4 sending several datagrams a second); mean over ``--count`` lookups;
2. a table read: ``/proc/net/udp`` and ``udp6`` read and indexed, or the netlink sock_diag
   dump of both families (every ``TTL_S``; on the /proc path also on a miss within the miss
   budget); mean over 200 reads;
3. a miss (netlink path): one source's query, both families, filtered in the kernel by
   port (and, since branch h-uidaddr, by the source's address and its wildcards); mean over
   200 queries of a port nobody holds;
4. a flood of fresh ports: ``--count`` lookups of ports nobody holds, 64 per "batch" as
   ``swarmd.udp`` reads them, each batch 1 ms apart on the lookup's own clock: the mean
   cost per datagram with the miss budget spending its reads or queries.

Both paths in one run, side by side (``proc``: ``SenderUids(netlink=False)``, ``netlink``:
the default), and for reference pyroute2's ``DiagSocket.get_sock_stats`` (a full UDP dump
of both families, and the same by port), which the lookup does not use.

2 shared cores: the times move with the box's load; the reads per flood do not.
"""

from __future__ import annotations

import argparse
import datetime
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd.senderuid import SenderUids  # noqa: E402


class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _open(n: int) -> list[socket.socket]:
    out = []
    for i in range(n):
        family, host = (socket.AF_INET, "127.0.0.1") if i % 2 else (socket.AF_INET6, "::1")
        s = socket.socket(family, socket.SOCK_DGRAM)
        s.bind((host, 0))
        out.append(s)
    return out


def pyroute2_us(port: int, reps: int) -> tuple[float, float]:
    """pyroute2's DiagSocket: a full UDP dump of both families, and the same for one port."""
    from pyroute2.netlink.diag import SS_ALL, DiagSocket

    out = []
    with DiagSocket() as ds:
        ds.bind()
        for sport in (0, port):
            start = time.perf_counter()
            for _ in range(reps):
                for family in (socket.AF_INET, socket.AF_INET6):
                    ds.get_sock_stats(
                        family=family, protocol=socket.IPPROTO_UDP, states=SS_ALL, sport=sport
                    )
            out.append((time.perf_counter() - start) / reps * 1e6)
    return out[0], out[1]


def measure(extra: int, count: int, netlink: bool) -> dict[str, float]:
    socks = _open(extra)
    mine = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    mine.bind(("::1", 0))
    source = ("::1", mine.getsockname()[1], 0, 0)
    try:
        clock = _Clock()
        uids = SenderUids(clock=clock, netlink=netlink)
        assert (uids._diag is not None) == netlink  # noqa: SLF001 - the path measured
        assert uids.uid_of(source) is not None
        start = time.perf_counter()
        for _ in range(count):
            uids.uid_of(source)
        hit_us = (time.perf_counter() - start) / count * 1e6
        reads = 200
        start = time.perf_counter()
        for _ in range(reads):
            uids._read(clock.now)  # noqa: SLF001 - the read itself is what is measured
        read_us = (time.perf_counter() - start) / reads * 1e6
        lines = sum(len(v) for v in uids._index.values())  # noqa: SLF001
        query_us = float("nan")
        if netlink:
            start = time.perf_counter()
            query = getattr(uids, "_query_source", None)  # before h-uidaddr: by port only
            for _ in range(reads):
                # a port nobody holds (below 1024, unused)
                query("127.0.0.1", 1) if query else uids._query_port(1)  # type: ignore[attr-defined]  # noqa: SLF001
            query_us = (time.perf_counter() - start) / reads * 1e6
        flood = SenderUids(clock=clock, netlink=netlink)
        flood.uid_of(source)
        before = flood.counters["reads"] + flood.counters["port_queries"]
        start = time.perf_counter()
        for i in range(count):
            if i % 64 == 0:
                clock.now += 0.001
            flood.uid_of(("127.0.0.1", 1 + (i * 7919) % 65000))
        flood_us = (time.perf_counter() - start) / count * 1e6
        flood_reads = flood.counters["reads"] + flood.counters["port_queries"] - before
        return {
            "extra": extra,
            "indexed": lines,
            "hit_us": hit_us,
            "read_us": read_us,
            "query_us": query_us,
            "flood_us": flood_us,
            "flood_reads": flood_reads,
            "flood_virtual_s": clock.now,
        }
    finally:
        mine.close()
        for s in socks:
            s.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sockets", default="0,200,2000")
    parser.add_argument("--count", type=int, default=20_000)
    parser.add_argument("--pyroute2-reps", type=int, default=5)
    args = parser.parse_args()
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    print(f"# {' '.join(sys.argv)}  ({stamp})")
    print("| extra sockets | path | indexed (loopback+wildcard) | hit µs/lookup | table read µs |"
          " miss query µs | flood µs/datagram | reads+queries in flood (per virtual s) |"
          " pyroute2 DiagSocket dump µs / by port µs |")  # fmt: skip
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for extra in (int(x) for x in args.sockets.split(",")):
        for netlink in (False, True):
            r = measure(extra, args.count, netlink)
            per_s = r["flood_reads"] / r["flood_virtual_s"]
            ref = "-"
            if netlink:
                mine = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
                mine.bind(("::1", 0))
                socks = _open(extra)
                try:
                    dump, by_port = pyroute2_us(mine.getsockname()[1], args.pyroute2_reps)
                finally:
                    mine.close()
                    for s in socks:
                        s.close()
                ref = f"{dump:.0f} / {by_port:.0f}"
            path = "netlink" if netlink else "proc"
            print(f"| {extra} | {path} | {r['indexed']:.0f} |"
                  f" {r['hit_us']:.2f} | {r['read_us']:.0f} | {r['query_us']:.0f} |"
                  f" {r['flood_us']:.2f} | {r['flood_reads']:.0f} ({per_s:.0f}/s) |"
                  f" {ref} |")  # fmt: skip


if __name__ == "__main__":
    main()
