"""The take-off sequence on virtual time: against the vehicle simulator and scripted vehicles."""

from __future__ import annotations

import math
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import DropFilter, VirtualLink

from swarmd.px4.command_sender import AckReceived, CommandSent, SenderConfig
from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
    Px4AutoSubMode,
    Px4MainMode,
)
from swarmd.px4.mavlink_codec import Message
from swarmd.px4.messages import (
    MODE_LOITER,
    MODE_TAKEOFF,
    CommandAck,
    ExtendedSysState,
    GlobalPositionInt,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    StateReset,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.readiness import ReadinessConfig, VehicleState
from swarmd.px4.takeoff import (
    FailReason,
    TakeoffConfig,
    TakeoffFailed,
    TakeoffPhase,
    TakeoffSequence,
    TakeoffSucceeded,
)

HOME_AMSL_M = 488.0


def ready_link(
    sim_config: SimConfig | None = None, drop: DropFilter | None = None, warmup_s: float = 5.0
) -> VirtualLink:
    sim = SimVehicle(sim_config or SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = VirtualLink(sim, VehicleState(), 0.0, drop=drop)
    link.run_until(warmup_s)
    return link


def fly(link: VirtualLink, alt_m: float | None, *, budget_s: float = 30.0) -> TakeoffSequence:
    seq = TakeoffSequence(link.state, alt_m)
    link.start(seq)
    link.run_until(link.now + budget_s, stop=lambda: seq.done)
    return seq


def commands(link: VirtualLink, command: MavCmd) -> list[VehicleCommand]:
    return [c for c in link.sent_down if c.command == command]


def test_takeoff_succeeds_against_the_simulator() -> None:
    link = ready_link()
    seq = fly(link, 10.0)
    assert isinstance(seq.outcome, TakeoffSucceeded), seq.outcome
    assert seq.outcome.landed_state in ("TAKEOFF", "IN_AIR")
    assert seq.outcome.target_amsl_m == HOME_AMSL_M + 10.0
    (arm,) = commands(link, MavCmd.COMPONENT_ARM_DISARM)
    assert arm.params[0] == 1.0 and all(math.isnan(p) for p in arm.params[1:])
    assert (arm.target_system, arm.target_component) == (1, 1)
    (takeoff,) = commands(link, MavCmd.NAV_TAKEOFF)
    assert all(math.isnan(p) for p in takeoff.params[:6])  # PX4: NaN = unused / here
    assert takeoff.params[6] == pytest.approx(HOME_AMSL_M + 10.0)  # param7 is AMSL
    # arm first, NAV_TAKEOFF right after (well inside COM_DISARM_PRFLT)
    assert link.sent_down.index(arm) < link.sent_down.index(takeoff)
    link.run_until(link.now + 15.0)
    assert link.sim.landed == LandedState.IN_AIR and link.sim.armed
    assert link.sim.alt_m == pytest.approx(10.0)
    assert link.sim.mode == MODE_LOITER  # PX4 holds after the take-off


def test_no_altitude_means_nan_and_mis_takeoff_alt() -> None:
    link = ready_link()
    seq = fly(link, None)
    assert isinstance(seq.outcome, TakeoffSucceeded)
    (takeoff,) = commands(link, MavCmd.NAV_TAKEOFF)
    assert math.isnan(takeoff.params[6])
    link.run_until(link.now + 10.0)
    assert link.sim.alt_m == pytest.approx(2.5)  # MIS_TAKEOFF_ALT


@pytest.mark.parametrize(
    ("sim_config", "cause"),
    [
        (SimConfig(gps_fix_after_s=100.0), "prearm_failed"),  # Hold needs a global position
        (SimConfig(gps_fix_after_s=1.0, no_home=True), "no_home"),
        (SimConfig(gps_fix_after_s=1.0, battery_pct=20.0), "battery_low"),
        (SimConfig(gps_fix_after_s=1.0, fail_prearm=True), "prearm_failed"),
    ],
)
def test_not_ready_vehicle_is_refused_with_its_reason(sim_config: SimConfig, cause: str) -> None:
    link = ready_link(sim_config)
    seq = fly(link, 10.0)
    assert isinstance(seq.outcome, TakeoffFailed)
    assert seq.outcome.reason is FailReason.NOT_READY
    assert seq.outcome.cause == cause
    assert link.sent_down == []  # refused before a single command
    assert not link.sim.armed


def test_link_down_is_refused() -> None:
    link = ready_link(drop=lambda msg, direction, now: now > 2.0)
    seq = fly(link, 5.0)
    assert isinstance(seq.outcome, TakeoffFailed)
    assert seq.outcome.cause == "heartbeat_stale"


def test_temporarily_rejected_then_retry_succeeds() -> None:
    link = ready_link(SimConfig(gps_fix_after_s=1.0, reject_arms=2))
    seq = fly(link, 5.0)
    assert isinstance(seq.outcome, TakeoffSucceeded), seq.outcome
    arms = commands(link, MavCmd.COMPONENT_ARM_DISARM)
    assert [c.confirmation for c in arms] == [0, 1, 2]  # MAVLink command protocol
    acks = [e.result for e in link.events if isinstance(e, AckReceived)]
    assert acks[:3] == ["TEMPORARILY_REJECTED", "TEMPORARILY_REJECTED", "ACCEPTED"]


def test_rejected_on_every_retry_fails_and_leaves_vehicle_disarmed() -> None:
    link = ready_link(SimConfig(gps_fix_after_s=1.0, reject_arms=10))
    seq = fly(link, 5.0)
    assert isinstance(seq.outcome, TakeoffFailed)
    assert seq.outcome.reason is FailReason.ARM_REJECTED
    assert seq.outcome.cause == "TEMPORARILY_REJECTED"
    assert "simulated rejection" in seq.outcome.detail  # PX4's STATUSTEXT is quoted
    arms = commands(link, MavCmd.COMPONENT_ARM_DISARM)
    assert [c.params[0] for c in arms] == [1.0, 1.0, 1.0, 1.0, 0.0]  # 1 + 3 retries, disarm
    assert not link.sim.armed


def test_lost_acks_are_confirmed_by_state() -> None:
    def drop_acks(msg: Message, direction: str, now: float) -> bool:
        return isinstance(msg, CommandAck)

    link = ready_link(drop=drop_acks)
    seq = fly(link, 5.0)
    assert isinstance(seq.outcome, TakeoffSucceeded), seq.outcome
    assert not any(isinstance(e, AckReceived) for e in link.events)
    link.run_until(link.now + 10.0)
    assert link.sim.landed == LandedState.IN_AIR


def test_lost_commands_run_out_of_retries() -> None:
    link = ready_link(drop=lambda msg, direction, now: direction == "down")
    t0 = link.now
    seq = fly(link, 5.0)
    assert isinstance(seq.outcome, TakeoffFailed)
    assert seq.outcome.reason is FailReason.ARM_NO_ACK
    arms = [c for c in commands(link, MavCmd.COMPONENT_ARM_DISARM) if c.params[0] == 1.0]
    assert [c.confirmation for c in arms] == [0, 1, 2, 3]
    assert seq.outcome.elapsed_s == pytest.approx(4 * 0.5)  # virtual time: 4 x ack timeout
    # reported once the DISARM repeats end: a fresh HEARTBEAT reads disarmed (1 Hz), within
    # the DISARM's own sender budget (tests/test_px4_disarm_repeat.py)
    assert 2.0 < link.now - t0 <= 4.0


def _takeoff_mode_by_another_ground_station(link: VirtualLink) -> None:
    """A GCS (system 255) puts the disarmed vehicle in AUTO.TAKEOFF: PX4 waits for an ARM,
    then climbs to MIS_TAKEOFF_ALT."""
    mode = VehicleCommand.make(MavCmd.DO_SET_MODE, p1=1.0, p2=float(Px4MainMode.AUTO),
                               p3=float(Px4AutoSubMode.TAKEOFF))  # fmt: skip
    link.sim.receive(mode, (255, 190), link.now)
    assert link.sim.mode == MODE_TAKEOFF and not link.sim.armed


def test_someone_elses_takeoff_mode_is_refused_before_any_arm() -> None:
    """Another ground station's AUTO.TAKEOFF: our ARM alone would make PX4 climb to
    MIS_TAKEOFF_ALT. Readiness refuses the mode (``flight_mode``) and nothing is sent.
    [main: ARM sent, the take-off reported done at PX4's 2.5 m, or ``takeoff_no_ack``]"""
    link = ready_link()
    _takeoff_mode_by_another_ground_station(link)
    link.run_until(link.now + 1.5)  # our state now shows the mode
    seq = fly(link, 10.0)
    assert isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert (seq.outcome.reason, seq.outcome.cause) == (FailReason.NOT_READY, "flight_mode")
    assert "AUTO.TAKEOFF" in seq.outcome.detail
    assert link.sent_down == []
    link.run_until(link.now + 10.0)
    assert not link.sim.armed and link.sim.alt_m == 0.0


def test_takeoff_mode_switched_while_our_arm_is_on_the_wire_does_not_confirm_nav_takeoff() -> None:
    """The race readiness cannot close: the GCS's mode switch reaches PX4 after readiness
    read Hold and before our ARM (5 ms on the wire). PX4 arms in AUTO.TAKEOFF and climbs to
    MIS_TAKEOFF_ALT; our NAV_TAKEOFF is lost every time. Its mode and lift-off, there before
    NAV_TAKEOFF was sent, never confirm it: ``takeoff_no_ack``, the operator told it failed."""

    def drop_takeoff(msg: Message, direction: str, now: float) -> bool:
        return isinstance(msg, VehicleCommand) and msg.command == MavCmd.NAV_TAKEOFF

    link = ready_link(drop=drop_takeoff)
    seq = TakeoffSequence(link.state, 10.0)
    link.start(seq)  # ARM queued, Hold read
    _takeoff_mode_by_another_ground_station(link)
    link.run_until(link.now + 30.0, stop=lambda: seq.done)
    assert isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert seq.outcome.reason is FailReason.TAKEOFF_NO_ACK
    assert [c.confirmation for c in commands(link, MavCmd.NAV_TAKEOFF)] == [0, 1, 2, 3]
    link.run_until(link.now + 10.0)
    assert link.sim.alt_m == pytest.approx(2.5)  # MIS_TAKEOFF_ALT: what the report says


# ---- scripted vehicle: exact control over what the autopilot says ------------------------


class Scripted:
    """A VehicleState + sequence fed by hand; the test plays PX4."""

    def __init__(self, alt_m: float | None = 5.0, config: TakeoffConfig | None = None) -> None:
        self.now = 0.0
        self.state = VehicleState()
        self.armed = False
        self.mode = MODE_LOITER
        self.landed = LandedState.ON_GROUND
        self.seq = TakeoffSequence(self.state, alt_m, config=config)
        self.sent: list[VehicleCommand] = []
        self.telemetry()

    def heartbeat(self) -> Heartbeat:
        return Heartbeat(
            12,
            2,
            1 | (128 if self.armed else 0),
            self.mode.custom_mode,
            MavState.ACTIVE if self.armed else MavState.STANDBY,
        )

    def telemetry(self) -> None:
        for obs in (
            self.heartbeat(),
            SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
            ExtendedSysState(self.landed),
            GpsRawInt(GpsFixType.FIX_3D, 12),
            HomePosition(0, 0, round(HOME_AMSL_M * 1000)),
        ):
            self.feed(obs)

    def feed(self, obs: Observation) -> None:
        self.state.observe(obs, self.now)
        self.seq.observe(obs, self.now)
        self.sent += self.seq.commands_to_send()

    # methods, not properties: mypy would narrow a property across the calls that change it
    def phase(self) -> TakeoffPhase:
        return self.seq.phase

    def outcome(self) -> TakeoffSucceeded | TakeoffFailed | None:
        return self.seq.outcome

    def failure(self) -> TakeoffFailed:
        out = self.seq.outcome
        assert isinstance(out, TakeoffFailed), out
        return out

    def start(self) -> None:
        self.seq.start(self.now)
        self.sent += self.seq.commands_to_send()

    def ack(self, command: MavCmd, result: MavResult) -> None:
        self.feed(CommandAck(command, result, 0, 1, 191))

    def advance_to_timer(self) -> None:
        timer = self.seq.get_timer()
        assert timer is not None
        self.now = timer
        self.seq.handle_timer(self.now)
        self.sent += self.seq.commands_to_send()


def test_retry_schedule_after_temporarily_rejected() -> None:
    v = Scripted()
    v.start()
    assert [c.command for c in v.sent] == [MavCmd.COMPONENT_ARM_DISARM]
    assert v.seq.get_timer() == 0.5  # ack timeout
    v.now = 0.1
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.TEMPORARILY_REJECTED)
    assert v.seq.get_timer() == pytest.approx(0.6)  # retry_backoff_s after the rejection
    v.advance_to_timer()
    assert [c.confirmation for c in v.sent] == [0, 1]
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.TAKING_OFF
    assert v.sent[-1].command == MavCmd.NAV_TAKEOFF


def test_denied_is_final_and_not_retried() -> None:
    v = Scripted()
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.DENIED)
    assert isinstance(v.outcome(), TakeoffFailed)
    assert (v.failure().reason, v.failure().cause) == (FailReason.ARM_REJECTED, "DENIED")
    assert [c.params[0] for c in v.sent] == [1.0, 0.0]  # one arm, then the safety disarm
    assert v.seq.disarming  # the DISARM waits for its answer (test_px4_disarm_repeat)


