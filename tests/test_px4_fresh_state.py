"""The state that confirms an action must be newer than the action (docs/px4.md, "Fresh
state"; docs/security.md, case 2c).

The attack: an ABORT that supersedes a take-off right after its ARM sends its own DISARM and,
before, took the HEARTBEAT it already held ("disarmed", from before the ARM took effect) as
its success, at the next message of any kind. When that DISARM is lost while the ARM got
through, the operator was told "disarmed" with the vehicle armed on the ground until PX4's
pre-flight disarm (``COM_DISARM_PRFLT``, 10 s; never, when the parameter is 0). The same
held for LAND and HOLD: a mode a superseded command was about to change confirmed the later
one. Now a state counts only when it was received at least one ack timeout after the
action's command was first sent (``actions.fresh_after``): a HEARTBEAT in flight when the
command left, which PX4 sent before the command (or an earlier one) reached it, does not.

On virtual time against the simulated PX4 (``Witness``: the ``Bench`` of
``tests.test_px4_vehicle`` that also notes the simulated vehicle's state at the moment each
task reports), and scripted where the simulator never answers so.
"""

from __future__ import annotations

import copy
import random

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from swarmd_lab.px4.sim_model import SimConfig

from swarmd.px4.actions import NOT_CONFIRMED, ActionFinished, ActionKind, VehicleAction
from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
)
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    Px4Mode,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.readiness import VehicleState
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleRequest
from tests.test_px4_stale_ack import _run_until_timer_settles
from tests.test_px4_vehicle import Bench

SLOW_SPOOL = SimConfig(gps_fix_after_s=0.5, spool_up_s=5.0)  # ARM accepted, long on the ground
DISARM_LABEL = "COMPONENT_ARM_DISARM"

# what the simulated vehicle is, when a task reports: (armed, mode, landed_state)
Seen = tuple[bool, Px4Mode, LandedState]


class Witness(Bench):
    """``Bench`` with a chosen one-way latency, and the simulated vehicle's state noted at
    the moment each ``TaskFinished`` comes out of the core (``seen``)."""

    def __init__(self, config: SimConfig | None = None, latency_s: float = 0.005) -> None:
        super().__init__(config, latency_s=latency_s)
        self.seen: dict[int, Seen] = {}

    def _pump_core(self) -> None:
        mark = len(self.events)
        super()._pump_core()
        for event in self.events[mark:]:
            if isinstance(event, TaskFinished):
                self.seen[event.token] = self._landing()

    def _landing(self) -> Seen:
        """The simulated vehicle once the commands already on their way down reach it: what
        a task reports must hold then too (a copy; the bench itself moves on untouched)."""
        future = copy.deepcopy(self.sim)
        for at, _, direction, msg in sorted(self._queue, key=lambda q: (q[0], q[1])):
            if direction == "down":
                assert isinstance(msg, VehicleCommand)
                future.receive(msg, (future.config.sysid, 191), at)
        return (future.armed, future.mode, future.landed)


class LoseFirst:
    """A ``Bench.drop`` rule: lose the first ``count`` commands ``command`` (with param1
    ``p1``, when given) on the way down; ``lost`` keeps them."""

    def __init__(self, command: MavCmd, p1: float | None = None, count: int = 1) -> None:
        self.command, self.p1, self.count = command, p1, count
        self.lost: list[VehicleCommand] = []

    def __call__(self, msg: Observation | VehicleCommand, direction: str) -> bool:
        if len(self.lost) >= self.count or not isinstance(msg, VehicleCommand):
            return False
        if msg.command != self.command or (self.p1 is not None and msg.params[0] != self.p1):
            return False
        self.lost.append(msg)
        return True


def _arming(latency_s: float = 0.005) -> Witness:
    """A take-off (token 1) whose ARM just went out; the state still says disarmed."""
    b = Witness(SLOW_SPOOL, latency_s)
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    assert [(c.command, c.params[0]) for c in b.sent] == [(MavCmd.COMPONENT_ARM_DISARM, 1.0)]
    assert b.core.state.armed is False
    return b


def _disarms(b: Bench) -> list[int]:
    """The confirmation counts of every DISARM on the wire (ours, never forced)."""
    return [
        c.confirmation
        for c in b.sent
        if c.command == MavCmd.COMPONENT_ARM_DISARM and c.params[0] == 0.0
    ]


