"""A flight's geometry replayed on MemNet: how slow re-discoveries arise (issue 20;
docs/discovery.md, "A peer that lost us while we kept it"; docs/benchmarks.md, "The fly-out
at N = 20").

    .venv/bin/python -m bench.flight_fade_replay \
        bench/results/flight-lost-us/runs/flight-fade-swarmd-n20-r1.json --seeds 200
    .venv/bin/python -m bench.flight_fade_replay \
        bench/results/flight-stagger-1e20f9e/runs/flight-fly-out-swarmd-n20-r1.json --seeds 100 \
        --edge-db 1.5 --edge-loss 0.5

The scenario is the run file's (``--scenario`` only checks it): in the fade the observer is
the fading drone (the last), whose re-discoveries are the slow ones, or with
``--every-observer`` every drone's re-discoveries of it (the fader's peers: the slow pair of
the N = 20 fade's run 2, docs/flight-history.md, "The fade's slow return at N = 20 (session
11)"); in every other scenario (fly-out, split) every drone observes every peer.

The run file gives the scenario (its seed rebuilds the waypoints, ``bench/wifi/flight.py``)
and each drone's link quality Q (the median of its status polls). Every seed builds the swarm
on MemNet (``swarmd_lab.testing.build_swarm``, virtual time, engines started together) and
moves it through the same flight: a datagram from i reaches j while j receives i at
``flight.RANGE_DBM`` or more (the truth's definition of in range: the channel's
log-distance loss, evaluated every 0.25 s), and is lost otherwise. No collisions, no 802.11
rates, no ARP: what remains is the engines' own schedule. ``--edge-db D --edge-loss P``
adds the one channel effect the fly-out's slow pairs point at: a frame received less than
D dB above the threshold is lost with probability P if multicast (802.11 sends a group frame
once, unacknowledged) and P ** 4 if directed (MAC-acknowledged and retried; 4 is a rough
stand-in for the retries that fit in a frame's time, not a measured figure).
``--seekers-max K`` sets ``seek.SEEK_PUT_OFF_SEEKERS_MAX`` for this process (1000: the
seek's put-off bound kept by every drone, as before branch h-seek-scale).

For every peer an observer lost and found again: the time from the pair's return (both
ways in range) to the re-discovery, by the clock, and (a line of its own) by the time in
range only (``Replay.in_range_s``, the flight measure since session 11). Each one slower
than 2 s by the clock is classed by what happened in the pair's first window (``_classify``;
"the fader" is the observer):

- ``lease-in-window``: the fader's lease of the peer ended inside the window (the peer, a
  vouched member, sends nothing unasked, and the fader's frames listed it until then), and
  no frame of the fader omitting it crossed before the window closed;
- ``answer-late``: such a frame (the lost_us rule's cue) crossed, and the peer's answer left
  after the window closed;
- ``answer-lost`` (only with ``--edge-loss``): the peer's answer (directed to the fader, or
  a multicast) left inside the window and none reached the fader;
- ``no-answer``: a cue crossed and the peer sent no answer within 1 s of the window's end
  (its spacing);
- ``no-cue``: the fader had lost the peer before the window and sent nothing across in it.

The report also counts the observers' PeerLost events (found again or not): per seed, in
bursts of 5 or more at one instant (a vouched lease's end: every member the commander's last
vouch listed is lost together), and how many were found again within 2 s (docs/flight-history.md,
"The fading drone's losses at N = 20 (session 9)").

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
from swarmd.discovery import seek
from swarmd.discovery.events import PeerDiscovered, PeerLost
from swarmd.discovery.inputs import LinkSample

STEP_S = 0.25  # the geometry's resolution (the waypoints move every flight.STEP_S = 0.5 s)
SLOW_S = 2.0  # issue 20's target


class Replay:
    """One run file's geometry and link qualities, replayed per seed."""

    def __init__(
        self,
        run: dict[str, Any],
        edge_db: float = 0.0,
        edge_loss: float = 0.0,
        every_observer: bool = False,
    ) -> None:
        self.scenario = flight.of_run(run)
        self.n: int = run["n"]
        self.fader = self.n - 1
        # who re-discovers: the fading drone in the fade (or, ``every_observer``, every
        # drone: the fader's peers re-discovering it), every drone otherwise
        fader_only = run["scenario"] == "fade" and not every_observer
        self.observers = [self.fader] if fader_only else list(range(self.n))
        self.edge_db, self.edge_loss = edge_db, edge_loss
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

    def loss(self, src: int, dst: int, t: float, multicast: bool) -> float:
        """The chance a frame from ``src`` at ``t`` is lost at ``dst`` (the module docstring)."""
        margin = self.rx_at(int(t / STEP_S))[src][dst] - flight.RANGE_DBM
        if margin < 0.0:
            return 1.0
        if margin >= self.edge_db:
            return 0.0
        return self.edge_loss if multicast else self.edge_loss**4

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
        # MemNet appends the transmission before it asks each receiver's loss
        net.link_loss = lambda src, dst: self.loss(
            src, dst, net.now, net.transmissions[-1].multicast
        )
        swarm.run_until(until)
        return swarm

    def in_range_s(self, i: int, j: int, start: float, t: float) -> float:
        """Seconds the pair (``i``, ``j``) was both ways in range from ``start`` to ``t``
        (the flight measure's re-discovery latency since session 11: a window that closed
        first adds its length, the seconds out of range after it do not)."""
        if t <= start:
            return 0.0
        first, last = int(start / STEP_S), int(t / STEP_S)
        whole = sum(
            1
            for step in range(first, last)
            if self.crosses(i, j, step * STEP_S) and self.crosses(j, i, step * STEP_S)
        )
        tail = t - last * STEP_S if self.crosses(i, j, t) and self.crosses(j, i, t) else 0.0
        return whole * STEP_S + tail

    def window(self, j: int, after: float, observer: int | None = None) -> tuple[float, float]:
        """The pair's (``observer``, default the fader, and ``j``) first time both ways in
        range at or after ``after``: (start, length)."""
        i = self.fader if observer is None else observer

        def both(step: int) -> bool:
            t = step * STEP_S
            return self.crosses(i, j, t) and self.crosses(j, i, t)

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