def test_in_progress_stretches_the_wait() -> None:
    v = Scripted()
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.IN_PROGRESS)
    assert v.seq.get_timer() == pytest.approx(3.0)


def test_acks_for_other_commands_are_ignored() -> None:
    v = Scripted()
    v.start()
    v.ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.ARMING


def test_auto_disarm_when_takeoff_does_not_follow_arming() -> None:
    """PX4 accepts ARM, swallows NAV_TAKEOFF's effect, and auto-disarms after 10 s."""
    v = Scripted(config=TakeoffConfig(liftoff_timeout_s=12.0))
    v.start()
    v.armed = True
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)
    v.feed(v.heartbeat())
    v.ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.LIFTING
    v.now = 10.0  # COM_DISARM_PRFLT: still on the ground
    v.armed = False
    v.feed(v.heartbeat())
    assert isinstance(v.outcome(), TakeoffFailed)
    assert v.failure().reason is FailReason.DISARMED


def test_no_liftoff_times_out_and_disarms() -> None:
    v = Scripted()
    v.start()
    v.armed = True
    v.feed(v.heartbeat())  # armed bit: ARM confirmed by state, no ACK needed
    assert v.phase() is TakeoffPhase.TAKING_OFF
    v.mode = MODE_TAKEOFF
    v.feed(v.heartbeat())  # received with NAV_TAKEOFF's send: may predate it, confirms nothing
    assert v.phase() is TakeoffPhase.TAKING_OFF
    v.now = 0.5  # an ack timeout after the send: mode AUTO.TAKEOFF confirms NAV_TAKEOFF
    v.feed(v.heartbeat())
    assert v.phase() is TakeoffPhase.LIFTING
    v.advance_to_timer()
    assert v.now == pytest.approx(8.5)
    assert isinstance(v.outcome(), TakeoffFailed)
    assert v.failure().reason is FailReason.NO_LIFTOFF
    last = v.sent[-1]
    assert last.command == MavCmd.COMPONENT_ARM_DISARM and last.params[0] == 0.0


