"""One pair's seeks in a flight replay: who put them off, and could those frames reach the
other side? (issue 20; docs/discovery.md, "A seek put off by a frame that cannot reach").

    .venv/bin/python -m bench.seek_trace \
        bench/results/flight-stagger-1e20f9e/runs/flight-fly-out-swarmd-n20-r1.json \
        --seed 71 --pair 9 15 --since 84 --until 89

Replays the run's geometry on MemNet as ``bench.flight_fade_replay`` does (clean channel) and
prints, for the two drones (uavN names, 1-based), in the time span: each multicast either
sent, and whether it reached the other (``--directed``: each directed frame too, to whom);
each time a peer's multicast put one's seek off (``Seek.heard`` moved its deadline): the
sender, and whether that sender was in range of the other drone (a frame out of its range
sought nothing for us). And each one's re-discovery of
the other. Instrumentation only: ``Seek.heard`` and ``ReceivePath._heard`` are wrapped for
the run and restored after; nothing asserted.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from swarmd_lab.testing import node_ipv4

from bench.flight_fade_replay import Replay, _changes
from swarmd.discovery import receive, seek


@contextmanager
def _suppressions(log: list[tuple[float, int, int, float, float]]) -> Iterator[None]:
    """Record (now, Seek id, sender's bundle index, deadline before, after) of each seek put
    off by a peer's multicast, while the block runs."""
    seek_heard, receive_heard = seek.Seek.heard, receive.ReceivePath._heard
    sender = [-1]

    def heard_by_receive(self: receive.ReceivePath, peer: Any, *args: Any, **kw: Any) -> None:
        sender[0] = peer.index
        receive_heard(self, peer, *args, **kw)

    def heard_by_seek(self: seek.Seek, heard: bytes | None, now: float, seeker: int) -> None:
        before = self.due
        seek_heard(self, heard, now, seeker)
        if before is not None and self.due != before:
            log.append((now, id(self), sender[0], before, self.due or 0.0))

    seek.Seek.heard = heard_by_seek  # type: ignore[method-assign]
    receive.ReceivePath._heard = heard_by_receive  # type: ignore[method-assign]
    try:
        yield
    finally:
        seek.Seek.heard = seek_heard  # type: ignore[method-assign]
        receive.ReceivePath._heard = receive_heard  # type: ignore[method-assign]


def trace(
    run: dict[str, Any],
    seed: int,
    a: int,
    b: int,
    since: float,
    until: float,
    directed: bool = False,
) -> str:
    """The text above for bundle indices ``a`` and ``b``; ``directed``: also each directed
    frame either sends, to whom (an answer to one seeker reaches no other)."""
    replay = Replay(run)
    log: list[tuple[float, int, int, float, float]] = []
    with _suppressions(log):
        swarm = replay.swarm(seed, replay.scenario.duration_s)
    seek_of = {id(e._seek): i for i, e in enumerate(swarm.engines)}  # noqa: SLF001
    out: list[str] = []
    for x, y in ((a, b), (b, a)):
        for (lost, was), (found, now_found) in zip(
            _changes(swarm, x, y), _changes(swarm, x, y)[1:], strict=False
        ):
            if not was and now_found:
                back, _ = replay.window(y, lost, x)
                out.append(
                    f"uav{x + 1} lost uav{y + 1} at {lost:.2f} s; both ways in range from "
                    f"{back:.2f} s; found at {found:.2f} s (+{found - back:.2f} s)"
                )
    events: list[tuple[float, str]] = []
    index_of = {node_ipv4(i): i for i in range(replay.n)}
    for t in swarm.net.transmissions:
        if t.multicast and t.node in (a, b) and since <= t.time <= until:
            other = b if t.node == a else a
            reach = "reaches" if replay.crosses(t.node, other, t.time) else "does not reach"
            events.append((t.time, f"uav{t.node + 1} multicasts ({reach} uav{other + 1})"))
        elif directed and t.node in (a, b) and since <= t.time <= until:
            to = index_of.get(t.target[0])
            events.append((t.time, f"uav{t.node + 1} sends directed to uav{(to or 0) + 1}"))
    for now, sid, sender, before, after in log:
        me = seek_of.get(sid)
        if me in (a, b) and since <= now <= until:
            other = b if me == a else a
            reach = "in range of" if replay.crosses(sender, other, now) else "out of range of"
            events.append(
                (
                    now,
                    f"uav{me + 1}'s seek put off {before:.3f} -> {after:.3f} s by uav{sender + 1}"
                    f" ({reach} uav{other + 1})",
                )
            )
    out += [f"{t:8.3f}  {text}" for t, text in sorted(events)]
    return "\n".join(out)


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.seek_trace",
        description="One pair's seeks in a flight replay and what put them off.",
    )
    parser.add_argument("run", type=Path, help="a flight run file (*.json)")
    parser.add_argument("--seed", type=int, required=True, help="the MemNet seed")
    parser.add_argument("--pair", type=int, nargs=2, required=True, help="uavN numbers (1-based)")
    parser.add_argument("--since", type=float, default=0.0, help="span start (s)")
    parser.add_argument("--until", type=float, default=float("inf"), help="span end (s)")
    parser.add_argument(
        "--directed", action="store_true", help="also each directed frame either drone sends"
    )
    args = parser.parse_args(argv)
    if not args.run.is_file():
        print(f"{args.run}: no such run file", file=sys.stderr)
        return 66  # EX_NOINPUT
    run = json.loads(args.run.read_text())
    if not all(1 <= u <= run["n"] for u in args.pair) or args.pair[0] == args.pair[1]:
        print(f"--pair: two different drones in 1..{run['n']}", file=sys.stderr)
        return 64  # EX_USAGE
    a, b = (u - 1 for u in args.pair)
    print(trace(run, args.seed, a, b, args.since, args.until, args.directed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