Found = tuple[float, int, int, float, float, float]  # latency, observer, peer, back, length, lost


DISCOVERY_KINDS = ("announce", "reply", "probe", "seek")  # not the renewals


Lost = tuple[float, int, int]  # t, observer, peer: one PeerLost


def rediscoveries(
    replay: Replay,
    seed: int,
    frames: Counter[str] | None = None,
    losses: list[Lost] | None = None,
) -> list[Found]:
    """(latency, observer, peer, return, window length, lost at) of each re-discovery;
    ``frames`` (if given) adds the run's discovery frames by kind, every drone's; ``losses``
    (if given) gets each observer's PeerLost events, found again or not."""
    swarm = replay.swarm(seed, replay.scenario.duration_s)
    if losses is not None:
        losses += [
            (t, i, swarm.index_of[e.name])
            for i in replay.observers
            for t, e in swarm.events[i]
            if isinstance(e, PeerLost)
        ]
    if frames is not None:
        for engine in swarm.engines:
            kinds = engine.counters()["tx_kind"]
            frames.update({k: kinds[k] for k in DISCOVERY_KINDS if kinds.get(k)})
    out: list[Found] = []
    for i in replay.observers:
        for j in range(replay.n):
            if j == i:
                continue
            changes = _changes(swarm, i, j)
            for (lost_at, found0), (found_at, found1) in zip(changes, changes[1:], strict=False):
                if not found0 and found1:
                    back, length = replay.window(j, lost_at, i)
                    out.append((found_at - back, i, j, back, length, lost_at))
    return out


def _classify(replay: Replay, seed: int, f: int, j: int, back: float, length: float) -> str:
    swarm = replay.swarm(seed, back + length + 1.0)
    end = back + length
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
        if x.node == j
        and (x.target[0] == fader_at or (x.multicast and replay.edge_loss > 0.0))
        and cues[0] <= x.time < end + 1.0
    ]
    if not answers:
        return "no-answer"
    # with edge loss an answer can leave in time and still not cross (without it, one
    # that left inside the window would have been heard)
    return "answer-lost" if replay.edge_loss > 0.0 and answers[0] < end else "answer-late"


