"""Discovery frames by kind in issue 20's fade and split-and-heal scenarios (MemNet, virtual
time), as tests/test_flight_scenarios.py runs them: what the last-chance probes cost.

    .venv/bin/python bench/flight_frames.py [--seeds 1 2 3 4 5]

*fade*: from 30 s, drone 9 of 10 is out of range 3 s in every 6 for 120 s (its link monitor
reads Q = 0 out, 0.4 in); counted to 180 s. *split*: drones 0-4 and 5-9 out of each other's
range from 30 s to 90 s; counted at the heal and 30 s after it. Prints, per seed, the
``counters()["tx_kind"]`` summed over the engines and the PeerLost events.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd_lab.testing import Swarm, build_swarm  # noqa: E402

from swarmd.discovery import LinkSample, PeerLost  # noqa: E402

N = 10


def losses(swarm: Swarm, since: float) -> int:
    return sum(
        1 for events in swarm.events for t, e in events if t >= since and isinstance(e, PeerLost)
    )


def fade(seed: int) -> str:
    out = {"now": False}
    edge = N - 1
    swarm = build_swarm(N, seed=seed)
    swarm.net.link_loss = lambda a, b: 1.0 if out["now"] and edge in (a, b) else 0.0
    swarm.run_until(30.0)
    before = swarm.tx_kinds()

    def swing(now: float) -> None:
        out["now"] = not out["now"]
        swarm.engines[edge].update_link_quality(LinkSample(q=0.0 if out["now"] else 0.4), now)
        swarm.net.poke(edge)
        if now + 3.0 < 150.0:
            swarm.net.call_at(now + 3.0, swing)

    swarm.net.call_at(30.0, swing)
    swarm.run_until(180.0)
    delta = swarm.tx_kinds() - before
    return f"fade  seed {seed}: 30-180 s {dict(delta)}, PeerLost {losses(swarm, 30.0)}"


def split(seed: int) -> str:
    apart = {"now": False}
    west = set(range(N // 2))
    swarm = build_swarm(N, seed=seed)
    swarm.net.link_loss = lambda a, b: 1.0 if apart["now"] and (a in west) != (b in west) else 0.0
    swarm.run_until(30.0)
    start = swarm.tx_kinds()
    swarm.net.call_at(30.0, lambda now: apart.update(now=True))
    swarm.net.call_at(90.0, lambda now: apart.update(now=False))
    swarm.run_until(90.0)
    at_heal = swarm.tx_kinds()
    swarm.run_until(120.0)
    return (
        f"split seed {seed}: 30-90 s {dict(at_heal - start)}, "
        f"90-120 s {dict(swarm.tx_kinds() - at_heal)}, PeerLost {losses(swarm, 30.0)}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    for seed in args.seeds:
        print(fade(seed))
        print(split(seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
