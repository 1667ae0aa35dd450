"""How the seek's put-off bound finds an edge pair whose sides seek out of its range, by the
size of a side (issue 20; docs/discovery.md, "The put-off bound at scale").

    .venv/bin/python -m bench.seek_sides [--sides 6 8 9 10] [--seeds 8] [--seekers-max K]

The shape of ``tests/test_discovery_seek_reach.py`` (MemNet, virtual time, clean channel): two
sides of S drones formed together, cut apart at 30 s, and at 60 s only the edge pair (uav S-1
and uav S) back in range. Every other drone of a side still seeks the whole other side out of
range, so each edge drone hears S - 1 seekers of its own side whose frames cannot reach. Per
side size it prints, over seeds 1..``--seeds``, when each seed's edge pair had found each other
again after the return.

``--seekers-max K`` sets ``seek.SEEK_PUT_OFF_SEEKERS_MAX`` for this process (the engine's, 8,
by default): a large K (e.g. 1000) is the bound kept by every drone, as before the cap (branch
h-seek-reach); 5 is the cap first tried. Nothing asserted (the test asserts the cap's side).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from swarmd_lab.testing import build_swarm

from swarmd.discovery import seek
from swarmd.discovery.events import PeerDiscovered

T_CUT = 30.0
T_BACK = 60.0


def edge_pair_found_s(side: int, seed: int) -> float:
    """From ``T_BACK`` until both edge drones have found each other again (inf: not within
    10 s)."""
    swarm = build_swarm(2 * side, seed=seed)
    edge_pair = {side - 1, side}

    def loss(a: int, b: int) -> float:
        if (a < side) == (b < side) or swarm.net.now < T_CUT:
            return 0.0
        return 0.0 if swarm.net.now >= T_BACK and {a, b} == edge_pair else 1.0

    swarm.net.link_loss = loss
    swarm.run_until(T_BACK + 10.0)

    def found(observer: int, peer: int) -> float:
        name = swarm.bundle.participants[peer].name
        times = [
            t - T_BACK
            for t, e in swarm.events[observer]
            if t >= T_BACK and isinstance(e, PeerDiscovered) and e.name == name
        ]
        return times[0] if times else float("inf")

    return max(found(side - 1, side), found(side, side - 1))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.seek_sides", description=__doc__)
    parser.add_argument("--sides", type=int, nargs="+", default=[6, 8, 9, 10])
    parser.add_argument("--seeds", type=int, default=8, help="seeds 1..S (default 8)")
    parser.add_argument("--seekers-max", type=int, help="override SEEK_PUT_OFF_SEEKERS_MAX")
    parser.add_argument("--rank-max", type=int, help="override SEEK_PUT_OFF_RANK_MAX")
    args = parser.parse_args(argv)
    if args.rank_max is not None:
        # Seek._ranked_first reads the module global on each call (0: the rank keeps none)
        seek.SEEK_PUT_OFF_RANK_MAX = args.rank_max  # type: ignore[misc]
    if args.seekers_max is not None:
        # Seek._few_seekers reads the module global on each call
        seek.SEEK_PUT_OFF_SEEKERS_MAX = args.seekers_max  # type: ignore[misc]
    for side in args.sides:
        found = [edge_pair_found_s(side, seed) for seed in range(1, args.seeds + 1)]
        slow = sum(f > 2.0 for f in found)
        print(
            f"side {side} (seekers max {seek.SEEK_PUT_OFF_SEEKERS_MAX}, rank max "
            f"{seek.SEEK_PUT_OFF_RANK_MAX}): edge pair found again "
            f"after max {max(found):.2f} s, over 2 s in {slow} of {len(found)} seeds: "
            f"{[round(f, 2) for f in found]}",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
