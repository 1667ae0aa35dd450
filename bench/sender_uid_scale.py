"""What a local user holding more sockets than the lookup indexes costs it (swarmd.senderuid;
docs/security.md, "The local user", residual (5)): in a throw-away network namespace
(swarmd_lab.netns: the host's ports are never touched), a node on 127.0.0.1:P and user
``nobody`` holding ``--sockets`` sockets on P at other loopback addresses (two processes:
its file limit is 20,000 here: swarmd_lab.sockholder), bound after the node so the kernel
lists them first. Times,
on the wall clock, a table read (netlink dump, cut at MAX_INDEXED_SOCKETS), the node's
source query (every socket on the port that can send IPv4, at any address, read until a
second owner shows: since branch h-pktinfo12 the node's port is nobody's here, the other
user's rows being on it, and the query stops at the first chunk) and a query of a port
nobody holds, the same node's query by a lookup that takes the node's user (``keep_uids``,
as the daemon's: it stops past ``FOREIGN_ROWS`` of another user's rows),
and the kernel's one-socket answer for the node's source and that port (``UdpDiag.receiver``,
branch h-uidlookup12 on); mean over ``--reps``. Prints markdown. Needs root and setpriv.

    .venv/bin/python bench/sender_uid_scale.py [--sockets 34000] [--reps 20]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "lab")]

from swarmd_lab.netns import Lan  # noqa: E402

# Runs inside the namespace: argv = sockets, reps. Prints one JSON line.
SCENARIO = """
import json, socket, sys, time
from swarmd.senderuid import SenderUids
from swarmd_lab.sockholder import nobody_holds
total, reps = int(sys.argv[1]), int(sys.argv[2])
node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
node.bind(("127.0.0.1", 0))
port = node.getsockname()[1]
with node, nobody_holds(port, total, hold_s=120.0):
    uids = SenderUids(clock=lambda: 0.0, netlink=True)
    query = getattr(uids, "_query_source", None)
    if query is None:  # before branch h-uidaddr: by port only
        node_query = lambda: uids._query_port(port)
        empty_query = lambda: uids._query_port(1)
    else:
        node_query = lambda: query("127.0.0.1", port)
        empty_query = lambda: query("127.0.0.1", 1)
    out = {}
    fns = [("read_ms", lambda: uids._read(0.0)), ("node_query_ms", node_query),
           ("empty_query_ms", empty_query)]
    if hasattr(uids, "keep_uids"):  # the daemon's lookup: it takes the node's user
        kept = SenderUids(clock=lambda: 0.0, netlink=True, keep_uids={0})
        fns.append(("kept_query_ms", lambda: kept._query_source("127.0.0.1", port)))
    diag = uids._diag
    if hasattr(diag, "receiver"):  # the one-socket lookup (branch h-uidlookup12 on)
        lo = socket.inet_aton("127.0.0.1")
        fns += [("node_receiver_ms", lambda: diag.receiver(socket.AF_INET, lo, port)),
                ("empty_receiver_ms", lambda: diag.receiver(socket.AF_INET, lo, 1))]
        out["node_receiver_uid"] = diag.receiver(socket.AF_INET, lo, port).uid
    for name, fn in fns:
        start = time.perf_counter()
        for _ in range(reps):
            fn()
        out[name] = (time.perf_counter() - start) / reps * 1000
    uids._read(0.0)
    out["node_in_index"] = any(uid == 0 for _, uid in uids._index.get(port, ()))
    out["truncated"] = uids.counters["truncated"]
    out["node_found_by_query"] = (query("127.0.0.1", port) if query else
                                  (uids._query_port(port), uids._uids("127.0.0.1", port))[1]) == {0}
    print(json.dumps(out), flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sockets", type=int, default=34_000)
    parser.add_argument("--reps", type=int, default=20)
    args = parser.parse_args()
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    with Lan(1) as lan:
        done = lan[0].run(
            [sys.executable, "-c", SCENARIO, str(args.sockets), str(args.reps)],
            timeout=600.0,
            env=env,
            check=False,
        )
    if done.returncode != 0:
        sys.exit(done.stderr[-2000:])
    r = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"# {' '.join(sys.argv)}  ({stamp}; tree {ROOT})")
    print("| other user's sockets | table read ms | node's query ms | empty port's query ms |"
          " node in the (cut) index | node found by its query |"
          " node's one-socket lookup ms | empty port's one-socket lookup ms |")  # fmt: skip
    print("|---:|---:|---:|---:|---|---|---:|---:|")
    receivers = (
        (
            f" {r['node_receiver_ms']:.3f} (uid {r['node_receiver_uid']}) |"
            f" {r['empty_receiver_ms']:.3f} |"
        )
        if "node_receiver_ms" in r
        else " - | - |"
    )
    if "kept_query_ms" in r:
        print(f"node's query with keep_uids (the daemon's): {r['kept_query_ms']:.2f} ms")
    print(f"| {args.sockets:,} | {r['read_ms']:.1f} | {r['node_query_ms']:.2f} |"
          f" {r['empty_query_ms']:.2f} | {r['node_in_index']} |"
          f" {r['node_found_by_query']} |{receivers}")  # fmt: skip


if __name__ == "__main__":
    main()