# ---- DISARM: an ABORT right after a take-off's ARM -----------------------------------------


def test_an_abort_right_after_arm_whose_disarm_is_lost_retransmits_and_is_true() -> None:
    """The residual h-busy15 left: ABORT supersedes a take-off whose ARM just left; the
    ABORT's DISARM is lost, the ARM gets through. The DISARM is sent again after the ack
    timeout and the ABORT reports done only once a HEARTBEAT newer than it says disarmed.
    [main: done at the next message, on the HEARTBEAT already in flight; no DISARM sent
    again; the simulated vehicle armed on the ground]"""
    b = _arming()
    lose = LoseFirst(MavCmd.COMPONENT_ARM_DISARM, p1=0.0)
    b.drop = lose
    b.request(2, TaskKind.ABORT)
    b.run(10.0, stop=lambda: b.finished(2) is not None)
    abort = b.finished(2)
    assert abort is not None and len(lose.lost) == 1
    armed, _, landed = b.seen[2]
    assert not armed and landed == LandedState.ON_GROUND
    assert (abort.ok, abort.reason) == (True, DISARM_LABEL)
    assert _disarms(b)[:2] == [0, 1]  # the sender's retransmission, not a second command
    b.run(1.0)
    assert not b.sim.armed


def test_an_abort_whose_every_disarm_is_lost_fails_and_says_so() -> None:
    """Every DISARM lost, the ARM through: the ABORT ends not ok (``no_ack``) and the operator
    is told; the vehicle is armed on the ground. [main: reported done, ``COMPONENT_ARM_DISARM``]"""
    b = _arming()
    b.drop = LoseFirst(MavCmd.COMPONENT_ARM_DISARM, p1=0.0, count=10)
    b.request(2, TaskKind.ABORT)
    b.run(10.0, stop=lambda: b.finished(2) is not None)
    abort = b.finished(2)
    assert abort is not None and not abort.ok
    assert abort.reason in ("no_ack", NOT_CONFIRMED)
    assert b.seen[2][0]  # armed: what the failure warns of
    assert _disarms(b) == [0, 1, 2, 3]


def test_an_abort_after_a_cancelled_takeoffs_disarm_is_lost_still_disarms() -> None:
    """A take-off cancelled just after its ARM left sends its one DISARM (abandoned); that is
    lost. An ABORT a moment later holds a state that says "disarmed on the ground", older than
    the ARM: it must not say ``on_ground_disarmed`` from it, but disarm and see it.
    [main: ``on_ground_disarmed`` at once, nothing sent, the vehicle armed]"""
    b = _arming()
    b.drop = LoseFirst(MavCmd.COMPONENT_ARM_DISARM, p1=0.0)
    b.core.cancel(1, b.now, "the member stopped")
    b.request(2, TaskKind.ABORT)
    b.run(10.0, stop=lambda: b.finished(2) is not None)
    abort = b.finished(2)
    assert abort is not None and not b.seen[2][0]
    assert (abort.ok, abort.reason) == (True, DISARM_LABEL)
    b.run(1.0)
    assert not b.sim.armed


def test_an_abort_long_after_the_last_arm_needs_nothing() -> None:
    """On the ground, disarmed, the last ARM long answered by fresh heartbeats: nothing to do
    (``on_ground_disarmed``), nothing sent. The freshness rule costs this case nothing."""
    b = Witness(SLOW_SPOOL)
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    b.run(0.2)
    b.core.cancel(1, b.now, "the member stopped")  # its DISARM gets through
    b.run(3.0)
    mark = len(b.sent)
    done = b.run_task(2, TaskKind.ABORT)
    assert (done.ok, done.reason) == (True, "on_ground_disarmed")
    assert b.sent[mark:] == []


# ---- LAND and HOLD: a mode a superseded command was about to change ------------------------


def _flying() -> Witness:
    b = Witness()
    b.fly()
    return b


def _stop_then_stop(
    b: Witness, token: int, first: TaskKind, then: TaskKind, *, lost: MavCmd
) -> TaskFinished:
    """``first`` (token ``token``) and at once ``then`` (``token + 1``), whose command
    ``lost`` is lost once on the way down; ``then``'s end (bounded: 10 s)."""
    b.drop = LoseFirst(lost)
    b.request(token, first)
    b.request(token + 1, then)
    b.run(10.0, stop=lambda: b.finished(token + 1) is not None)
    done = b.finished(token + 1)
    assert done is not None
    return done


