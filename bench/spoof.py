"""Spoofed SPDP from the swarm's own addresses (issue 18): real peers lost, daemon CPU.

    sudo .venv/bin/python bench/spoof.py --label after [--rates 100,1000,5000]
        [--seconds 30] [--out bench/results/security/spoof_after.json] [--write-docs]

The pieces of ``tests/test_attacks_spoof_netns.py``: three real ``swarmd`` daemons in
namespaces (bundle flashed by ``swarmctl bundle flash``, the shipped config, a MAVLink
vehicle simulator each) and an attacker host that sniffs their SPDP and sends raw IPv4
claiming the commander's exact address (to the multicast group and to each member's
metatraffic port) and each member's (to the group and to the commander): forgeries under
the claimed drone's own prefix, fresh, signed with the attacker's key, random receiver tags
(``tests/attacker/spoof.py``), a quarter of them plain replays. Per rate, from a freshly
started, converged swarm: the real peers any drone saw in another state than
"discovered" (or logged lost) during the flood and when, ``swarmctl takeoff --require-all``
started half-way through (its exit code), each daemon's CPU (utime + stime from /proc over
the flood, % of one core) next to the same daemon idle, and the refusal counters that moved.

"Before" runs this file against the landed main (aa7ad0f: no receiver tags) from a separate
worktree: copy ``bench/spoof.py``, ``tests/attacker/spoof.py`` and ``tests/attacker/flood.py``
there and run with that worktree first on PYTHONPATH (the pool is sealed with the
``swarmd.auth.spdp.seal`` of the code under test). ``--write-docs`` rewrites the block
between the spoof markers in docs/benchmarks.md from ``spoof_before.json`` and
``spoof_after.json``. Needs root; traffic stays in namespaces this process creates.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd_lab.netns import Lan, run_prefix, unavailable_reason  # noqa: E402

from bench.docblock import head_commit, write_block  # noqa: E402
from tests.attacker.flood import run_flood  # noqa: E402
from tests.attacker.host import Attacker  # noqa: E402
from tests.attacker.spoof import Spoofer, spoof_pool  # noqa: E402
from tests.attacker.swarm import FlashedSwarm, delta, flashed_swarm, refusals  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / "docs" / "benchmarks.md"
RESULTS = REPO / "bench" / "results" / "security"
BEGIN = "<!-- spoof:begin (bench/spoof.py --write-docs) -->"
END = "<!-- spoof:end -->"
PER_STREAM = 200  # distinct forgeries per spoofed stream (7 streams)


def _one_rate(
    sw: FlashedSwarm, atk: Attacker, spoofer: Spoofer, rate: float, seconds: float, claim: str
) -> dict[str, Any]:
    sw.reset()  # a fresh, converged swarm on the ground for every rate
    before = [refusals(sw.status(i)) for i in range(sw.n)]
    pool = spoof_pool(sw, atk, PER_STREAM, seed=int(rate), claim=claim)
    takeoff: list[int] = []

    def operator() -> None:
        time.sleep(seconds / 2)
        done = sw.swarmctl(0, "takeoff", "--require-all", "--timeout", "10", "--alt", "5")
        takeoff.append(done.returncode)

    thread = threading.Thread(target=operator, name="operator")
    thread.start()
    try:
        result = run_flood(
            sw,
            atk,
            [],
            rate,
            seconds,
            send=lambda r, count, max_s: spoofer.paced(
                pool, rate_hz=r, max_count=count, max_s=max_s
            ),
        ).as_dict()
    finally:
        thread.join(timeout=60.0)
    result["takeoff_require_all_rc"] = takeoff[0] if takeoff else None
    result["refused"] = {
        sw.names[i]: {
            k.rsplit(".", 1)[1]: v
            for k, v in delta(refusals(sw.status(i)), before[i]).items()
            if ".auth_" in k
        }
        for i in range(sw.n)
    }
    return result


def run(label: str, rates: list[float], seconds: float, claim: str) -> dict[str, Any]:
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="spoof-", dir="/tmp") as tmp:
        lan = Lan(4, prefix=run_prefix("spfb")).__enter__()
        try:
            started: list[Attacker] = []

            def listen(sw: FlashedSwarm) -> None:
                started.append(Attacker(sw.attacker_ns, sw.spdp_group).start())

            with flashed_swarm(lan, Path(tmp), before_start=listen) as sw:
                atk = started[0]
                spoofer = Spoofer(sw.attacker_ns)
                try:
                    for rate in rates:
                        result = _one_rate(sw, atk, spoofer, rate, seconds, claim)
                        runs.append(result)
                        print(json.dumps(result), file=sys.stderr)
                finally:
                    spoofer.close()
                    atk.close()
        finally:
            lan.close()
    return {
        "label": label,
        "commit": head_commit(),
        "host": f"{platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}",
        "seconds": seconds,
        "claim": claim,
        "rates": [
            {
                "rate_hz": r["rate_hz"],
                "sent": r["sent"],
                "peers_lost": sum(len(v) for v in r["peers_lost"].values()),
                "lost_at_s": r["lost_at_s"],
                "takeoff_require_all_rc": r["takeoff_require_all_rc"],
                "cpu_percent_median": round(statistics.median(r["cpu_percent"].values()), 1),
                "cpu_percent_max": max(r["cpu_percent"].values()),
                "idle_cpu_percent_median": round(
                    statistics.median(r["idle_cpu_percent"].values()), 1
                ),
                "spdp_socket_drops_max": max(r["spdp_socket_drops"].values(), default=0),
            }
            for r in runs
        ],
        "runs": runs,
        "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }


def _load(name: str) -> dict[str, Any] | None:
    path = RESULTS / f"spoof_{name}.json"
    return json.loads(path.read_text()) if path.exists() else None


def _cells(r: dict[str, Any]) -> str:
    lost = r["peers_lost"]
    first = min((t for d in r["lost_at_s"].values() for t in d.values()), default=None)
    when = f" (first at {first:.1f} s)" if first is not None else ""
    return (
        f"{r['sent']:,} | {lost}{when} | {r['takeoff_require_all_rc']} | "
        f"{r['cpu_percent_median']} / {r['cpu_percent_max']} ({r['idle_cpu_percent_median']})"
    )


def docs_block() -> str:
    """The before/after tables from ``spoof_before.json``/``spoof_after.json`` (7 streams),
    ``spoof_before_commander.json``/``spoof_after_commander.json`` (the issue's attack) and
    ``spoof_after_20k.json`` (beyond, when present)."""
    before, after = _load("before"), _load("after")
    if before is None or after is None:
        raise SystemExit("spoof: run --label before and --label after first")
    head = (
        "| spoofed SPDP/s | code | sent | real peers lost (peer-drone pairs) | "
        "`takeoff --require-all` exit | daemon CPU, % of one core, median / max (idle) |"
    )
    lines = [
        BEGIN,
        f"`sudo .venv/bin/python bench/spoof.py --label L [--claim C] --rates R --seconds S`, "
        f"each rate from a freshly started swarm, the take-off half-way through the flood; "
        f"before = `{before['commit']}` (main before the receiver tags), after = "
        f"`{after['commit']}`; "
        f"{after['host']} (load is other jobs on the 2 shared cores).",
        "",
        f"Every drone's address in turn (7 streams, `--claim all`), {after['seconds']:.0f} s "
        "per rate:",
        "",
        head,
        "|---:|---|---:|---:|---:|---|",
    ]
    for b, a in zip(before["rates"], after["rates"], strict=True):
        lines.append(f"| {a['rate_hz']:,.0f} | before | {_cells(b)} |")
        lines.append(f"| {a['rate_hz']:,.0f} | after | {_cells(a)} |")
    cb, ca = _load("before_commander"), _load("after_commander")
    if cb is not None and ca is not None:
        lines += [
            "",
            f"The issue's attack: the whole rate on the commander's address (`--claim "
            f"commander`: to the group and to each member), {ca['seconds']:.0f} s:",
            "",
            head,
            "|---:|---|---:|---:|---:|---|",
        ]
        for b, a in zip(cb["rates"], ca["rates"], strict=True):
            lines.append(f"| {a['rate_hz']:,.0f} | before | {_cells(b)} |")
            lines.append(f"| {a['rate_hz']:,.0f} | after | {_cells(a)} |")
    beyond = _load("after_20k")
    if beyond is not None:
        lines += ["", f"Beyond the issue's rates, after only ({beyond['seconds']:.0f} s):", ""]
        lines += [head, "|---:|---|---:|---:|---:|---|"]
        for a in beyond["rates"]:
            drops = a["spdp_socket_drops_max"]
            lines.append(
                f"| {a['rate_hz']:,.0f} | after | {_cells(a)}; kernel drops on the SPDP "
                f"sockets, highest drone: {drops:,} |"
            )
    lines += [
        "",
        "Raw runs (per drone: peers lost and when, refusal counters, kernel drops): "
        "`bench/results/security/spoof_*.json`.",
        END,
    ]
    return "\n".join(lines)


def write_docs(block: str) -> None:
    write_block(DOCS, BEGIN, END, block)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--label", default="", help="before or after (names the output file)")
    p.add_argument("--rates", default="100,1000,5000", help="spoofed datagrams per second")
    p.add_argument("--seconds", type=float, default=30.0, help="flood duration per rate")
    p.add_argument("--out", default=None, help="default bench/results/security/spoof_LABEL.json")
    p.add_argument(
        "--claim",
        choices=("all", "commander"),
        default="all",
        help="spoof every drone's address (7 streams) or only the commander's (3: the issue's)",
    )
    p.add_argument("--write-docs", action="store_true", help="update docs/benchmarks.md")
    args = p.parse_args(argv)
    rates = [float(x) for x in args.rates.split(",") if x]
    if args.write_docs and not rates:  # --rates "" --write-docs: the tables from the files
        write_docs(docs_block())
        return 0
    if not args.label:
        print("spoof: --label is needed to run", file=sys.stderr)
        return 2
    reason = unavailable_reason()
    if reason is not None:
        print(f"spoof: {reason}", file=sys.stderr)
        return 2
    if not all(0 < r <= 20_000 for r in rates) or not 0 < args.seconds <= 60:
        print("spoof: --rates each 1..20000, --seconds 1..60", file=sys.stderr)
        return 2
    summary = run(args.label, rates, args.seconds, args.claim)
    out = Path(args.out) if args.out else RESULTS / f"spoof_{args.label}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}, indent=2))
    if args.write_docs:
        write_docs(docs_block())
    return 0


if __name__ == "__main__":
    sys.exit(main())
