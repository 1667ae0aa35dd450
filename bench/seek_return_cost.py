"""What a peer that comes back once a minute costs the others per hour (docs/security.md,
"Seek and rejoin paths").

    .venv/bin/python -m bench.seek_return_cost [--seeds 3] [--n 10] [--hours 1]

The attack: a lost peer heard again freshens the seek's put-off bound (``Seek.returned``) and
each loss of a peer heard within ``SEEK_PUT_OFF_FOR_S`` is fresh (``Seek.start``); while a
loss is fresh every drone that lost it seeks at least every ``SEEK_PUT_OFF_MAX_S``, where a
stale loss draws one seek per period per neighbourhood. Who can make a peer come back over
and over: a captured member (its own genuine frames), or a relay that lets one of a real
peer's genuine, fresh frames across now and then (a wormhole: the frames verify, they are
the peer's). A replayer cannot: a replayed frame is refused before anything moves
(``tests/test_discovery_seek_attacks.py``).

MemNet, virtual time, the clean channel: the last drone's links to the others are cut at
``T_CUT`` and opened for ``OPEN_S`` once every ``--every`` seconds (its seeks, ~1 s apart
while it has lost everyone, cross then; the others find it, lose it by lease, seek it). Per
seed it prints, over the hours after the first ``SEEK_FOR_S``, the frames the others sent
per hour (multicast, of which seeks, and directed), for three cases:

* *returns*: the peer back for ``OPEN_S`` every ``--every`` seconds, as built;
* *returns, no bound*: the same with ``SEEK_PUT_OFF_FOR_S`` = 0 (the suppression whole, as
  before the bound: a2a86ac's parent);
* *gone*: the peer never back (past ``SEEK_FOR_S`` it is no longer sought).

``--reflection`` prints instead what a captured member that leaves (its signed DATA(p[UD]))
and returns (its signed DATA(p)) 10 times a second draws from the others at its signed
locator, which it chooses (any unicast address but loopback and the receiver's own): the
directed copies of ``Debts.take_late_copies``, with and without them, against the bytes it
sent itself (the case of ``tests/test_discovery_found_again.py``, 30 s).

Nothing asserted (the unit tests assert the bounds).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from swarmd_lab.testing import (
    ScriptedSender,
    Swarm,
    auth_for,
    build_swarm,
    leave_or_return_datagram,
    node_ipv4,
)

from swarmd.discovery import seek
from swarmd.discovery.debts import Debts
from swarmd.discovery.seek import SEEK_FOR_S

T_CUT = 30.0
OPEN_S = 1.5


@dataclass(frozen=True, slots=True)
class PerHour:
    multicast: float
    seeks: float
    directed: float


def _run(n: int, seed: int, *, every_s: float | None, hours: float) -> PerHour:
    swarm = build_swarm(n, seed=seed, authenticated=True)
    net = swarm.net
    peer = n - 1

    def open_now() -> bool:
        if every_s is None:
            return False
        return (net.now - T_CUT) % every_s < OPEN_S

    def loss(a: int, b: int) -> float:
        if peer not in (a, b) or a == b or net.now < T_CUT:
            return 0.0
        return 0.0 if open_now() else 1.0

    net.link_loss = loss
    start_t = T_CUT + SEEK_FOR_S  # the steady state: a drone gone is no longer sought by then
    swarm.run_until(start_t)
    before = len(net.transmissions)
    seeks_before = sum(swarm.engines[i].counters()["tx_kind"]["seek"] for i in range(n - 1))
    swarm.run_until(start_t + hours * 3600.0)
    sent = [x for x in net.transmissions[before:] if x.node != peer]
    seeks = sum(swarm.engines[i].counters()["tx_kind"]["seek"] for i in range(n - 1))
    return PerHour(
        multicast=sum(1 for x in sent if x.multicast) / hours,
        seeks=(seeks - seeks_before) / hours,
        directed=sum(1 for x in sent if not x.multicast) / hours,
    )


class _Cycling(ScriptedSender):
    """The captured member: every 0.05 s for ``for_s`` from ``start``, alternately its
    signed dispose and a signed DATA(p) listing nobody, to the group."""

    def __init__(self, swarm: Swarm, index: int, start: float, for_s: float) -> None:
        super().__init__(start)
        self._swarm, self._index = swarm, index
        self._auth = auth_for(swarm.bundle, index, now=start)
        self._end = start + for_s
        self._sn = 10_000
        self.sent_bytes = 0

    def handle_timer(self, now: float) -> None:
        group = self._swarm.engines[0].spdp_multicast
        while self._next is not None and self._next <= now:
            self._sn += 1
            frame = leave_or_return_datagram(
                self._swarm.bundle, self._index, sequence_number=self._sn, auth=self._auth
            )
            self._out.append((frame, group))
            self.sent_bytes += len(frame)
            self._next += 0.05
            if self._next > self._end:
                self._next = None


def reflection(n: int, seed: int, *, copies: bool, missing: bool) -> tuple[int, int, int, int]:
    """(frames and bytes the captured member sent, directed frames and bytes the others sent
    to its locator) over 30 s. ``missing``: one other drone cut off, so each return pulls a
    multicast in and the copy rides on it; else each return is answered by a directed frame
    alone (the rejoin answer, before this session too). Both share the re-ack gap."""
    swarm = build_swarm(n, seed=seed, authenticated=True)
    swarm.run_until(30.0)
    captured = n - 1
    if missing:
        swarm.net.isolate(n - 2)
    swarm.run_until(60.0)
    attacker = _Cycling(swarm, captured, 60.0, 30.0)
    swarm.net.replace(captured, attacker)
    start = len(swarm.net.transmissions)
    take = Debts.take_late_copies
    if not copies:
        Debts.take_late_copies = lambda self, now: []  # type: ignore[method-assign]
    try:
        swarm.run_until(90.0)
    finally:
        Debts.take_late_copies = take  # type: ignore[method-assign]
    sent = swarm.net.transmissions[start:]
    to_it = [x for x in sent if not x.multicast and x.target[0] == node_ipv4(captured)]
    mine = [x for x in sent if x.node == captured]
    return len(mine), attacker.sent_bytes, len(to_it), sum(x.size for x in to_it)


def _line(label: str, r: PerHour) -> str:
    return (
        f"  {label}: {r.multicast:.0f} multicast/h (seeks {r.seeks:.0f}), "
        f"{r.directed:.0f} directed/h"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.seek_return_cost", description=__doc__)
    parser.add_argument("--seeds", type=int, default=3, help="seeds 1..S (default 3)")
    parser.add_argument("--n", type=int, default=10, help="drones (default 10)")
    parser.add_argument("--every", type=float, default=60.0, help="a return every S s")
    parser.add_argument("--hours", type=float, default=1.0, help="measured hours (default 1)")
    parser.add_argument("--reflection", action="store_true", help="the copies' reflection")
    args = parser.parse_args(argv)
    if args.reflection:
        cases = ((True, True), (False, True), (True, False))
        for s in range(1, args.seeds + 1):
            for copies, missing in cases:
                frames, sent_b, got, got_b = reflection(args.n, s, copies=copies, missing=missing)
                label = ("as built" if copies else "without the copies") + (
                    ", one drone missing" if missing else ", nobody missing"
                )
                print(
                    f"N = {args.n} seed {s}, {label}: the captured member sent {frames} frames "
                    f"({sent_b} B); the others sent its locator {got} directed ({got_b} B)"
                )
        return 0
    print(f"N = {args.n}, the last drone back for {OPEN_S} s every {args.every:g} s:")
    for s in range(1, args.seeds + 1):
        print(f"seed {s}:")
        print(_line("returns", _run(args.n, s, every_s=args.every, hours=args.hours)))
        bound = seek.SEEK_PUT_OFF_FOR_S
        seek.SEEK_PUT_OFF_FOR_S = 0.0  # type: ignore[misc]  # the bound off: before a2a86ac
        try:
            r = _run(args.n, s, every_s=args.every, hours=args.hours)
        finally:
            seek.SEEK_PUT_OFF_FOR_S = bound  # type: ignore[misc]
        print(_line("returns, no bound", r))
        print(_line("gone", _run(args.n, s, every_s=None, hours=args.hours)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