def test_a_state_reset_while_lifting_is_unknown_not_disarmed() -> None:
    """XRCE's new session (``StateReset``) empties the state mid-climb: no HEARTBEAT is not
    a disarm (no ``disarmed`` failure, no DISARM sent); the new life's state decides."""
    v = Scripted()
    v.start()
    v.armed = True
    v.feed(v.heartbeat())  # armed: ARM confirmed by state
    v.ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.LIFTING
    sent = len(v.sent)
    v.now = 1.0
    v.feed(StateReset("new XRCE session"))
    v.feed(SysStatus(SENSOR_PREARM_CHECK, 90, 16000))
    assert v.outcome() is None and len(v.sent) == sent
    v.mode, v.landed = MODE_TAKEOFF, LandedState.TAKEOFF
    v.now = 1.5
    v.feed(v.heartbeat())
    v.feed(ExtendedSysState(v.landed))
    assert isinstance(v.outcome(), TakeoffSucceeded)


def test_success_needs_armed_and_airborne_state_not_just_acks() -> None:
    v = Scripted()
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)
    v.ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.LIFTING and v.outcome() is None
    v.landed = LandedState.TAKEOFF
    v.feed(ExtendedSysState(v.landed))
    assert v.outcome() is None  # airborne but the armed bit was never seen
    v.armed = True
    v.feed(v.heartbeat())
    assert isinstance(v.outcome(), TakeoffSucceeded)
    assert [type(e).__name__ for e in iter(v.seq.next_event, None)].count("TakeoffSucceeded") == 1


