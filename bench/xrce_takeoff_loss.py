"""What a lossy uXRCE-DDS link costs a take-off with and without the command life
(docs/px4.md, "The agent's reliable stream and a command's life").

    .venv/bin/python -m bench.xrce_takeoff_loss [RUNS] [--losses 0.1,0.2,0.3]

``bench/takeoff_loss.py`` loses MAVLink messages; this loses XRCE datagrams, so the
agent's reliable stream (PX4 >= 1.15 reads commands on it) repairs what it can. RUNS
take-offs (default 200, seeds 0..RUNS-1) per loss rate, on the pieces of
``tests/test_xrce_late_command.py`` (vehicle core, XRCE agent backend, PX4 1.16 stand-in,
one virtual clock), every datagram lost with that probability both ways once the vehicle is
ready. "life 0.5 s" is ``COMMAND_LIFE_S`` (a command frame repaired as itself only within
it, then as a stand-in); "no life" repairs every frame for as long as the session lives
(session 16). Printed per rule: how each take-off ended, how many stand-ins were sent, and
how many failed take-offs left the stand-in vehicle armed on the ground 3 s after their
outcome. A reading, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import math
import random
from collections import Counter
from collections.abc import Callable

from swarmd.px4.constants import LandedState
from swarmd.px4.vehicle import TaskFinished
from tests.test_xrce_late_command import Edge


class LossyEdge(Edge):
    """The edge with every datagram lost with probability ``loss`` (0 until set)."""

    def __init__(self, seed: int, release: str = "1.16") -> None:
        self.rng = random.Random(seed)
        self.loss = 0.0
        super().__init__(release)

    def carry(self, deliver: Callable[[], None]) -> None:
        if self.rng.random() >= self.loss:
            super().carry(deliver)

    def lossy_takeoff(self, loss: float) -> TaskFinished | None:
        """Ready, then a take-off with ``loss`` each way: its end, or None (never ended)."""
        self.run_until_ready()
        self.run(self.clock.now + 1.0)
        self.loss = loss
        try:
            return self.takeoff_until_done(limit_s=20.0)
        except AssertionError:
            return None


def one(seed: int, loss: float, life: float) -> tuple[str, int, bool]:
    """The outcome's code, the stand-ins sent, and whether a failure left PX4 armed on the
    ground 3 s after it."""
    edge = LossyEdge(seed)
    edge.backend.command_life_s = life
    done = edge.lossy_takeoff(loss)
    if done is None:
        return "never_ended", 0, False
    edge.run(edge.clock.now + 3.0)
    vehicle = edge.px4.vehicle
    left_armed = not done.ok and vehicle.armed and vehicle.landed == LandedState.ON_GROUND
    expired = int(edge.backend.stats().get("commands_expired", 0))
    return ("succeeded" if done.ok else str(done.reason)), expired, left_armed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("runs", nargs="?", type=int, default=200)
    parser.add_argument("--losses", default="0.1,0.2,0.3")
    args = parser.parse_args()
    for loss in (float(x) for x in args.losses.split(",")):
        for name, life in (("life 0.5 s", 0.5), ("no life", math.inf)):
            codes: Counter[str] = Counter()
            stand_ins = left_armed = 0
            for seed in range(args.runs):
                code, expired, armed = one(seed, loss, life)
                codes[code] += 1
                stand_ins += expired
                left_armed += armed
            ended = ", ".join(f"{k} {v}" for k, v in sorted(codes.items()))
            print(
                f"loss {loss:.0%} {name:10s}: {ended}; stand-ins {stand_ins}; "
                f"failed and left armed on the ground {left_armed}",
                flush=True,
            )


if __name__ == "__main__":
    main()
