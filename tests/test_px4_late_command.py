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

from swarmd.px4.constants import LandedState, MavCmd, MavResult
from swarmd.px4.mavlink_codec import Message
from swarmd.px4.messages import CommandAck, VehicleCommand
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


class _HeldLink(VirtualLink):
    """A ``VirtualLink`` whose companion stops running (swarmd's loop held up) right after
    it sends ``NAV_TAKEOFF``, for ``stall_s`` past that command's retransmission time. PX4
    runs on; what it sends waits, as in a socket's buffer, and on the loop's return the
    due timer runs before it (asyncio reads at most one datagram per socket before the
    timers that fell due)."""

    def __init__(self, sim: SimVehicle, *, lose_first_takeoff: bool) -> None:
        super().__init__(sim, VehicleState(), 0.0, drop=self._hold)
        self.lose_first_takeoff = lose_first_takeoff
        self.holding = False
        self.held: list[Message] = []

    def _hold(self, msg: Message, direction: str, now: float) -> bool:
        if direction == "down" and isinstance(msg, VehicleCommand):
            first = msg.command == MavCmd.NAV_TAKEOFF and msg.confirmation == 0
            return first and self.lose_first_takeoff
        if self.holding:
            self.held.append(msg)
            return True
        return False

    def fly(self, stall_s: float) -> TakeoffSequence:
        self.run_until(5.0)
        seq = TakeoffSequence(self.state, 10.0)
        self.start(seq)
        self.run_until(10.0, stop=lambda: any(_is_takeoff(c) for c in self.sent_down))
        sent = self.now
        self.sequence, self.holding = None, True  # the loop stops; PX4 goes on
        self.run_until(sent + seq.config.command.ack_timeout_s + stall_s)
        self.sequence, self.holding = seq, False
        seq.handle_timer(self.now)  # the timer that fell due runs first
        self._pump_sequence()
        for msg in self.held:  # then what waited
            self._enqueue("up", self._vehicle_codec.encode(msg))
        self.run_until(self.now + 20.0, stop=lambda: seq.done)
        self.run_until(self.now + 10.0)
        return seq


def _is_takeoff(cmd: VehicleCommand) -> bool:
    return cmd.command == MavCmd.NAV_TAKEOFF


@pytest.mark.parametrize("stall_s", [0.5, 2.0, 6.0])
def test_a_loop_held_up_after_nav_takeoff_px4_took_is_not_a_failure_in_the_air(
    stall_s: float,
) -> None:
    """Review 17: PX4 took the first NAV_TAKEOFF and answered; swarmd's loop stalled right
    after sending it, past the retransmission's time, so its answer and PX4's state wait
    behind the due timer. The take-off read nothing before judging: it failed ``held_up``
    and its DISARM met a vehicle spooling up (0.5 s: disarmed, a take-off PX4 would have
    flown lost) or in the air (2 s, 6 s: refused, and the operator was told FAILED while
    the vehicle climbed to 10 m). Now it reads what waited for one ack timeout, sending
    nothing: a success, with no late NAV_TAKEOFF and no DISARM [fails on main: FAILED
    ``held_up``, the simulated vehicle in the air at 2 s and 6 s]."""
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = _HeldLink(sim, lose_first_takeoff=False)
    seq = link.fly(stall_s)
    assert not isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert sim.armed and sim.landed is LandedState.IN_AIR
    assert [_is_takeoff(c) for c in link.sent_down].count(True) == 1
    assert not any(_is_disarm(c) for c in link.sent_down)


@pytest.mark.parametrize("stall_s", [0.5, 6.0])
def test_a_loop_held_up_after_a_lost_nav_takeoff_still_never_sends_it_late(
    stall_s: float,
) -> None:
    """The control: the first NAV_TAKEOFF was lost, the vehicle sits armed on the ground,
    and the loop stalls past the retransmission's time. Nothing confirms the step in the
    ack timeout after the loop's return: the take-off fails ``held_up`` with its one DISARM,
    and no NAV_TAKEOFF ever leaves late (holds on main)."""
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = _HeldLink(sim, lose_first_takeoff=True)
    seq = link.fly(stall_s)
    assert isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert seq.outcome.reason is FailReason.HELD_UP
    assert [_is_takeoff(c) for c in link.sent_down].count(True) == 1
    assert _is_disarm(link.sent_down[-1])
    assert not sim.armed and sim.landed is LandedState.ON_GROUND


def test_an_in_progress_read_in_the_held_window_waits_its_3_s_on_time() -> None:
    """The read window's own edge: NAV_TAKEOFF went out, the loop was held past its
    retransmission time, and what waited is IN_PROGRESS. The take-off neither fails nor
    asks for a timer in the past (a loop that spins): it waits IN_PROGRESS's 3 s, then
    retransmits on time."""
    c = Core()
    c.takeoff()
    c.feed(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED, 0, 1, 191))
    assert [cmd.command for cmd, _ in c.wire] == [MavCmd.COMPONENT_ARM_DISARM, MavCmd.NAV_TAKEOFF]
    c.now = 2.0  # the retransmission was due at 0.5
    c.core.handle_timer(c.now)
    c._collect()  # noqa: SLF001 - the test's own recorder
    assert len(c.wire) == 2 and c.finished == []
    seq = c.core.last_takeoff
    assert seq is not None and seq.get_timer() == pytest.approx(2.5)
    c.feed(CommandAck(MavCmd.NAV_TAKEOFF, MavResult.IN_PROGRESS, 0, 1, 191))
    assert seq.get_timer() == pytest.approx(c.now + 3.0)
    c.advance(3.1)
    assert c.finished == []
    assert [cmd.confirmation for cmd, _ in c.wire if _is_takeoff(cmd)] == [0, 1]
