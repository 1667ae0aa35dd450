"""How often a failed take-off leaves the vehicle armed on the ground on a lossy link, with
one DISARM (session 16) and with the DISARM repeated (docs/px4.md, "A failed take-off's
DISARM").

    .venv/bin/python -m bench.takeoff_disarm_loss [RUNS] [--loss 0.3]

RUNS take-offs (default 200, seeds 0..RUNS-1) per backend and rule, every message lost
with probability ``--loss`` each way once the vehicle is ready: MAVLink messages against the
vehicle simulator (``VirtualLink``, as ``bench/takeoff_loss.py``), and XRCE datagrams
against the PX4 1.14 stand-in (best-effort commands: nothing repairs a lost DISARM), on
the pieces of ``tests/test_xrce_late_command.py``. Printed per backend and rule: how many
take-offs failed, how many of those left the vehicle armed on the ground 3 s after the
failure was reported (PX4's own pre-flight disarm comes 10 s after arming), and how many
were reported ``disarm_unconfirmed``. "one DISARM" is the session-16 rule rebuilt as a
subclass (the DISARM sent once and abandoned); "repeated" is ``TakeoffSequence``. A
reading, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import swarmd.px4.vehicle as vehicle_module
from bench.takeoff_loss import lossy_link
from bench.xrce_takeoff_loss import LossyEdge
from swarmd.px4.constants import LandedState
from swarmd.px4.takeoff import TakeoffPhase, TakeoffSequence

AFTER_S = 3.0  # how long after the reported failure the vehicle is looked at


class OneDisarm(TakeoffSequence):
    """Session 16: a failure's DISARM sent once, abandoned at once, never repeated."""

    def _fail(self, *args: Any, **kwargs: Any) -> None:
        super()._fail(*args, **{**kwargs, "repeat": False})


def mavlink_one(rule: type[TakeoffSequence], seed: int, loss: float) -> tuple[bool, bool, bool]:
    """Failed?, left armed on the ground ``AFTER_S`` after?, reported disarm_unconfirmed?"""
    link = lossy_link(seed, loss)
    sim = link.sim
    seq = rule(link.state, 5.0)
    link.start(seq)
    link.run_until(link.now + 30.0, stop=lambda: seq.outcome is not None)
    if seq.phase is not TakeoffPhase.FAILED:
        return False, False, False
    link.run_until(link.now + AFTER_S)
    armed = sim.armed and sim.landed == LandedState.ON_GROUND
    return True, armed, seq.disarm_unconfirmed


@contextmanager
def _sequence(rule: type[TakeoffSequence]) -> Iterator[None]:
    """The vehicle core builds ``rule`` for its take-offs while inside."""
    # the module's name, not an attribute mypy sees exported: the bench's own stand-in
    saved = getattr(vehicle_module, "TakeoffSequence")  # noqa: B009
    setattr(vehicle_module, "TakeoffSequence", rule)  # noqa: B010
    try:
        yield
    finally:
        setattr(vehicle_module, "TakeoffSequence", saved)  # noqa: B010


def xrce_one(rule: type[TakeoffSequence], seed: int, loss: float) -> tuple[bool, bool, bool]:
    edge = LossyEdge(seed, "1.14")
    with _sequence(rule):
        done = edge.lossy_takeoff(loss)
        if done is None or done.ok:  # None: never ended, no failure reported
            return False, False, False
        edge.run(edge.clock.now + AFTER_S)
    px4 = edge.px4.vehicle
    armed = px4.armed and px4.landed == LandedState.ON_GROUND
    return True, armed, edge.core.disarm_unconfirmed > 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("runs", nargs="?", type=int, default=200)
    parser.add_argument("--loss", type=float, default=0.3)
    args = parser.parse_args()
    for backend, one in (("mavlink", mavlink_one), ("xrce 1.14", xrce_one)):
        for name, rule in (("one DISARM", OneDisarm), ("repeated", TakeoffSequence)):
            failed = armed = unconfirmed = 0
            for seed in range(args.runs):
                f, a, u = one(rule, seed, args.loss)
                failed += f
                armed += a
                unconfirmed += u
            print(
                f"loss {args.loss:.0%} {backend:9s} {name:10s}: {failed}/{args.runs} failed; "
                f"left armed on the ground {AFTER_S:g} s after: {armed}; "
                f"disarm_unconfirmed: {unconfirmed}",
                flush=True,
            )


if __name__ == "__main__":
    main()
