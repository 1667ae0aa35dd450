"""A forged-SPDP flood against a flashed 3-drone swarm: real peers lost, daemon CPU.

    sudo .venv/bin/python bench/flood.py [--rate 5000] [--seconds 10] [--repeats 3]
        [--out bench/results/security/flood.json] [--write-docs]

The pieces of
``tests/test_attacks_discovery_netns.py::test_spdp_flood_loses_no_real_peer`` (issue 10,
attack 9): three real ``swarmd`` daemons in namespaces with a bundle flashed by
``swarmctl bundle flash``, the shipped config, a MAVLink vehicle simulator per drone, and
an attacker host that sniffs the members' SPDP and floods the SPDP multicast group with
forged announcements (half with the members' own prefixes: replayed authenticators, and
fresh ones signed with the attacker's key; half new foreign prefixes), paced at ``--rate``
per second, bounded by ``--seconds`` and by ``rate * seconds`` datagrams. Per repeat it
records the real peers any drone saw in another state than "discovered" (or logged lost)
during the flood, and each daemon's CPU (utime + stime from /proc over the flood, in
percent of one core) next to the same daemon idle.
``--write-docs`` rewrites the block between the flood markers in docs/benchmarks.md.
Needs root. Traffic stays in namespaces this process creates.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd_lab.netns import Lan, run_prefix, unavailable_reason  # noqa: E402

from bench.docblock import head_commit, write_block  # noqa: E402
from tests.attacker.cpulimit import CpuLimit  # noqa: E402
from tests.attacker.flood import forged_pool, run_flood  # noqa: E402
from tests.attacker.host import Attacker  # noqa: E402
from tests.attacker.swarm import FlashedSwarm, flashed_swarm, refusals  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs" / "benchmarks.md"
BEGIN = "<!-- flood:begin (bench/flood.py --write-docs) -->"
END = "<!-- flood:end -->"
POOL = 2000
# which of flood_pool's datagrams a --kind keeps (flood_pool's index pattern): a foreign
# prefix (odd), a member's prefix with its sniffed authenticator (a replay, 0 mod 4), a
# member's prefix with a newer freshness signed by the attacker (2 mod 4: a budget refusal,
# or a signature check while the budget lasts)
KINDS = {"mixed": (1, 0), "foreign": (2, 1), "replayed": (4, 0), "resigned": (4, 2)}


def run(
    rate: float, seconds: float, repeats: int, cpu_percent: float | None, kind: str
) -> dict[str, Any]:
    runs: list[dict[str, Any]] = []
    modulo, rest = KINDS[kind]
    with tempfile.TemporaryDirectory(prefix="flood-", dir="/tmp") as tmp:
        lan = Lan(4, prefix=run_prefix("atkb")).__enter__()
        limit = CpuLimit(lan.prefix, cpu_percent) if cpu_percent is not None else None
        try:
            started: list[Attacker] = []

            def listen(sw: FlashedSwarm) -> None:
                # from before the daemons start: vouched members go quiet on SPDP
                started.append(Attacker(sw.attacker_ns, sw.spdp_group).start())

            with flashed_swarm(lan, Path(tmp), before_start=listen) as sw:
                if limit is not None:
                    for i in range(sw.n):
                        limit.add(sw.daemon_pid(i))
                atk = started[0]
                try:
                    for k in range(repeats):
                        pool = forged_pool(sw, atk, POOL * modulo, seed=k)
                        pool = [d for j, d in enumerate(pool) if j % modulo == rest]
                        throttled0 = limit.throttled_s() if limit is not None else {}
                        before = [refusals(sw.status(i)) for i in range(sw.n)]
                        result = run_flood(sw, atk, pool, rate, seconds).as_dict()
                        after = [refusals(sw.status(i)) for i in range(sw.n)]
                        result["refused"] = {
                            sw.names[i]: sum(after[i].values()) - sum(before[i].values())
                            for i in range(sw.n)
                        }
                        if limit is not None:
                            result["throttled_s"] = {
                                g: round(v - throttled0.get(g, 0.0), 2)
                                for g, v in limit.throttled_s().items()
                            }
                        runs.append(result)
                        print(json.dumps(result), file=sys.stderr)
                        sw.wait_ready()  # a repeat starts from a converged swarm
                finally:
                    atk.close()
        finally:
            if limit is not None:
                limit.close()
            lan.close()
    cpu = [v for r in runs for v in r["cpu_percent"].values()]
    idle = [v for r in runs for v in r["idle_cpu_percent"].values()]
    return {
        "commit": head_commit(),
        "host": f"{platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}",
        "rate_hz": rate,
        "kind": kind,
        "cpu_limit_percent": cpu_percent,
        "seconds": seconds,
        "repeats": repeats,
        "sent_per_run": [r["sent"] for r in runs],
        "peers_lost_total": sum(len(v) for r in runs for v in r["peers_lost"].values()),
        "cpu_percent_median": round(statistics.median(cpu), 1) if cpu else None,
        "cpu_percent_max": max(cpu) if cpu else None,
        "idle_cpu_percent_median": round(statistics.median(idle), 1) if idle else None,
        "kernel_drop_fraction_max": max(
            (v / r["sent"] for r in runs for v in r["kernel_rcvbuf_drops"].values() if r["sent"]),
            default=0,
        ),
        "spdp_socket_drop_fraction_max": max(
            (v / r["sent"] for r in runs for v in r["spdp_socket_drops"].values() if r["sent"]),
            default=0,
        ),
        "refused_fraction_min": min(
            (v / r["sent"] for r in runs for v in r["refused"].values() if r["sent"]), default=0
        ),
        "runs": runs,
        "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }


def docs_block(s: dict[str, Any], out: str) -> str:
    lost = s["peers_lost_total"]
    return "\n".join(
        [
            BEGIN,
            f"`sudo .venv/bin/python bench/flood.py --rate {s['rate_hz']:.0f} "
            f"--seconds {s['seconds']:.0f} --repeats {s['repeats']} --out {out} --write-docs` "
            f"at {s['commit']} ({s['when']}; {s['host']}):",
            "",
            "| figure | value |",
            "|---|---|",
            f"| forged SPDP sent per run | {', '.join(str(x) for x in s['sent_per_run'])} |",
            f"| real peers lost (all drones, all runs; target 0) | {lost} |",
            f"| daemon CPU during the flood, % of one core (median / max) | "
            f"{s['cpu_percent_median']} / {s['cpu_percent_max']} |",
            f"| the same daemons idle, % of one core (median) | {s['idle_cpu_percent_median']} |",
            f"| forged datagrams counted as refused (lowest drone; those claiming the receiver's "
            f"own prefix, a third of the member half, count as `own` and are left out) | "
            f"{100 * s['refused_fraction_min']:.0f} % |",
            f"| dropped by the kernel before the daemon read them (highest drone) | "
            f"{100 * s['kernel_drop_fraction_max']:.0f} % |",
            "",
            f"Raw runs: `{out}`.",
            END,
        ]
    )


def write_docs(block: str) -> None:
    write_block(DOCS, BEGIN, END, block)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=5000.0, help="forged datagrams per second")
    p.add_argument("--seconds", type=float, default=10.0, help="flood duration (bounded)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default="bench/results/security/flood.json")
    p.add_argument(
        "--cpu-percent",
        type=float,
        default=None,
        help="cap each daemon at this %% of one core (a cgroup each; a slow, shared drone CPU)",
    )
    p.add_argument("--kind", choices=sorted(KINDS), default="mixed", help="which forgeries")
    p.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = p.parse_args(argv)
    reason = unavailable_reason()
    if reason is not None:
        print(f"flood: {reason}", file=sys.stderr)
        return 2
    if not 0 < args.rate <= 20_000 or not 0 < args.seconds <= 60 or not 1 <= args.repeats <= 10:
        print("flood: --rate 1..20000, --seconds 1..60, --repeats 1..10", file=sys.stderr)
        return 2
    summary = run(args.rate, args.seconds, args.repeats, args.cpu_percent, args.kind)
    out = REPO / args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}, indent=2))
    if args.write_docs:
        write_docs(docs_block(summary, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
