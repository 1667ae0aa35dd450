"""How long a local user's flood of fresh ports keeps a new sender unknown (swarmd.senderuid;
docs/security.md, "The local user"): the miss budget spent by the flood, a node binding a
port mid-flood and sending every ``--node-period-ms``; measured on the lookup's real clock
(time.monotonic), real sockets, loopback only, bounded in time. Prints markdown.

    .venv/bin/python bench/sender_uid_starve.py [--trials 10] [--node-period-ms 10]
        [--sockets 34000 --cap-s 10] [--hold-s 10]

``--sockets N``: the trials run in a throw-away network namespace (swarmd_lab.netns) where
user ``nobody`` holds N sockets on one port at other loopback addresses (two processes past
17,000: its file limit), as bench/sender_uid_scale.py: every table read costs what such a
table costs, and past MAX_INDEXED_SOCKETS it is cut. The "lookup CPU" column is this
thread's CPU time inside the lookup's reads and queries per second of trial (the cost the
bound of swarmd.senderuid caps at COST_SHARE); "one-socket lookups CPU" the same for the
kernel's one-socket answers a miss of the caller's user asks first (outside that share:
their cost does not grow with the table; swarmd.senderuid, "First contact"); needs root and
setpriv. The lookup takes this process's user (``keep_uids``), the node's, as the daemon
takes ``px4.loopback_user`` and ``ros2.node_users``.

Each trial: a fresh ``SenderUids``; lookups of ports nobody holds, 64 per batch as
``swarmd.udp`` reads them, as fast as this process makes them, for ``--warmup-s`` plus a
random part of a second (seeded; the bind falls anywhere between two reads; the budget is
spent); then a socket is bound on a fresh port of 127.0.0.1 (the node) and its
source is looked up every ``--node-period-ms`` between the flood's batches, until it is
found or ``--cap-s`` passes. The delay is from the bind to the first lookup that names it;
the node's lookups before it are its dropped datagrams. ``--hold-s S``: the flood and the
node go on S seconds after it is found (its datagrams then dropped are counted), so the
CPU columns are the steady state's, not a short trial's first dump and burst. The bounds
the design gives: on the netlink path the node's first datagram when it is a ``keep_uids``
user's (the kernel's one-socket answer and its query: swarmd.senderuid, "First contact");
else the next full dump, ``TTL_S`` after the last (not charged to the miss budget; the
flood's one-port queries do not find the node), or with 34,000 sockets whichever cut dump
or spare query of the share finds it; on the /proc path a miss re-reads the whole table,
so the next token of the budget, ``1 / MISS_READS_PER_S``.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import random
import socket
import statistics
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "lab")]

from swarmd_lab.netns import Lan  # noqa: E402
from swarmd_lab.sockholder import nobody_holds  # noqa: E402

from swarmd.senderuid import TTL_S, SenderUids  # noqa: E402

HELD_PORT = 40_000  # nobody's sockets' port, outside FLOOD_PORTS

FLOOD_PORTS = range(20_000, 30_000)  # mostly free on a test box; a held one is just a hit


def trial(
    netlink: bool, warmup_s: float, period_s: float, cap_s: float, hold_s: float = 0.0
) -> dict[str, float]:
    """One node binding after ``warmup_s`` of flood (module docstring)."""
    # the node is this process's socket, and its user the one the caller takes (as
    # ``px4.loopback_user`` or ``ros2.node_users`` name it in the daemon)
    uids = SenderUids(netlink=netlink, keep_uids={os.getuid()})
    cpu = [0.0]
    for name in ("_read", "_query_source"):  # the lookup's calls into the kernel, timed
        method = getattr(uids, name)

        def timed(*args: Any, _method: Any = method) -> Any:
            started = time.thread_time()
            try:
                return _method(*args)
            finally:
                cpu[0] += time.thread_time() - started

        setattr(uids, name, timed)
    flood = 0
    start = time.monotonic()

    def batch() -> None:
        nonlocal flood
        for _ in range(64):
            uids.uid_of(("127.0.0.1", FLOOD_PORTS[flood % len(FLOOD_PORTS)]))
            flood += 1

    while time.monotonic() - start < warmup_s:
        batch()
    node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        node.bind(("127.0.0.1", 0))
        source = ("127.0.0.1", node.getsockname()[1])
        bound_at = next_send = time.monotonic()
        dropped = dropped_later = 0
        found_after = float("nan")
        while (now := time.monotonic()) - bound_at < cap_s:
            if now >= next_send:
                next_send += period_s
                if uids.uid_of(source) is not None:
                    found_after = now - bound_at
                    break
                dropped += 1
            batch()
        held_until = time.monotonic() + (hold_s if not math.isnan(found_after) else 0.0)
        while (now := time.monotonic()) < held_until:  # the flood goes on, the node sends
            if now >= next_send:
                next_send += period_s
                dropped_later += uids.uid_of(source) is None
            batch()
    finally:
        node.close()
    elapsed = time.monotonic() - start
    return {
        "found_after_s": found_after,
        "dropped": dropped,
        "flood_per_s": flood / elapsed,
        "over_budget": uids.counters["miss_reads_over_budget"],
        "dropped_later": dropped_later,
        "cpu_per_s": cpu[0] / elapsed,
        # the one-socket lookups (outside the share; absent before branch h-uidlookup12)
        "receiver_cpu_per_s": uids.counters.get("receiver_us", 0) / 1e6 / elapsed,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--node-period-ms", type=float, default=10.0)
    parser.add_argument("--warmup-s", type=float, default=0.3)
    parser.add_argument("--cap-s", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--sockets", type=int, default=0)
    parser.add_argument("--hold-s", type=float, default=0.0)
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.sockets and not args.inner:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
        with Lan(1) as lan:
            argv = [sys.executable, str(Path(__file__).resolve()), *sys.argv[1:], "--inner"]
            done = lan[0].run(argv, timeout=1800.0, env=env,
                              check=False)  # fmt: skip
        sys.stdout.write(done.stdout)
        if done.returncode != 0:
            sys.exit(done.stderr[-2000:])
        return
    if not args.sockets:
        run_trials(args)
        return
    with nobody_holds(HELD_PORT, args.sockets):
        run_trials(args)


def run_trials(args: argparse.Namespace) -> None:
    rng = random.Random(args.seed)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    print(f"# {' '.join(sys.argv)}  ({stamp}; TTL_S = {TTL_S}; tree {ROOT})")
    print("| other user's sockets | path | trials | flood lookups/s |"
          " node found after: median / max ms | node datagrams dropped: median / max |"
          " not found within cap | lookup CPU s/s: median / max |"
          " one-socket lookups CPU s/s: median | dropped after found (--hold-s) |")  # fmt: skip
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for netlink in (False, True):
        runs = [
            trial(
                netlink,
                args.warmup_s + rng.random(),
                args.node_period_ms / 1000,
                args.cap_s,
                args.hold_s,
            )
            for _ in range(args.trials)
        ]
        found = [r["found_after_s"] * 1000 for r in runs if not math.isnan(r["found_after_s"])]
        dropped = [r["dropped"] for r in runs]
        rate = statistics.median(r["flood_per_s"] for r in runs)
        delays = f"{statistics.median(found):.0f} / {max(found):.0f}" if found else "- / -"
        cpu = [r["cpu_per_s"] for r in runs]
        print(f"| {args.sockets:,} | {'netlink' if netlink else 'proc'} | {len(runs)} |"
              f" {rate:,.0f} | {delays} |"
              f" {statistics.median(dropped):.0f} / {max(dropped):.0f} |"
              f" {len(runs) - len(found)} | {statistics.median(cpu):.3f} / {max(cpu):.3f} |"
              f" {statistics.median(r['receiver_cpu_per_s'] for r in runs):.3f} |"
              f" {sum(r['dropped_later'] for r in runs)} |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
