"""The fade's geometry replayed on MemNet: how the fading drone's slow re-discoveries arise
(issue 20; docs/discovery.md, "A peer that lost us while we kept it").

    .venv/bin/python -m bench.flight_fade_replay \
        bench/results/flight-lost-us/runs/flight-fade-swarmd-n20-r1.json --seeds 200

The run file gives the scenario (its seed rebuilds the waypoints, ``bench/wifi/flight.py``)
and each drone's link quality Q (the median of its status polls). Every seed builds the swarm
on MemNet (``swarmd_lab.testing.build_swarm``, virtual time, engines started together) and
moves it through the same flight: a datagram from i reaches j while j receives i at
``flight.RANGE_DBM`` or more (the truth's definition of in range: the channel's
log-distance loss, evaluated every 0.25 s), and is lost otherwise. No collisions, no 802.11
rates, no ARP: what remains is the engines' own schedule.

For every peer the fading drone lost and found again: the time from the pair's return (both
ways in range) to the re-discovery. Each one slower than 2 s is classed by what happened in
the pair's first window (``_classify``):

- ``lease-in-window``: the fader's lease of the peer ended inside the window (the peer, a
  vouched member, sends nothing unasked, and the fader's frames listed it until then), and
  no frame of the fader omitting it crossed before the window closed;
- ``answer-late``: such a frame (the lost_us rule's cue) crossed, and the peer's answer left
  after the window closed;
- ``no-answer``: a cue crossed and the peer sent no answer within 1 s of the window's end
  (its spacing);
- ``no-cue``: the fader had lost the peer before the window and sent nothing across in it.

Nothing asserted: a reading (``tests/test_discovery_lost_us.py`` holds the rule's shapes).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
from collections import Counter
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

from swarmd_lab.testing import Swarm, build_swarm, node_ipv4

from bench.wifi import flight
from swarmd.discovery.events import PeerDiscovered, PeerLost
from swarmd.discovery.inputs import LinkSample

STEP_S = 0.25  # the geometry's resolution (the waypoints move every flight.STEP_S = 0.5 s)
SLOW_S = 2.0  # issue 20's target


class Replay:
    """One run file's geometry and link qualities, replayed per seed."""

    def __init__(self, run: dict[str, Any]) -> None:
        self.scenario = flight.of_run(run)
        self.n: int = run["n"]
        self.fader = self.n - 1
        polls: dict[int, list[float]] = {}
        for poll in run["renewals"]:  # (t, node, renewals, Q, ...)
            if poll[3] is not None:
                polls.setdefault(poll[1], []).append(poll[3])
        self.q = [statistics.median(polls.get(i, [0.5])) for i in range(self.n)]
        self.last_step = int(self.scenario.duration_s / STEP_S)
        self.rx_at = lru_cache(maxsize=4096)(self._rx_at)

    def _rx_at(self, step: int) -> tuple[tuple[float, ...], ...]:
        where = self.scenario.positions_at(step * STEP_S)
        return tuple(
            tuple(flight.rx_dbm(math.dist(where[i], where[j])) for j in range(self.n))
            for i in range(self.n)
        )

    def crosses(self, src: int, dst: int, t: float) -> bool:
        return self.rx_at(int(t / STEP_S))[src][dst] >= flight.RANGE_DBM

    def swarm(self, seed: int, until: float) -> Swarm:
        swarm = build_swarm(self.n, seed=seed, q=0.5)

        def read_q(i: int) -> None:
            def at(now: float) -> None:
                swarm.engines[i].update_link_quality(LinkSample(q=self.q[i]), now)
                swarm.net.poke(i)

            swarm.net.call_at(0.2, at)

        for i in range(self.n):
            read_q(i)
        net = swarm.net
        net.link_loss = lambda src, dst: 0.0 if self.crosses(src, dst, net.now) else 1.0
        swarm.run_until(until)
        return swarm

    def window(self, j: int, after: float) -> tuple[float, float]:
        """The pair's first time both ways in range at or after ``after``: (start, length)."""

        def both(step: int) -> bool:
            t = step * STEP_S
            return self.crosses(self.fader, j, t) and self.crosses(j, self.fader, t)

        s = int(after / STEP_S)
        while s < self.last_step and not both(s):
            s += 1
        e = s
        while e < self.last_step and both(e):
            e += 1
        return s * STEP_S, (e - s) * STEP_S


