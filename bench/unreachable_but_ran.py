"""How often the commander calls a drone ``unreachable`` that ran the command.

    .venv/bin/python bench/unreachable_but_ran.py [--loss 0.6] [--seeds 100] [--kind takeoff]

The virtual-time swarm of ``tests/test_swarm_core.py`` (``Swarm``: a commander and 10
members on ``MemNet``, every user datagram lost with probability ``--loss`` each way): one
command per seed, followed until the commander's snapshot is ``done`` (every row answered
or ``unreachable`` at validity + 2 s), then 20 s more. Counts the rows that were
``unreachable`` at ``done`` and, of those, the drones that ran the command all the same
(their answers were lost and repaired after the verdict). A reading, not a test: nothing
asserted (docs/operations.md, "What swarmctl tells you about a command").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.swarm.commander import UNREACHABLE  # noqa: E402
from tests.test_swarm_core import Swarm  # noqa: E402

MEMBERS = 10
FOLLOW_S = 30.0  # longer than any validity + grace; a bound on the loop
AFTER_S = 20.0  # for the late answers to arrive


def one(loss: float, seed: int, kind: str) -> tuple[int, int, int]:
    """(rows unreachable at done, of those ran, rows that ran) for one command."""
    swarm = Swarm(MEMBERS, loss=loss, seed=seed)
    swarm.run(3.0)
    if kind == "takeoff":
        sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    else:
        sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": kind}, now))
    if not sent["sent"]:
        return 0, 0, 0
    cid = int(sent["command_id"])
    end = swarm.net.now + FOLLOW_S
    states: dict[str, str] = {}
    while swarm.net.now < end and not states:
        swarm.run(0.1)
        snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
        if snap["done"]:
            states = {n: r["state"] for n, r in snap["nodes"].items()}
    swarm.run(AFTER_S)
    unreachable = [n for n, s in states.items() if s == UNREACHABLE]
    ran = [n for n in swarm.members if swarm.requests(n)]
    return len(unreachable), len(set(unreachable) & set(ran)), len(ran)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loss", type=float, default=0.6)
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--kind", default="takeoff", choices=["takeoff", "land", "hold", "abort"])
    args = parser.parse_args()
    totals = [0, 0, 0]
    for seed in range(args.seeds):
        for i, count in enumerate(one(args.loss, seed, args.kind)):
            totals[i] += count
    print(
        f"loss {args.loss:g}, {args.kind}, {args.seeds} commands to {MEMBERS} members: "
        f"{totals[0]} rows unreachable when the command was done, {totals[1]} of them ran it; "
        f"{totals[2]} rows ran it in all"
    )


if __name__ == "__main__":
    main()
