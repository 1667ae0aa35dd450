"""What a peer gone for good costs the others in seeks (issue 20; docs/discovery.md, "A seek put
off by a frame that cannot reach").

    .venv/bin/python -m bench.seek_cost [--seeds 5] [--n 10] [--unbounded] [--case gone|commander]

Two cases on MemNet, virtual time, the clean channel:

* *a member gone*: the last drone's links to every other drone cut at 30 s for good (the case
  of ``tests/test_discovery_seek.py::test_a_peer_that_never_returns_is_sought_for_the_bound_
  then_only_renewed``); the others' seeks from 30 s to ``SEEK_FOR_S`` + ``SEEK_MAX_S`` after
  the last frame heard across;
* *a dead commander*: uav0 isolated at 40 s (as in ``tests/test_discovery_vouch.py``), the
  members' seeks from 40 s on, per minute, up to ``SEEK_FOR_S`` past its death.

Prints, per seed, the seeks sent by all the others, and for the commander the seeks per minute;
nothing asserted (the tests assert the bounds). ``--unbounded`` runs the engine with the seek's
put-off bound off (``seek.SEEK_PUT_OFF_FOR_S`` set to 0 for this process: every loss is stale,
the suppression is whole), the baseline the bound's cost is judged against.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from swarmd_lab.testing import Swarm, build_swarm

from swarmd.discovery import seek
from swarmd.discovery.seek import SEEK_FOR_S, SEEK_MAX_S

T_CUT = 30.0
T_DIE = 40.0


def _seeks(swarm: Swarm, nodes: range) -> int:
    return sum(swarm.engines[i].counters()["tx_kind"]["seek"] for i in nodes)


def member_gone(n: int, seed: int) -> int:
    """The seeks the n - 1 others send for the last drone, gone at ``T_CUT``."""
    swarm = build_swarm(n, seed=seed)
    gone = n - 1

    def loss(a: int, b: int) -> float:
        return 1.0 if gone in (a, b) and a != b and swarm.net.now >= T_CUT else 0.0

    swarm.net.link_loss = loss
    swarm.run_until(T_CUT)
    swarm.run_until(T_CUT + SEEK_FOR_S + SEEK_MAX_S)
    return _seeks(swarm, range(n - 1))


def dead_commander(n: int, seed: int) -> list[int]:
    """The members' seeks in each minute from ``T_DIE`` on, the commander (uav0) dead."""
    swarm = build_swarm(n, seed=seed)
    swarm.run_until(T_DIE)
    swarm.net.isolate(0)
    per_minute: list[int] = []
    before = _seeks(swarm, range(1, n))
    minute = 0
    while minute * 60.0 < SEEK_FOR_S + 60.0:
        minute += 1
        swarm.run_until(T_DIE + minute * 60.0)
        now = _seeks(swarm, range(1, n))
        per_minute.append(now - before)
        before = now
    return per_minute


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.seek_cost", description=__doc__)
    parser.add_argument("--seeds", type=int, default=5, help="seeds 1..S (default 5)")
    parser.add_argument("--n", type=int, default=10, help="drones (default 10)")
    parser.add_argument(
        "--unbounded", action="store_true", help="the put-off bound off (the baseline)"
    )
    parser.add_argument(
        "--case", choices=("both", "gone", "commander"), default="both", help="default both"
    )
    args = parser.parse_args(argv)
    if args.unbounded:
        # Seek.heard reads the module global on each call: 0 makes every loss stale
        seek.SEEK_PUT_OFF_FOR_S = 0.0  # type: ignore[misc]
    label = "unbounded" if args.unbounded else "engine"
    for seed in range(1, args.seeds + 1):
        parts = [f"N = {args.n} seed {seed} ({label}):"]
        if args.case in ("both", "gone"):
            parts.append(f"member gone for good: {member_gone(args.n, seed)} seeks by the others;")
        if args.case in ("both", "commander"):
            minutes = dead_commander(args.n, seed)
            parts.append(
                f"dead commander: {sum(minutes)} seeks by the members, per minute {minutes}"
            )
        print(" ".join(parts), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