def test_a_land_right_after_a_hold_whose_nav_land_is_lost_is_not_done_hovering() -> None:
    """Landing (AUTO.LAND), then HOLD and at once LAND (the last stop wins). The HOLD's mode
    change gets through, the LAND's NAV_LAND is lost. The state in hand says AUTO.LAND,
    LANDING: from before the HOLD reached PX4. [main: the LAND done at the next message, the
    vehicle hovering in AUTO.LOITER]"""
    b = _flying()
    assert b.run_task(2, TaskKind.LAND).ok
    b.run(0.5)
    land = _stop_then_stop(b, 3, TaskKind.HOLD, TaskKind.LAND, lost=MavCmd.NAV_LAND)
    assert (land.ok, land.reason) == (True, "")
    assert b.seen[4][1] == MODE_LAND
    assert [c.confirmation for c in b.sent if c.command == MavCmd.NAV_LAND][-2:] == [0, 1]


def test_a_hold_right_after_a_land_whose_mode_change_is_lost_is_not_done_landing() -> None:
    """In the air in AUTO.LOITER (take-off done), LAND and at once HOLD. NAV_LAND gets through,
    the HOLD's DO_SET_MODE is lost; the heartbeat in hand says AUTO.LOITER, from before the
    LAND. [main: the HOLD done at the next message, the vehicle landing]"""
    b = _flying()
    b.run(1.5)  # a heartbeat since the climb ended: the state in hand says AUTO.LOITER
    held = b.core.state.heartbeat
    assert b.sim.mode == MODE_LOITER and held is not None and held.mode == MODE_LOITER
    hold = _stop_then_stop(b, 2, TaskKind.LAND, TaskKind.HOLD, lost=MavCmd.DO_SET_MODE)
    assert (hold.ok, hold.reason) == (True, "")
    assert b.seen[3][1] == MODE_LOITER
    assert b.sim.landed == LandedState.IN_AIR


# ---- scripted: the state already right before the send ------------------------------------


def _state(mode: Px4Mode, *, armed: bool, landed: LandedState, at: float) -> VehicleState:
    v = VehicleState()
    for obs in _status(mode, armed=armed, landed=landed):
        v.observe(obs, at)
    return v


def _status(mode: Px4Mode, *, armed: bool, landed: LandedState) -> list[Observation]:
    status = MavState.ACTIVE if armed else MavState.STANDBY
    return [
        Heartbeat(12, 2, 1 | (128 if armed else 0), mode.custom_mode, status),
        SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
        ExtendedSysState(landed),
        GpsRawInt(GpsFixType.FIX_3D, 12),
        HomePosition(0, 0, 488000),
    ]


def _ended(action: VehicleAction) -> ActionFinished | None:
    """The outcome, read through a call (mypy would keep an asserted None narrowed)."""
    return action.outcome


ALREADY = {
    ActionKind.DISARM: (MODE_LOITER, False, LandedState.ON_GROUND, MavCmd.COMPONENT_ARM_DISARM),
    ActionKind.HOLD: (MODE_LOITER, True, LandedState.IN_AIR, MavCmd.DO_SET_MODE),
    ActionKind.LAND: (MODE_LAND, True, LandedState.LANDING, MavCmd.NAV_LAND),
}


@pytest.mark.parametrize("kind", list(ALREADY), ids=str)
def test_the_effect_already_in_state_counts_only_from_a_message_newer_than_the_send(
    kind: ActionKind,
) -> None:
    """The state shows the effect before the command leaves (already disarmed, already in
    AUTO.LOITER, already landing). Messages in flight when it left, and its ACCEPTED, do not
    confirm it; the first HEARTBEAT (or, for LAND, EXTENDED_SYS_STATE) received one ack
    timeout after the send does. [main: done at the first message after the send]"""
    mode, armed, landed, command = ALREADY[kind]
    v = _state(mode, armed=armed, landed=landed, at=0.0)
    action = VehicleAction(v, kind)
    action.start(1.0)
    assert [c.command for c in action.commands_to_send()] == [command]
    in_flight = [
        *_status(mode, armed=armed, landed=landed),
        CommandAck(command, MavResult.ACCEPTED),
    ]
    for i, obs in enumerate(in_flight):
        t = 1.01 + i * 0.01
        v.observe(obs, t)
        action.observe(obs, t)
    assert _ended(action) is None
    newer = _status(mode, armed=armed, landed=landed)[0 if kind is not ActionKind.LAND else 2]
    v.observe(newer, 1.6)
    action.observe(newer, 1.6)
    done = _ended(action)
    assert done is not None and done.ok


