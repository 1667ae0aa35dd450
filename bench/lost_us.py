"""A peer that lost us while we kept it, on MemNet (issue 20; docs/discovery.md, "A peer that
lost us while we kept it"): the shapes of ``tests/test_discovery_lost_us.py``, measured.

    .venv/bin/python -m bench.lost_us [--seeds 3] [--q 0.05 0.5]

N = 20, virtual time, the clean channel; the last drone (the fader) hears nobody from 60 s
while everyone hears it, so it loses all 19 peers and they keep it:

* *deaf for 40 s*: it hears again at 100 s; prints the time from then to the last peer it
  found again (the test asserts at most 2.4 s);
* *deaf for good*: the 19 peers' discovery frames (every ``tx_kind``) per second, all of
  them together, from 120 s to 240 s, against the same seed with nobody deaf (the test
  asserts the peers' replies stay near one per ``LOST_US_GAP_MAX_S`` each).

Nothing asserted here (the tests assert the bounds).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from swarmd_lab.testing import Swarm, build_swarm

from swarmd.discovery.events import PeerDiscovered

N = 20
FADER = N - 1
T_CUT = 60.0
T_BACK = 100.0
COST_FROM = 120.0
COST_TO = 240.0


def _swarm(seed: int, q: float, deaf_until: float | None) -> Swarm:
    swarm = build_swarm(N, seed=seed, q=q)
    swarm.run_until(T_CUT)
    if deaf_until is not None:
        until = deaf_until

        def loss(src: int, dst: int) -> float:
            return 1.0 if dst == FADER and T_CUT <= swarm.net.now < until else 0.0

        swarm.net.link_loss = loss
    return swarm


def last_found_after_return(seed: int, q: float) -> float | None:
    """From the fader's return to the last of its peers found again (None: one never was)."""
    swarm = _swarm(seed, q, T_BACK)
    swarm.run_until(T_BACK + 30.0)
    first: dict[int, float] = {}
    for t, e in swarm.events[FADER]:
        if t >= T_BACK and isinstance(e, PeerDiscovered):
            first.setdefault(swarm.index_of[e.name], t - T_BACK)
    return max(first.values()) if len(first) == N - 1 else None


def peers_frames_per_s(seed: int, q: float, deaf: bool) -> float:
    """The 19 peers' discovery frames per second, together, from ``COST_FROM`` to ``COST_TO``."""
    swarm = _swarm(seed, q, float("inf") if deaf else None)

    def frames() -> int:
        return sum(sum(swarm.engines[i].counters()["tx_kind"].values()) for i in range(N - 1))

    swarm.run_until(COST_FROM)
    before = frames()
    swarm.run_until(COST_TO)
    return (frames() - before) / (COST_TO - COST_FROM)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lost_us", description=__doc__)
    parser.add_argument("--seeds", type=int, default=3, help="seeds 1..S (default 3)")
    parser.add_argument("--q", type=float, nargs="+", default=[0.05, 0.5])
    args = parser.parse_args(argv)
    for q in args.q:
        for seed in range(1, args.seeds + 1):
            found = last_found_after_return(seed, q)
            shown = "never" if found is None else f"{found:.2f} s"
            quiet = peers_frames_per_s(seed, q, deaf=False)
            deaf = peers_frames_per_s(seed, q, deaf=True)
            print(
                f"N = {N} Q = {q} seed {seed}: deaf 40 s, last peer found {shown} after the "
                f"return; the peers' frames/s, nobody deaf {quiet:.2f}, one deaf {deaf:.2f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
