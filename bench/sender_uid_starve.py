"""How long a local user's flood of fresh ports keeps a new sender unknown (swarmd.senderuid;
docs/security.md, "The local user"): the miss budget spent by the flood, a node binding a
port mid-flood and sending every ``--node-period-ms``; measured on the lookup's real clock
(time.monotonic), real sockets, loopback only, bounded in time. Prints markdown.

    .venv/bin/python bench/sender_uid_starve.py [--trials 10] [--node-period-ms 10]

Each trial: a fresh ``SenderUids``; lookups of ports nobody holds, 64 per batch as
``swarmd.udp`` reads them, as fast as this process makes them, for ``--warmup-s`` plus a
random part of a second (seeded; the bind falls anywhere between two reads; the budget is
spent); then a socket is bound on a fresh port of 127.0.0.1 (the node) and its
source is looked up every ``--node-period-ms`` between the flood's batches, until it is
found or ``--cap-s`` passes. The delay is from the bind to the first lookup that names it;
the node's lookups before it are its dropped datagrams. The bounds the design gives: on
the netlink path the next full dump, ``TTL_S`` after the last (not charged to the miss
budget; the flood's one-port queries do not find the node); on the /proc path a miss
re-reads the whole table, so the next token of the budget, ``1 / MISS_READS_PER_S``.
"""

from __future__ import annotations

import argparse
import datetime
import math
import random
import socket
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd.senderuid import TTL_S, SenderUids  # noqa: E402

FLOOD_PORTS = range(20_000, 30_000)  # mostly free on a test box; a held one is just a hit


def trial(netlink: bool, warmup_s: float, period_s: float, cap_s: float) -> dict[str, float]:
    """One node binding after ``warmup_s`` of flood (module docstring)."""
    uids = SenderUids(netlink=netlink)
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
        dropped = 0
        found_after = float("nan")
        while (now := time.monotonic()) - bound_at < cap_s:
            if now >= next_send:
                next_send += period_s
                if uids.uid_of(source) is not None:
                    found_after = now - bound_at
                    break
                dropped += 1
            batch()
    finally:
        node.close()
    elapsed = time.monotonic() - start
    return {
        "found_after_s": found_after,
        "dropped": dropped,
        "flood_per_s": flood / elapsed,
        "over_budget": uids.counters["miss_reads_over_budget"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--node-period-ms", type=float, default=10.0)
    parser.add_argument("--warmup-s", type=float, default=0.3)
    parser.add_argument("--cap-s", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    print(f"# {' '.join(sys.argv)}  ({stamp}; TTL_S = {TTL_S})")
    print("| path | trials | flood lookups/s | node found after: median / max ms |"
          " node datagrams dropped: median / max | not found within cap |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    for netlink in (False, True):
        runs = [
            trial(netlink, args.warmup_s + rng.random(), args.node_period_ms / 1000, args.cap_s)
            for _ in range(args.trials)
        ]
        found = [r["found_after_s"] * 1000 for r in runs if not math.isnan(r["found_after_s"])]
        dropped = [r["dropped"] for r in runs]
        rate = statistics.median(r["flood_per_s"] for r in runs)
        delays = f"{statistics.median(found):.0f} / {max(found):.0f}" if found else "- / -"
        print(f"| {'netlink' if netlink else 'proc'} | {len(runs)} | {rate:,.0f} | {delays} |"
              f" {statistics.median(dropped):.0f} / {max(dropped):.0f} |"
              f" {len(runs) - len(found)} |")  # fmt: skip


if __name__ == "__main__":
    main()