def _changes(swarm: Swarm, observer: int, peer: int) -> list[tuple[float, bool]]:
    """(t, found) of ``observer``'s PeerDiscovered (True) and PeerLost (False) of ``peer``."""
    return [
        (t, isinstance(e, PeerDiscovered))
        for t, e in swarm.events[observer]
        if isinstance(e, PeerDiscovered | PeerLost) and swarm.index_of[e.name] == peer
    ]


def rediscoveries(replay: Replay, seed: int) -> list[tuple[float, int, float, float, float]]:
    """(latency, peer, return, window length, lost at) of each re-discovery by the fader."""
    swarm = replay.swarm(seed, replay.scenario.duration_s)
    out: list[tuple[float, int, float, float, float]] = []
    for j in range(replay.n - 1):
        changes = _changes(swarm, replay.fader, j)
        for (lost_at, found0), (found_at, found1) in zip(changes, changes[1:], strict=False):
            if not found0 and found1:
                back, length = replay.window(j, lost_at)
                out.append((found_at - back, j, back, length, lost_at))
    return out


def _classify(replay: Replay, seed: int, j: int, back: float, length: float) -> str:
    swarm = replay.swarm(seed, back + length + 1.0)
    end, f = back + length, replay.fader
    lost_at = max(t for t, found in _changes(swarm, f, j) if not found and t <= end + 1.0)
    if lost_at >= back:
        return "lease-in-window"
    sent = swarm.net.transmissions
    cues = [x.time for x in sent if x.node == f and x.multicast and back <= x.time < end]
    if not cues:
        return "no-cue"
    fader_at = node_ipv4(f)
    answers = [
        x.time
        for x in sent
        if x.node == j and x.target[0] == fader_at and cues[0] <= x.time < end + 1.0
    ]
    return "answer-late" if answers else "no-answer"


def report(path: Path, seeds: int) -> str:
    replay = Replay(json.loads(path.read_text()))
    rows = [(seed, *r) for seed in range(1, seeds + 1) for r in rediscoveries(replay, seed)]
    slow = sorted((r for r in rows if r[1] > SLOW_S), key=lambda r: -r[1])
    latencies = sorted(r[1] for r in rows)
    kinds = Counter(_classify(replay, s, j, back, length) for s, _, j, back, length, _ in slow)
    out = [
        f"{path.name}, {seeds} seeds on MemNet: {len(rows)} re-discoveries by uav{replay.n}, "
        f"{len(slow)} over {SLOW_S:g} s; p50 {latencies[len(latencies) // 2]:.2f} s, "
        f"max {latencies[-1]:.2f} s",
        "  slow, by what happened in the pair's first window: "
        + ", ".join(f"{k} {v}" for k, v in kinds.most_common()),
    ]
    out += [
        f"  {lat:.2f} s: seed {s}, uav{j + 1} back {back:.2f} s for {length:.2f} s"
        for s, lat, j, back, length, _ in slow[:5]
    ]
    return "\n".join(out)


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.flight_fade_replay",
        description="Replay a flight fade run's geometry on MemNet and class the fading "
        "drone's re-discoveries slower than 2 s.",
    )
    parser.add_argument("run", type=Path, help="a flight fade run file (*.json)")
    parser.add_argument("--seeds", type=int, default=20, help="MemNet seeds 1..S (default 20)")
    args = parser.parse_args(argv)
    if not args.run.is_file():
        print(f"{args.run}: no such run file", file=sys.stderr)
        return 66  # EX_NOINPUT
    print(report(args.run, args.seeds))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