@pytest.mark.parametrize("alt", [0.0, -3.0, math.nan, math.inf, 500.0])
def test_bad_altitude_is_refused(alt: float) -> None:
    v = Scripted(alt_m=alt)
    v.start()
    assert isinstance(v.outcome(), TakeoffFailed)
    assert v.failure().reason is FailReason.BAD_ALTITUDE
    assert v.sent == []


def test_budget_that_cannot_beat_auto_disarm_is_rejected() -> None:
    with pytest.raises(ValueError, match="COM_DISARM_PRFLT"):
        TakeoffConfig(command=SenderConfig(retries=30)).check()


def test_events_tell_the_story() -> None:
    link = ready_link()
    fly(link, 5.0)
    sent = [e.command for e in link.events if isinstance(e, CommandSent)]
    assert sent == ["COMPONENT_ARM_DISARM", "NAV_TAKEOFF"]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), loss=st.floats(0.0, 0.6))
def test_lossy_link_never_leaves_the_vehicle_armed_on_the_ground(seed: int, loss: float) -> None:
    """Whatever the channel loses, the outcome is consistent with the simulator's state."""
    rng = random.Random(seed)

    def lossy(msg: Message, direction: str, now: float) -> bool:
        return rng.random() < loss

    link = ready_link(drop=lossy)
    seq = TakeoffSequence(link.state, 5.0)
    link.start(seq)
    link.run_until(link.now + 30.0, stop=lambda: seq.done)
    assert seq.done
    link.run_until(link.now + 15.0)  # let auto-disarm / the climb play out
    if isinstance(seq.outcome, TakeoffSucceeded):
        assert link.sim.armed and link.sim.landed != LandedState.ON_GROUND
    else:
        assert not (link.sim.armed and link.sim.landed == LandedState.ON_GROUND)


