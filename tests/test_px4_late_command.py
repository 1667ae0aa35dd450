"""Never late at the PX4 edge over MAVLink (docs/security.md, "A command frame delivered
late"): no frame that starts motion (ARM, NAV_TAKEOFF) leaves swarmd after the take-off
gave it up, nor when its retransmission fell due while swarmd's loop did not run.

The take-off's give-ups on the simulator over ``VirtualLink`` (real MAVLink bytes, virtual
time; pins: they hold on main), and the held-up loop on a hand-fed ``VehicleCore``
(``tests/test_px4_arm_mode.py``'s ``Core``: the test plays PX4).
"""

from __future__ import annotations

import random

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import VirtualLink

from swarmd.px4.constants import MavCmd
from swarmd.px4.mavlink_codec import Message
from swarmd.px4.messages import VehicleCommand
from swarmd.px4.readiness import ReadinessConfig, VehicleState, readiness
from swarmd.px4.takeoff import FailReason, TakeoffFailed, TakeoffSequence
from tests.test_px4_arm_mode import Core, _is_arm, _is_disarm


def _starts_motion(cmd: VehicleCommand) -> bool:
    return _is_arm(cmd) or cmd.command == MavCmd.NAV_TAKEOFF


class _Cut:
    """Drops every frame in ``direction`` from the first send of ``after`` on, for
    ``for_s`` seconds (a link that goes one way, or a stalled router)."""

    def __init__(self, after: int, direction: str, for_s: float) -> None:
        self.after, self.direction, self.for_s = after, direction, for_s
        self.since: float | None = None

    def __call__(self, msg: Message, direction: str, now: float) -> bool:
        if self.since is None and isinstance(msg, VehicleCommand) and msg.command == self.after:
            self.since = now
        cut = self.since is not None and now < self.since + self.for_s
        return cut and direction == self.direction


@pytest.mark.parametrize(
    ("after", "reason"),
    [
        (MavCmd.COMPONENT_ARM_DISARM, FailReason.ARM_NO_ACK),
        (MavCmd.NAV_TAKEOFF, FailReason.TAKEOFF_NO_ACK),
    ],
)
def test_after_a_takeoff_gave_up_nothing_that_starts_motion_leaves(
    after: int, reason: FailReason
) -> None:
    """PX4's side of the link goes silent from the first ARM (or NAV_TAKEOFF) on, for 3 s:
    the take-off gives up. From then on only its one DISARM leaves: no retransmission of
    ARM or NAV_TAKEOFF, for the 20 s after. Pinned: holds on main (``_fail`` cancels the
    step's command in the sender before anything else)."""
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = VirtualLink(sim, VehicleState(), 0.0, drop=_Cut(after, "up", 3.0))
    link.run_until(5.0)
    assert readiness(link.state, link.now, ReadinessConfig()).ready
    seq = TakeoffSequence(link.state, 10.0)
    link.start(seq)
    link.run_until(link.now + 15.0, stop=lambda: seq.done)
    assert isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert seq.outcome.reason is reason
    sent_at_failure = len(link.sent_down)
    link.run_until(link.now + 20.0)
    after_failure = link.sent_down[sent_at_failure - 1 :]
    assert [_is_disarm(c) for c in after_failure] == [True]
    assert not any(_starts_motion(c) for c in after_failure)
    if reason is FailReason.ARM_NO_ACK:
        # PX4 got the ARMs (only its answers were lost): the one DISARM disarmed it
        assert not sim.armed


@pytest.mark.parametrize("stall_s", [0.5, 6.0, 60.0])
def test_a_retransmission_of_arm_due_while_the_loop_was_held_up_is_never_sent(
    stall_s: float,
) -> None:
    """The first ARM goes out, PX4's answer is lost, and swarmd's loop does not run again
    until ``stall_s`` after the retransmission fell due (a starved CPU, a blocking call, a
    host suspended: docs/security.md, "A command frame delivered late"). Sent then, the ARM
    would start the take-off that late, past its validity (3 s for a TAKEOFF). The take-off
    fails ``held_up`` with the one DISARM, no second ARM [fails on main: ARM sent 6 s and
    60 s late, and 0.5 s late, outside the retry budget's pace]."""
    c = Core()
    c.takeoff()
    assert len(c.arms()) == 1
    c.now = 0.5 + stall_s  # the retransmission was due at 0.5
    c.core.handle_timer(c.now)
    c._collect()  # noqa: SLF001 - the test's own recorder
    assert len(c.arms()) == 1
    (done,) = c.finished
    assert (done.ok, done.reason) == (False, "held_up")
    assert [_is_disarm(cmd) for cmd, _ in c.wire[1:]] == [True]


def test_a_retransmission_on_time_still_goes_out() -> None:
    """The control: the loop runs a little late (0.3 s), inside the ack timeout: the ARM is
    retransmitted as before."""
    c = Core()
    c.takeoff()
    c.now = 0.8
    c.core.handle_timer(c.now)
    c._collect()  # noqa: SLF001
    assert [a.confirmation for a in c.arms()] == [0, 1]
    assert c.finished == []