BURST = 5  # this many losses by one observer at one instant: a vouched lease's end


def losses_line(losses: dict[int, list[Lost]], rows: Sequence[tuple[Any, ...]]) -> str:
    """The observers' PeerLost events per seed (``losses``: seed -> its losses; ``rows``:
    (seed, latency, ...) of the re-discoveries), and how many were found again within 2 s."""
    per_seed = sorted(len(v) for v in losses.values())
    total = sum(per_seed)
    bursts, largest = 0, 0
    for seed_losses in losses.values():
        at_once = Counter((round(t, 6), i) for t, i, _ in seed_losses)
        bursts += sum(1 for k in at_once.values() if k >= BURST)
        largest = max([largest, *at_once.values()])
    fast = sum(1 for r in rows if r[1] <= SLOW_S)
    return (
        f"  PeerLost by the observers: {total} in {len(per_seed)} seeds (per seed min "
        f"{per_seed[0]}, p50 {per_seed[len(per_seed) // 2]}, max {per_seed[-1]}; at most 1 in "
        f"{sum(1 for k in per_seed if k <= 1)}); {bursts} bursts of {BURST}+ at one instant "
        f"(largest {largest}); "
        f"re-discovered within {SLOW_S:g} s: {fast}"
    )


def run_losses_line(run: dict[str, Any], observers: Sequence[int]) -> str:
    """The run file's own losses by ``observers`` (its ``changes``: per observer [t, peer,
    kind]), to set beside the replay's."""
    lost = [
        (round(float(t), 3), i)
        for i in observers
        for t, _, kind in run["changes"].get(str(i), [])
        if kind == "lost"
    ]
    at_once = Counter(lost)
    bursts = sorted(((k, t) for (t, _), k in at_once.items() if k >= BURST), key=lambda b: b[1])
    said = ", ".join(f"{k} at {t:g} s" for k, t in bursts) or "none"
    return f"  the run itself: PeerLost by the observers {len(lost)}; bursts of {BURST}+: {said}"


def in_range_line(replay: Replay, rows: Sequence[tuple[Any, ...]]) -> str:
    """The re-discoveries (``rows``: (seed, latency, observer, peer, back, length, lost))
    by the time in range from the return (``Replay.in_range_s``), and how many came after
    the return's first window had closed."""
    in_range = sorted(replay.in_range_s(i, j, back, back + lat) for _, lat, i, j, back, *_ in rows)
    closed = sum(1 for _, lat, _, _, _, length, _ in rows if lat > length + STEP_S)
    top = f"{in_range[-1]:.2f} s" if in_range else "-"
    return (
        f"  by the time in range from the return: {sum(1 for x in in_range if x > SLOW_S)} "
        f"over {SLOW_S:g} s, max {top}; found after the first window closed: {closed}"
    )


