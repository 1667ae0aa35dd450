"""What the kernel's one-socket lookup costs when another user holds a long hash chain
(swarmd.senderuid, "First contact"; docs/security.md, "The local user", residual (5)): in a
throw-away network namespace (swarmd_lab.netns), user ``nobody`` binds ``--sockets``
sockets with SO_REUSEADDR all to 127.0.0.1:P (swarmd_lab.sockholder, ``same_address``), so
the kernel's lookup of a source on P walks every one of them. Prints, per count, the
lookup's CPU time (``UdpDiag.receiver``, this thread) for P and for a port nobody holds.
Then the flood: with 17,000 more of nobody's sockets elsewhere (every dump cut, so every
datagram is a miss), a daemon-like lookup (``keep_uids={0}``) answers ``uid_of`` for P for
``--flood-s`` wall seconds as fast as it can, and the bench prints the lookup's CPU time
per wall second, split into the one-socket lookups' and the reads' and queries'.
``--tree`` runs another checkout's swarmd (main, for the before). Needs root and setpriv.

    .venv/bin/python bench/sender_uid_receiver_walk.py [--sockets 1000,5000,17000]
        [--reps 200] [--flood-s 3] [--tree DIR]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT / "lab")]

from swarmd_lab.netns import Lan  # noqa: E402

# Runs inside the namespace: argv = counts (comma-separated), reps, flood seconds.
SCENARIO = """
import json, socket, sys, time
from swarmd.senderuid import SenderUids
from swarmd.sockdiag import UdpDiag
from swarmd_lab.sockholder import nobody_holds
counts = [int(n) for n in sys.argv[1].split(",")]
reps, flood_s = int(sys.argv[2]), float(sys.argv[3])
lo, port = socket.inet_aton("127.0.0.1"), 40_000
diag = UdpDiag()
def per_call_ms(p):
    start = time.thread_time()
    for _ in range(reps):
        diag.receiver(socket.AF_INET, lo, p)
    return (time.thread_time() - start) / reps * 1000
for count in counts:
    with nobody_holds(port, count, hold_s=300.0, same_address=True):
        print(json.dumps({"sockets": count, "chain_ms": per_call_ms(port),
                          "empty_ms": per_call_ms(port + 1)}), flush=True)
count = counts[-1]
with nobody_holds(port, count, hold_s=300.0, same_address=True), \\
        nobody_holds(port + 2, 17_000, hold_s=300.0):
    uids = SenderUids(netlink=True, keep_uids={0})
    start_cpu, start = time.thread_time(), time.monotonic()
    while time.monotonic() - start < flood_s:
        uids.uid_of(("127.0.0.1", port))
    wall = time.monotonic() - start
    c = uids.counters
    print(json.dumps({"flood_sockets": count, "wall_s": wall, "lookups": c["lookups"],
                      "cpu_per_s": (time.thread_time() - start_cpu) / wall,
                      "receiver_per_s": c["receiver_us"] / 1e6 / wall,
                      "reads_queries_per_s": c["cost_us"] / 1e6 / wall,
                      "receiver_lookups": c["receiver_lookups"],
                      "receiver_over_budget": c["receiver_over_budget"]}), flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sockets", default="1000,5000,17000")
    parser.add_argument("--reps", type=int, default=200)
    parser.add_argument("--flood-s", type=float, default=3.0)
    parser.add_argument("--tree", type=Path, default=ROOT)
    args = parser.parse_args()
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    path = [str(args.tree.resolve()), str(ROOT / "lab"), *sys.path]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(path))
    argv = [args.sockets, str(args.reps), str(args.flood_s)]
    with Lan(1) as lan:
        done = lan[0].run(  # -P: the tree's swarmd, not the working directory's
            [sys.executable, "-P", "-c", SCENARIO, *argv], timeout=900.0, env=env, check=False
        )
    if done.returncode != 0:
        sys.exit(done.stderr[-2000:])
    print(f"# {' '.join(sys.argv)}  ({stamp}; swarmd of {args.tree.resolve()})")
    print("| nobody's sockets at 127.0.0.1:P | one-socket lookup of P, ms | of an empty port, ms |")
    print("|---:|---:|---:|")
    for line in done.stdout.splitlines():
        r = json.loads(line)
        if "sockets" in r:
            print(f"| {r['sockets']:,} | {r['chain_ms']:.3f} | {r['empty_ms']:.3f} |")
        else:
            print(
                f"flood from P ({r['flood_sockets']:,} sockets on it, every dump cut):"
                f" {r['lookups']:,} lookups in {r['wall_s']:.1f} s; the lookup's CPU"
                f" {r['cpu_per_s']:.2f} s/s, of it one-socket lookups"
                f" {r['receiver_per_s']:.2f} s/s ({r['receiver_lookups']:,},"
                f" {r['receiver_over_budget']:,} over budget), reads and queries"
                f" {r['reads_queries_per_s']:.2f} s/s"
            )


if __name__ == "__main__":
    main()