def test_a_disarm_in_flight_heartbeat_then_armed_ends_not_confirmed() -> None:
    """ABORT right after ARM: the HEARTBEAT in flight says disarmed (PX4 sent it before the ARM
    reached it), PX4 then ACCEPTs the DISARM, yet every newer HEARTBEAT says armed. The ABORT
    ends ``not_confirmed``, never done. [main: done on the heartbeat in flight]"""
    core = VehicleCore()
    for obs in _status(MODE_LOITER, armed=False, landed=LandedState.ON_GROUND):
        core.receive_datagram(obs, None, 0.9)
    core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0), 1.0)
    core.request(VehicleRequest(2, TaskKind.ABORT), 1.0)
    assert [c.params[0] for c in core.datagrams_to_send()] == [1.0, 0.0]  # ARM, DISARM
    feed: list[tuple[float, Observation]] = [
        (1.01, _status(MODE_LOITER, armed=False, landed=LandedState.ON_GROUND)[0]),
        (1.02, CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)),  # the ARM's: owed
        (1.03, CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)),  # the DISARM's
    ]
    feed += [
        (2.0 + i, _status(MODE_LOITER, armed=True, landed=LandedState.ON_GROUND)[0])
        for i in range(5)
    ]
    _run_until_timer_settles(core, feed)
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    abort = next(e for e in ends if e.token == 2)
    assert (abort.ok, abort.reason) == (False, NOT_CONFIRMED)


# ---- any order, any loss, any heartbeat timing ---------------------------------------------

KINDS = st.sampled_from([TaskKind.TAKEOFF, TaskKind.LAND, TaskKind.HOLD, TaskKind.ABORT])
# at once, within a round trip, within a heartbeat period, or later: the races are short
GAPS = st.one_of(st.just(0.0), st.floats(0.0, 0.3), st.floats(0.0, 3.0))


def _claim_holds(done: TaskFinished, kind: TaskKind, seen: Seen) -> bool:
    """Is the vehicle, when ``done`` reports success, in the state it claims?"""
    armed, mode, landed = seen
    if kind is TaskKind.ABORT and done.reason in (DISARM_LABEL, "on_ground_disarmed"):
        return not armed
    if kind is TaskKind.LAND or (kind is TaskKind.ABORT and done.reason == "NAV_LAND"):
        return mode == MODE_LAND
    if kind is TaskKind.HOLD:
        return mode == MODE_LOITER
    if kind is TaskKind.TAKEOFF:
        return armed and landed in (LandedState.TAKEOFF, LandedState.IN_AIR)
    return False


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    plan=st.lists(st.tuples(KINDS, GAPS), min_size=1, max_size=5),
    start=st.floats(0.0, 1.0),
    latency_s=st.sampled_from([0.001, 0.005, 0.05, 0.2]),
    loss=st.sampled_from([0.0, 0.25, 0.5]),
    seed=st.integers(0, 2**32 - 1),
)
# the residual itself (ABORT at once after TAKEOFF, the seed loses its DISARM, not the ARM),
# and a LAND between them (the ABORT judged "on_ground_disarmed" with the ARM in flight):
# the two shapes the search found on main, kept so every run tries them
@example(
    plan=[(TaskKind.TAKEOFF, 0.0), (TaskKind.ABORT, 0.0)],
    start=0.0,
    latency_s=0.005,
    loss=0.25,
    seed=7,
)
@example(
    plan=[(TaskKind.TAKEOFF, 0.0), (TaskKind.LAND, 0.0), (TaskKind.ABORT, 0.0)],
    start=0.0,
    latency_s=0.001,
    loss=0.0,
    seed=0,
)
def test_success_only_when_the_vehicle_is_in_the_claimed_state(
    plan: list[tuple[TaskKind, float]],
    start: float,
    latency_s: float,
    loss: float,
    seed: int,
) -> None:
    """Requests of any kinds at any gaps (so at any point of PX4's 1 Hz heartbeat), with a
    one-way latency up to 0.2 s and a share of commands, acks and heartbeats lost: every
    success a task reports is true of the simulated vehicle then, counting the commands
    already on their way to it. Bounded: 5 requests, 3 s apart, 20 s after."""
    b = Witness(SimConfig(gps_fix_after_s=0.5, spool_up_s=2.0), latency_s)
    rng = random.Random(seed)

    def lossy(msg: Observation | VehicleCommand, direction: str) -> bool:
        carries = isinstance(msg, (VehicleCommand, CommandAck, Heartbeat))
        return carries and rng.random() < loss

    b.run(3.0 + start)
    b.drop = lossy
    kinds: dict[int, TaskKind] = {}
    for token, (kind, gap) in enumerate(plan, start=1):
        b.run(gap)
        kinds[token] = kind
        b.request(token, kind, 4.0 if kind is TaskKind.TAKEOFF else None)
    b.run(20.0, stop=lambda: not b.core.busy())
    for event in b.events:
        if isinstance(event, TaskFinished) and event.ok:
            kind = kinds[event.token]
            assert _claim_holds(event, kind, b.seen[event.token]), (kind, event, b.seen)