def report(
    path: Path,
    seeds: int,
    edge_db: float = 0.0,
    edge_loss: float = 0.0,
    every_observer: bool = False,
) -> str:
    run = json.loads(path.read_text())
    replay = Replay(run, edge_db, edge_loss, every_observer)
    frames: Counter[str] = Counter()
    losses: dict[int, list[Lost]] = {seed: [] for seed in range(1, seeds + 1)}
    rows = [
        (seed, *r)
        for seed in range(1, seeds + 1)
        for r in rediscoveries(replay, seed, frames, losses[seed])
    ]
    fade = run["scenario"] == "fade"
    if fade and replay.observers != [replay.fader]:  # the fader's peers re-discovering it
        rows = [r for r in rows if r[3] == replay.fader]
        losses = {seed: [x for x in v if x[2] == replay.fader] for seed, v in losses.items()}
    slow = sorted((r for r in rows if r[1] > SLOW_S), key=lambda r: -r[1])
    latencies = sorted(r[1] for r in rows)
    kinds = Counter(
        _classify(replay, s, i, j, back, length) for s, _, i, j, back, length, _ in slow
    )
    if replay.observers == [replay.fader]:
        who = f"uav{replay.n}"
    else:
        who = f"every drone of uav{replay.n}" if fade else "every drone"
    spread = (
        f"p50 {latencies[len(latencies) // 2]:.2f} s, max {latencies[-1]:.2f} s"
        if latencies
        else "p50 -, max -"
    )
    edge = f" (edge loss {edge_loss:g} within {edge_db:g} dB)" if edge_loss else ""
    out = [
        f"{path.name}, {seeds} seeds on MemNet{edge}: {len(rows)} re-discoveries by {who}, "
        f"{len(slow)} over {SLOW_S:g} s; " + spread,
        "  slow, by what happened in the pair's first window: "
        + ", ".join(f"{k} {v}" for k, v in kinds.most_common()),
        in_range_line(replay, rows),
        losses_line(losses, rows),
        run_losses_line(run, replay.observers),
    ]
    if who == "every drone":  # each pair's re-discovery is counted from both ends
        pairs = len(rows) / 2
        per_pair = ", ".join(f"{k} {frames[k] / pairs:.2f}" for k in DISCOVERY_KINDS)
        out.append(
            f"  discovery frames per rejoining pair (the whole run, formation included): "
            f"{sum(frames.values()) / pairs:.2f} ({per_pair})"
        )
    out += [
        f"  {lat:.2f} s: seed {s}, uav{i + 1} of uav{j + 1} back {back:.2f} s for {length:.2f} s"
        for s, lat, i, j, back, length, _ in slow[:5]
    ]
    return "\n".join(out)


def add_replay_args(parser: argparse.ArgumentParser) -> None:
    """The arguments every replay tool takes: the run file and the seeds (bench.edge_trace
    too)."""
    parser.add_argument("run", type=Path, help="a flight run file (*.json)")
    parser.add_argument("--seeds", type=int, default=20, help="MemNet seeds 1..S (default 20)")


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.flight_fade_replay",
        description="Replay a flight run's geometry on MemNet and class the re-discoveries "
        "slower than 2 s (the fading drone's in a fade, every drone's otherwise).",
    )
    add_replay_args(parser)
    parser.add_argument(
        "--scenario",
        choices=sorted(flight.SCENARIOS),
        help="the run file's scenario, checked (default: whatever the run file is)",
    )
    parser.add_argument(
        "--edge-db", type=float, default=0.0, help="the edge's width above -82 dBm (dB)"
    )
    parser.add_argument(
        "--edge-loss", type=float, default=0.0, help="a multicast's loss at the edge (0-1)"
    )
    parser.add_argument(
        "--every-observer",
        action="store_true",
        help="in a fade, every drone observes (the fader's peers re-discovering it too), "
        "not the fader alone",
    )
    parser.add_argument(
        "--seekers-max",
        type=int,
        help="override seek.SEEK_PUT_OFF_SEEKERS_MAX (1000: the put-off bound kept by every "
        "drone, as before branch h-seek-scale)",
    )
    args = parser.parse_args(argv)
    if args.seekers_max is not None:
        # Seek._few_seekers reads the module global on each call
        seek.SEEK_PUT_OFF_SEEKERS_MAX = args.seekers_max  # type: ignore[misc]
    if not args.run.is_file():
        print(f"{args.run}: no such run file", file=sys.stderr)
        return 66  # EX_NOINPUT
    scenario = json.loads(args.run.read_text()).get("scenario")
    if args.scenario is not None and scenario != args.scenario:
        print(f"{args.run}: a {scenario} run, not {args.scenario}", file=sys.stderr)
        return 65  # EX_DATAERR
    if not 0.0 <= args.edge_loss <= 1.0 or args.edge_db < 0.0:
        print("--edge-loss: use 0..1; --edge-db: use >= 0", file=sys.stderr)
        return 64  # EX_USAGE
    print(report(args.run, args.seeds, args.edge_db, args.edge_loss, args.every_observer))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