GROUND_AMSL_M = 512.25  # where the vehicle stands when PX4 has no home yet
GPS_FIX = GpsRawInt(GpsFixType.FIX_3D, 12, 90, 473977420, 85455940, round(GROUND_AMSL_M * 1000))
GPS_NO_FIX = GpsRawInt(GpsFixType.FIX_2D, 4, 900, 473977420, 85455940, round(GROUND_AMSL_M * 1000))
HOME = HomePosition(0, 0, round(HOME_AMSL_M * 1000))
ESTIMATE = GlobalPositionInt(473977420, 85455940, round((GROUND_AMSL_M + 0.5) * 1000), 0)


@pytest.mark.parametrize(
    ("extra", "target", "ref"),
    [
        ((GPS_FIX, HOME), HOME_AMSL_M + 5.0, "home"),  # home wins over the current position
        ((GPS_FIX, ESTIMATE, HOME), HOME_AMSL_M + 5.0, "home"),
        ((GPS_FIX,), GROUND_AMSL_M + 5.0, "gps"),  # no home: where it stands (GPS, AMSL)
        ((GPS_FIX, ESTIMATE), GROUND_AMSL_M + 0.5 + 5.0, "global_position"),  # PX4's estimate
        ((GPS_NO_FIX, ESTIMATE), None, None),  # no fix: neither is trusted
        ((GPS_NO_FIX,), None, None),  # neither home nor a 3D fix
    ],
)
def test_ground_reference_is_home_then_the_current_gps_altitude(
    extra: tuple[Observation, ...], target: float | None, ref: str | None
) -> None:
    """Without a home (PX4 sets it only at arming), a relative altitude is measured from where
    the vehicle stands, by a GPS fix; without a fix it is refused ``no_home`` as before."""
    state, now = VehicleState(), 0.0
    for obs in (
        Heartbeat(12, 2, 1, MODE_LOITER.custom_mode, MavState.STANDBY),
        SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
        ExtendedSysState(LandedState.ON_GROUND),
        *extra,
    ):
        state.observe(obs, now)
    # readiness relaxed (no home, no fix required), so the ground reference alone decides
    relaxed = ReadinessConfig(require_home=False, min_fix_type=GpsFixType.NO_FIX)
    seq = TakeoffSequence(state, 5.0, readiness_config=relaxed)
    seq.start(now)
    sent = seq.commands_to_send()
    if target is None:
        assert isinstance(seq.outcome, TakeoffFailed)
        assert (seq.outcome.reason, seq.outcome.cause) == (FailReason.NOT_READY, "no_home")
        assert sent == []  # refused before arming
        return
    assert seq.phase is TakeoffPhase.ARMING and seq.target_amsl_m == pytest.approx(target)
    (arm,) = sent
    assert arm.command == MavCmd.COMPONENT_ARM_DISARM
    state.observe(Heartbeat(12, 2, 1 | 128, MODE_LOITER.custom_mode, MavState.ACTIVE), 0.1)
    seq.observe(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED, 0, 1, 191), 0.1)
    (takeoff,) = seq.commands_to_send()
    assert takeoff.command == MavCmd.NAV_TAKEOFF
    assert takeoff.params[6] == pytest.approx(target)  # param7: AMSL
    airborne = Heartbeat(12, 2, 1 | 128, MODE_TAKEOFF.custom_mode, MavState.ACTIVE)
    for obs in (airborne, ExtendedSysState(LandedState.IN_AIR)):
        state.observe(obs, 0.6)  # an ack timeout after NAV_TAKEOFF's send: fresh
        seq.observe(obs, 0.6)
    assert isinstance(seq.outcome, TakeoffSucceeded), seq.outcome
    assert seq.outcome.altitude_ref == ref and seq.outcome.target_amsl_m == pytest.approx(target)
