"""Re-discovery after a heal and after a commander blackout when the drones cut off read a
poor link (issue 20; MemNet, virtual time), as tests/test_flight_rejoin.py runs them.

    .venv/bin/python bench/flight_rejoin.py [--n 10 20] [--seeds 1 2 3 4 5]

*split*: the second half is cut from the first from 30 s to 90 s and reads Q = 0.15 from the
cut until 3 s after the heal. *blackout*: the commander is cut from everyone from 30 s to
60 s and reads Q = 0 until 3 s after its return. Prints, per N and seed, the re-discovery
times of the crossing pairs from the return (p50, max) and the discovery frames by kind
(``counters()["tx_kind"]``, all engines) from the return to 25 s after it, per rejoining
(unordered) pair.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd_lab.testing import build_swarm  # noqa: E402

from swarmd.discovery import LinkSample, PeerDiscovered  # noqa: E402

Q_LAG_S = 3.0


def run(n: int, seed: int, apart: set[int], q_cut: float, t_cut: float, t_back: float) -> str:
    cut = {"now": False}
    swarm = build_swarm(n, seed=seed)
    swarm.net.link_loss = lambda a, b: 1.0 if cut["now"] and (a in apart) != (b in apart) else 0.0
    swarm.run_until(t_cut)

    def read(q: float, now: float) -> None:
        for i in sorted(apart):
            swarm.engines[i].update_link_quality(LinkSample(q=q, source="static"), now)
            swarm.net.poke(i)

    def go(now: float) -> None:
        cut["now"] = True
        read(q_cut, now)

    swarm.net.call_at(t_cut, go)
    swarm.net.call_at(t_back, lambda now: cut.update(now=False))
    swarm.net.call_at(t_back + Q_LAG_S, lambda now: read(1.0, now))
    swarm.run_until(t_back)
    at_return = swarm.tx_kinds()
    swarm.run_until(t_back + 25.0)
    first: dict[tuple[int, int], float] = {}
    for i, events in enumerate(swarm.events):
        for t, e in events:
            if t >= t_back and isinstance(e, PeerDiscovered):
                first.setdefault((i, swarm.index_of[e.name]), t - t_back)
    spent = swarm.tx_kinds() - at_return
    pairs = max(1, len(first) // 2)
    heal = {k: spent[k] for k in ("announce", "reply", "probe")}
    per_pair = sum(heal.values()) / pairs
    times = list(first.values()) or [float("nan")]
    return (
        f"p50 {statistics.median(times):.2f} s max {max(times):.2f} s, {pairs} pairs, "
        f"{heal} renewal {spent['renewal']}: {per_pair:.2f} per pair"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[10, 20])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args(argv)
    for n in args.n:
        for seed in args.seeds:
            away = set(range(n // 2, n))
            print(f"split    N={n} seed {seed}: {run(n, seed, away, 0.15, 30.0, 90.0)}")
            print(f"blackout N={n} seed {seed}: {run(n, seed, {0}, 0.0, 30.0, 60.0)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
