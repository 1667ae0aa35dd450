"""What a lossy PX4 link costs the take-off since NAV_TAKEOFF's state confirmation needs an
armed on-ground state in an allowed mode (docs/px4.md, "Fresh state": the take-off).

    .venv/bin/python bench/takeoff_loss.py [RUNS]

Runs RUNS take-offs (default 200, seeds 0..RUNS-1) per loss rate against the vehicle
simulator on virtual time, every MAVLink message lost with that probability in both
directions, and prints per rule how each ended and how many were reported failed while the
simulated vehicle flew (armed, off the ground, 15 s after the outcome). "before" is the
session-15 rule (state confirms NAV_TAKEOFF unless the state at its send already showed
AUTO.TAKEOFF or a lift-off), rebuilt here as a subclass; "now" is ``TakeoffSequence``. A
reading, not a test: nothing asserted.
"""

from __future__ import annotations

import random
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "lab"))

from swarmd_lab.px4.sim_model import SimConfig, SimVehicle  # noqa: E402
from swarmd_lab.px4.virtual import VirtualLink  # noqa: E402

from swarmd.px4.actions import fresh  # noqa: E402
from swarmd.px4.constants import LandedState, MavCmd  # noqa: E402
from swarmd.px4.messages import MODE_TAKEOFF, VehicleCommand  # noqa: E402
from swarmd.px4.readiness import VehicleState  # noqa: E402
from swarmd.px4.takeoff import AIRBORNE, TakeoffFailed, TakeoffSequence  # noqa: E402

LOSSES = (0.1, 0.3)


class BeforeRule(TakeoffSequence):
    """The session-15 confirmation: only a state that already showed the effect is refused."""

    _took_off_before = False

    def _send(self, command: VehicleCommand, now: float) -> None:
        if command.command == MavCmd.NAV_TAKEOFF:
            v = self.vehicle
            mode = v.heartbeat is not None and v.heartbeat.mode == MODE_TAKEOFF
            self._took_off_before = v.landed_state in AIRBORNE or mode
        super()._send(command, now)

    def _takeoff_shows(self) -> bool:
        v, since = self.vehicle, self._takeoff_fresh_from
        if since is None or self._took_off_before:
            return False
        mode = v.heartbeat is not None and v.heartbeat.mode == MODE_TAKEOFF
        airborne = v.landed_state in AIRBORNE
        return (fresh(v.heartbeat_at, since) and mode) or (fresh(v.extended_at, since) and airborne)


def lossy_link(seed: int, loss: float) -> VirtualLink:
    """The simulator ready at 5 s, every MAVLink message lost with ``loss`` both ways."""
    rng = random.Random(seed)
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = VirtualLink(sim, VehicleState(), 0.0, drop=lambda msg, d, now: rng.random() < loss)
    link.run_until(5.0)
    return link


def one(rule: type[TakeoffSequence], seed: int, loss: float) -> tuple[str, bool]:
    """The outcome's code and whether the simulated vehicle flew."""
    link = lossy_link(seed, loss)
    sim = link.sim
    seq = rule(link.state, 5.0)
    link.start(seq)
    link.run_until(link.now + 30.0, stop=lambda: seq.done)
    link.run_until(link.now + 15.0)
    flew = sim.armed and sim.landed != LandedState.ON_GROUND
    out = seq.outcome
    code = out.reason.value if isinstance(out, TakeoffFailed) else "succeeded"
    return code, flew


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    for loss in LOSSES:
        for name, rule in (("before", BeforeRule), ("now", TakeoffSequence)):
            codes: Counter[str] = Counter()
            failed_but_flew = 0
            for seed in range(runs):
                code, flew = one(rule, seed, loss)
                codes[code] += 1
                failed_but_flew += code != "succeeded" and flew
            tally = ", ".join(f"{c} {n}" for c, n in sorted(codes.items()))
            print(f"loss {loss:.0%} {name:6}: {tally}; reported failed but flew: {failed_but_flew}")


if __name__ == "__main__":
    main()