# ---- the take-off: its steps cannot be confirmed by a state from before its command -------
# Readiness pins the state it starts from (a HEARTBEAT heard within 2.5 s: disarmed, STANDBY;
# EXTENDED_SYS_STATE on the ground), and both links deliver in order (MAVLink: signed
# timestamps per stream; XRCE: a stale best-effort sequence number is dropped). So the armed
# bit or a lift-off that confirms ARM or NAV_TAKEOFF came in a message PX4 sent after the
# one readiness read: never the last arming or the last flight. These pin that.


def _takeoff_after(before: list[Observation], ready: list[Observation]) -> VehicleCore:
    """A take-off requested while ``before`` is the state (refused), then again once
    ``ready`` (the vehicle since disarmed, or landed) has been heard."""
    core = VehicleCore()
    for obs in before:
        core.receive_datagram(obs, None, 0.0)
    core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0), 0.1)
    assert core.datagrams_to_send() == []  # not ready: nothing sent
    for obs in ready:
        core.receive_datagram(obs, None, 0.9)
    core.request(VehicleRequest(2, TaskKind.TAKEOFF, 4.0), 1.0)
    return core


def test_a_takeoff_after_a_disarm_is_never_armed_by_the_last_arming() -> None:
    """PX4 was armed (the last arming) and has disarmed since; every ARM is lost. No armed
    HEARTBEAT from before confirms the ARM: NAV_TAKEOFF is never sent, ``arm_no_ack``."""
    core = _takeoff_after(
        _status(MODE_LOITER, armed=True, landed=LandedState.ON_GROUND),
        _status(MODE_LOITER, armed=False, landed=LandedState.ON_GROUND),
    )
    feed: list[tuple[float, Observation]] = [
        (1.5 + i, _status(MODE_LOITER, armed=False, landed=LandedState.ON_GROUND)[0])
        for i in range(6)
    ]
    _run_until_timer_settles(core, feed)
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(e.token, e.ok, e.reason) for e in ends] == [
        (1, False, "not_ready: armed"),
        (2, False, "arm_no_ack"),
    ]
    assert MavCmd.NAV_TAKEOFF not in [c.command for c in core.datagrams_to_send()]


def test_a_takeoff_after_a_flight_is_never_airborne_by_the_last_flight() -> None:
    """The last flight's IN_AIR is held (refused: not on the ground); once PX4 says ON_GROUND
    the take-off arms, and every NAV_TAKEOFF is lost. Nothing from the last flight confirms
    it: ``takeoff_no_ack``, never a success."""
    core = _takeoff_after(
        _status(MODE_LOITER, armed=False, landed=LandedState.IN_AIR),
        _status(MODE_LOITER, armed=False, landed=LandedState.ON_GROUND),
    )
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.COMPONENT_ARM_DISARM]
    feed: list[tuple[float, Observation]] = [
        (1.05, CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)),
    ]
    feed += [
        (1.5 + 0.5 * i, _status(MODE_LOITER, armed=True, landed=LandedState.ON_GROUND)[j])
        for i in range(8)
        for j in (0, 2)
    ]
    _run_until_timer_settles(core, feed)
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(e.token, e.ok) for e in ends] == [(1, False), (2, False)]
    assert ends[0].reason == "not_ready: not_on_ground" and ends[1].reason == "takeoff_no_ack"
