"""Where the time goes in a slow return at the edge of range (issue 20; docs/benchmarks.md,
"Where it stands (session 13)": the two runs that missed 2 s).

    .venv/bin/python -m bench.edge_trace \
        bench/results/flight-stagger/runs/flight-split-swarmd-n20-r3.json \
        --seeds 200 --edge-db 1.5 --edge-loss 0.5

Replays the run's geometry on MemNet as ``bench.flight_fade_replay`` does (same seeds, same
edge loss; in a fade, every drone's re-discoveries of the fader) and, for each re-discovery
slower than 2 s from the pair's return, lists every discovery frame either drone of the pair
sent from the return to the re-discovery: its kind (``Sender.send``'s tx kind: seek,
announce, reply, probe, renewal), directed or multicast, and whether it reached the other
drone of the pair (crossed), was lost at the edge, or was out of range. Then a tally over
the slow ones: the frames each side sent before the first one crossed, by kind, and the
time from the return to the first frame that crossed each way. Instrumentation only
(``Sender.send`` and the network's delivery queue are wrapped for the run, then restored);
nothing asserted.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from swarmd_lab import memnet

from bench.flight_fade_replay import SLOW_S, STEP_S, Replay, add_replay_args, rediscoveries
from bench.wifi import flight
from swarmd.discovery import sending

Sent = tuple[float, int, str, int | None]  # now, Sender id, kind, directed to (bundle index)


@contextmanager
def _sends(log: list[Sent]) -> Iterator[None]:
    """Record each ``Sender.send`` while the block runs."""
    send = sending.Sender.send

    def logged(self: sending.Sender, peer: Any, now: float, kind: str) -> None:
        log.append((now, id(self), kind, None if peer is None else peer.index))
        send(self, peer, now, kind)

    sending.Sender.send = logged  # type: ignore[method-assign]
    try:
        yield
    finally:
        sending.Sender.send = send  # type: ignore[method-assign]


def trace_seed(
    replay: Replay, seed: int, slow: list[tuple[float, int, int, float]]
) -> list[dict[str, Any]]:
    """For each slow (latency, observer, peer, back) of ``seed``: the pair's frames from the
    return to the re-discovery, each (t, sender, kind, directed, fate)."""
    log: list[Sent] = []
    with _sends(log):
        swarm = replay.swarm(seed, max(back + lat for lat, _, _, back in slow) + 0.5)
    sender_of = {id(e._sender): i for i, e in enumerate(swarm.engines)}  # noqa: SLF001
    # which datagrams reached whom: ``_deliveries`` logs each delivery MemNet queues, at its
    # send time (two frames of one drone at one instant to the same peer are not told apart)
    net = swarm.net
    out = []
    for lat, i, j, back in slow:
        found = back + lat
        frames = []
        for now, sid, kind, to in log:
            a = sender_of.get(sid)
            if a not in (i, j) or not back - 0.05 <= now <= found + 0.01:
                continue
            b = j if a == i else i
            if to is not None and to != b:
                continue  # directed to a third drone: cannot reach the pair's other end
            margin = replay.rx_at(int(now / STEP_S))[a][b] - flight.RANGE_DBM
            if margin < 0:
                fate = "out of range"
            else:
                fate = "crossed" if _delivered(net, a, b, now) else "lost at the edge"
            frames.append((now, a, kind, to is not None, fate))
        out.append(
            {"seed": seed, "lat": lat, "observer": i, "peer": j, "back": back, "frames": frames}
        )
    return out


def _delivered(net: Any, src: int, dst: int, at: float) -> bool:
    """Whether ``net`` delivered a datagram of ``src`` sent at ``at`` to ``dst`` (its
    ``delivered_log``, filled by ``_deliveries``)."""
    return any(abs(t - at) < 1e-9 for t in net.delivered_log.get((src, dst), ()))


def report(path: Path, seeds: int, edge_db: float, edge_loss: float, show: int) -> str:
    run = json.loads(path.read_text())
    every = run["scenario"] == "fade"
    replay = Replay(run, edge_db, edge_loss, every_observer=every)
    per_seed: dict[int, list[tuple[float, int, int, float]]] = {}
    total = 0
    for seed in range(1, seeds + 1):
        rows = rediscoveries(replay, seed)
        if every:
            rows = [r for r in rows if r[2] == replay.fader]
        total += len(rows)
        slow = [(lat, i, j, back) for lat, i, j, back, _, _ in rows if lat > SLOW_S]
        if slow:
            per_seed[seed] = slow
    traces: list[dict[str, Any]] = []
    with _deliveries():
        for seed, slow in per_seed.items():
            traces += trace_seed(replay, seed, slow)
    traces.sort(key=lambda r: -r["lat"])
    out = [
        f"{path.name}, {seeds} seeds on MemNet (edge loss {edge_loss:g} within {edge_db:g} dB): "
        f"{total} re-discoveries, {len(traces)} over {SLOW_S:g} s"
    ]
    before: Counter[str] = Counter()
    first_cross: list[float] = []
    lost_kinds: Counter[str] = Counter()
    for r in traces:
        crossed = [f for f in r["frames"] if f[4] == "crossed"]
        first = crossed[0][0] - r["back"] if crossed else None
        if first is not None:
            first_cross.append(first)
        for f in r["frames"]:
            if crossed and f[0] >= crossed[0][0]:
                break
            before[f"{f[2]} {'directed' if f[3] else 'multicast'}: {f[4]}"] += 1
        for f in r["frames"]:
            if f[4] == "lost at the edge":
                lost_kinds[f"{f[2]} {'directed' if f[3] else 'multicast'}"] += 1
    out.append(
        "  frames of the pair before the first one crossed: "
        + (", ".join(f"{k} {v}" for k, v in before.most_common()) or "none")
    )
    out.append(
        "  frames lost at the edge, return to re-discovery: "
        + (", ".join(f"{k} {v}" for k, v in lost_kinds.most_common()) or "none")
    )
    if first_cross:
        first_cross.sort()
        out.append(
            f"  first frame across after the return: min {first_cross[0]:.2f} s, "
            f"p50 {first_cross[len(first_cross) // 2]:.2f} s, max {first_cross[-1]:.2f} s"
        )
    for r in traces[:show]:
        i, j, back = r["observer"], r["peer"], r["back"]
        out.append(
            f"  {r['lat']:.2f} s: seed {r['seed']}, uav{i + 1} of uav{j + 1}, back {back:.2f} s"
        )
        for t, a, kind, directed, fate in r["frames"]:
            how = "directed" if directed else "multicast"
            out.append(f"    +{t - back:5.2f} s uav{a + 1} {kind} {how}: {fate}")
    return "\n".join(out)


@contextmanager
def _deliveries() -> Iterator[None]:
    """Give every MemNet a ``delivered_log``: (src, dst) -> send times of the datagrams it
    delivered. ``MemNet._transmit`` queues one delivery per receiver it did not lose, at the
    send time (``now``): ``MemNet._push`` is wrapped while the block runs."""
    push = memnet.MemNet._push

    def logged(self: memnet.MemNet, when: float, item: Any) -> None:
        if isinstance(item, memnet._Delivery):  # noqa: SLF001
            log = self.__dict__.setdefault("delivered_log", {})
            src = self._by_host.get(item.source[0])  # noqa: SLF001
            log.setdefault((src, item.node_id), []).append(self.now)
        push(self, when, item)

    memnet.MemNet._push = logged  # type: ignore[method-assign]
    try:
        yield
    finally:
        memnet.MemNet._push = push  # type: ignore[method-assign]


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.edge_trace",
        description="The frames of each slow pair in a flight replay, from the return to the "
        "re-discovery, and what became of them.",
    )
    add_replay_args(parser)
    parser.add_argument("--edge-db", type=float, default=1.5, help="edge width above -82 dBm")
    parser.add_argument("--edge-loss", type=float, default=0.5, help="multicast loss there")
    parser.add_argument("--show", type=int, default=3, help="slow pairs printed frame by frame")
    args = parser.parse_args(argv)
    if not args.run.is_file():
        print(f"{args.run}: no such run file", file=sys.stderr)
        return 66  # EX_NOINPUT
    print(report(args.run, args.seeds, args.edge_db, args.edge_loss, args.show))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
