"""Two requests, one vehicle (docs/px4.md, "Two requests, one vehicle"): what runs when a
TAKEOFF, LAND, HOLD or ABORT meets a running task, on virtual time against the simulated PX4
(``tests.test_px4_vehicle.Bench``).

The attack: before, the vehicle core refused a second take-off (``busy``) and nothing else.
A LAND during a take-off ran beside it: the sequence went on, sent NAV_TAKEOFF after the
LAND's mode change and climbed, or waited for its altitude and reported success. Now every
pair meets ``vehicle.RULES``: a take-off never interrupts (``busy``); a LAND, HOLD or ABORT
supersedes the running task, which ends at once (``superseded: <kind>``) and sends nothing
after that. Each test asserts the wire after the supersede, both ``TaskFinished`` and the
vehicle's final state; ``Spy`` attributes every command on the wire to the task that sent it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from swarmd_lab.px4.sim_model import SimConfig

from swarmd.px4.command_sender import SenderTask
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
    MODE_TAKEOFF,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Px4Mode,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.takeoff import TakeoffPhase, TakeoffSequence
from swarmd.px4.vehicle import (
    RULES,
    Meet,
    TaskFinished,
    TaskKind,
    VehicleCore,
    VehicleRequest,
)
from tests.test_px4_vehicle import Bench

SLOW_SPOOL = SimConfig(gps_fix_after_s=0.5, spool_up_s=5.0)  # ARM accepted, long on the ground


class Spy:
    """Which task put each command on the wire. A task is *over* once a later task started
    or it was seen done (or superseded); a command it gives after that is ``late``."""

    def __init__(self) -> None:
        self.over: set[int] = set()
        self.started: list[SenderTask[Any]] = []
        self.late: list[tuple[str, list[VehicleCommand]]] = []

    @contextmanager
    def installed(self) -> Iterator[Spy]:
        spy = self
        commands_to_send = SenderTask.commands_to_send

        def collect(task: SenderTask[Any]) -> list[VehicleCommand]:
            out = commands_to_send(task)
            if id(task) in spy.over and out:
                spy.late.append((type(task).__name__, out))
            if task.done:
                spy.over.add(id(task))
            return out

        def start_of(cls: Any) -> Any:
            start = cls.start

            def started(task: Any, now: float) -> None:
                spy.over.update(id(t) for t in spy.started)
                spy.started.append(task)
                start(task, now)

            return started

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(SenderTask, "commands_to_send", collect)
            for cls in SenderTask.__subclasses__():
                mp.setattr(cls, "start", start_of(cls))
                if hasattr(cls, "supersede"):
                    supersede = cls.supersede

                    def superseded(
                        task: Any, now: float, why: str, _s: Any = supersede, **kw: Any
                    ) -> None:
                        spy.over.add(id(task))
                        _s(task, now, why, **kw)  # the take-off's ``disarms`` (review 18)

                    mp.setattr(cls, "supersede", superseded)
            yield self


@pytest.fixture
def spy() -> Iterator[Spy]:
    with Spy().installed() as s:
        yield s


def _after(b: Bench, mark: int) -> list[tuple[str, float, int]]:
    return [(c.label, c.params[0], c.confirmation) for c in b.sent[mark:]]


def _superseded(b: Bench, token: int, by: str) -> TaskFinished:
    done = b.finished(token)
    assert done is not None and (done.ok, done.reason) == (False, f"superseded: {by}")
    return done


def _lifting() -> Bench:
    """A take-off (token 1) whose NAV_TAKEOFF PX4 accepted: mode AUTO.TAKEOFF, armed, the
    motors spooling up (``SLOW_SPOOL``), the sequence waiting for lift-off."""
    b = Bench(SLOW_SPOOL)
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 10.0)
    seq = b.core.last_takeoff
    assert seq is not None
    b.run(5.0, stop=lambda: seq.phase is TakeoffPhase.LIFTING)
    assert seq.phase is TakeoffPhase.LIFTING and b.sim.mode == MODE_TAKEOFF
    return b


def _arming() -> Bench:
    """A take-off (token 1) whose ARM went out, the vehicle not yet armed in our state."""
    b = Bench(SLOW_SPOOL)
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    assert [c.command for c in b.sent] == [MavCmd.COMPONENT_ARM_DISARM]
    assert not b.core.state.armed
    return b


def _flying() -> Bench:
    b = Bench()
    b.fly()
    return b


# ---- the rule table --------------------------------------------------------------------


def test_every_pair_has_a_rule_and_only_a_takeoff_is_ever_busy() -> None:
    assert set(RULES) == {(a, b) for a in TaskKind for b in TaskKind}
    busy = {pair for pair, meet in RULES.items() if meet is Meet.BUSY}
    assert busy == {(a, TaskKind.TAKEOFF) for a in TaskKind}


# ---- running TAKEOFF -------------------------------------------------------------------


def test_takeoff_x_takeoff_is_busy_and_sends_nothing(spy: Spy) -> None:
    b = _arming()
    mark = len(b.sent)
    b.request(2, TaskKind.TAKEOFF, 4.0)
    busy = b.finished(2)
    assert busy is not None and (busy.ok, busy.reason) == (False, "busy")
    assert b.sent[mark:] == []
    b.run(30.0, stop=lambda: b.finished(1) is not None)
    first = b.finished(1)
    assert first is not None and first.ok
    assert spy.late == []


def test_land_before_liftoff_stops_the_takeoff_and_lands(spy: Spy) -> None:
    """The operator's case: LAND while the drone spools up to climb. [main: the take-off
    went on beside the LAND, failed no_liftoff 8 s later and sent its DISARM after it]"""
    b = _lifting()
    mark = len(b.sent)
    b.request(2, TaskKind.LAND)
    done = _superseded(b, 1, "land")
    assert "superseded by LAND (token 0x2)" in str(getattr(done.outcome, "detail", ""))
    b.run(30.0, stop=lambda: b.finished(2) is not None)
    land = b.finished(2)
    assert land is not None and land.ok
    b.run(15.0)
    assert b.sim.landed == LandedState.ON_GROUND and b.sim.alt_m == 0.0
    assert not b.sim.armed  # PX4's pre-flight disarm (COM_DISARM_PRFLT)
    assert {c[0] for c in _after(b, mark)} == {"NAV_LAND"}
    assert spy.late == []


def test_land_while_arming_never_lets_the_takeoff_send_nav_takeoff(spy: Spy) -> None:
    """[main: the sequence saw the arm and sent NAV_TAKEOFF after the LAND: the drone
    climbed to 4 m, the take-off reported success and the LAND ``not_confirmed``]"""
    b = _arming()
    mark = len(b.sent)
    b.request(2, TaskKind.LAND)
    _superseded(b, 1, "land")
    b.run(20.0)
    assert [c[0] for c in _after(b, mark)] == ["NAV_LAND"]  # no NAV_TAKEOFF, no DISARM
    land = b.finished(2)
    assert land is not None and land.ok
    assert b.sim.landed == LandedState.ON_GROUND and b.sim.alt_m == 0.0
    assert not b.sim.armed  # PX4's own pre-flight disarm (COM_DISARM_PRFLT) or the land's
    assert spy.late == []


def test_hold_before_liftoff_keeps_it_on_the_ground(spy: Spy) -> None:
    """[main: the take-off went on beside the HOLD, failed no_liftoff and sent a DISARM]"""
    b = _lifting()
    mark = len(b.sent)
    b.request(2, TaskKind.HOLD)
    _superseded(b, 1, "hold")
    b.run(15.0)
    hold = b.finished(2)
    assert hold is not None and hold.ok
    assert {c[0] for c in _after(b, mark)} == {"DO_SET_MODE"}
    assert b.sim.mode == MODE_LOITER and b.sim.landed == LandedState.ON_GROUND
    assert not b.sim.armed  # PX4's pre-flight disarm (COM_DISARM_PRFLT)
    assert spy.late == []


@pytest.mark.parametrize("phase", ["arming", "lifting"])
def test_abort_of_a_takeoff_on_the_ground_disarms_once_through_its_own_task(
    spy: Spy, phase: str
) -> None:
    """ARM went out (arming: the state not armed yet; lifting: armed, NAV_TAKEOFF accepted):
    the ABORT's one DISARM follows it on the link, never forced. [main: the take-off's
    DISARM, then the ABORT's, two tasks on one command number]"""
    b = _arming() if phase == "arming" else _lifting()
    mark = len(b.sent)
    b.request(2, TaskKind.ABORT)
    _superseded(b, 1, "abort")
    b.run(10.0, stop=lambda: b.finished(2) is not None)
    abort = b.finished(2)
    assert abort is not None and (abort.ok, abort.reason) == (True, "COMPONENT_ARM_DISARM")
    disarms = _after(b, mark)
    assert {(c[0], c[1]) for c in disarms} == {("COMPONENT_ARM_DISARM", 0.0)}
    assert [c[2] for c in disarms] == list(range(len(disarms)))  # one command, its retries
    b.run(2.0)
    assert not b.sim.armed and b.sim.landed == LandedState.ON_GROUND
    assert spy.late == []


# ---- running LAND, HOLD or ABORT, in the air --------------------------------------------
# Each pair by itself (pytest ids ``land-abort`` ...): the running task is asked for in the
# air and the new request a moment later, while it still waits for its effect.

L, H, A, T = TaskKind.LAND, TaskKind.HOLD, TaskKind.ABORT, TaskKind.TAKEOFF


@pytest.mark.parametrize(
    ("running", "new", "reason", "lands"),
    [
        (L, H, "", False),  # the HOLD wins, as it would once the LAND is confirmed
        (L, A, "NAV_LAND", True),
        (H, L, "", True),  # [main: the HOLD saw AUTO.LOITER a moment before and said done]
        (H, A, "NAV_LAND", True),
        (A, L, "", True),
        (A, H, "", False),  # explicit, as after the ABORT's LAND is confirmed (PX4's rule)
        (A, A, "NAV_LAND", True),
    ],
    ids=[
        "land-hold",
        "land-abort",
        "hold-land",
        "hold-abort",
        "abort-land",
        "abort-hold",
        "abort-abort",
    ],
)
def test_in_the_air_the_later_stop_wins(
    spy: Spy, running: TaskKind, new: TaskKind, reason: str, lands: bool
) -> None:
    """[main: both tasks ran and each reported on its own; none was superseded]"""
    b = _flying()
    b.request(2, running)
    b.request(3, new)
    _superseded(b, 2, str(new))
    b.run(30.0, stop=lambda: b.sim.landed == LandedState.ON_GROUND)
    done = b.finished(3)
    assert done is not None and (done.ok, done.reason) == (True, reason)
    if lands:
        assert b.sim.landed == LandedState.ON_GROUND
    else:
        assert b.sim.mode == MODE_LOITER and b.sim.landed == LandedState.IN_AIR
    assert spy.late == []


@pytest.mark.parametrize("running", [L, A], ids=str)
def test_a_takeoff_meeting_a_land_or_abort_is_busy_never_undoing_it(
    spy: Spy, running: TaskKind
) -> None:
    """[main: the take-off ran beside it, refused ``not_ready: armed`` only by luck]"""
    b = _flying()
    b.request(2, running)
    mark = len(b.sent)
    b.request(3, T, 4.0)
    busy = b.finished(3)
    assert busy is not None and (busy.ok, busy.reason) == (False, "busy")
    assert b.sent[mark:] == []
    b.run(30.0, stop=lambda: b.sim.landed == LandedState.ON_GROUND)
    first = b.finished(2)
    assert first is not None and first.ok and b.sim.landed == LandedState.ON_GROUND
    assert spy.late == []


def test_hold_x_takeoff_is_busy_and_nothing_arms(spy: Spy) -> None:
    """On the ground (a HOLD there is a mode switch). [main: the take-off ran beside the
    HOLD, armed and climbed]"""
    b = Bench()
    b.run(3.0)
    b.request(2, H)
    mark = len(b.sent)
    b.request(3, T, 4.0)
    busy = b.finished(3)
    assert busy is not None and (busy.ok, busy.reason) == (False, "busy")
    b.run(10.0)
    assert {c.command for c in b.sent[mark:]} <= {MavCmd.DO_SET_MODE}
    assert not b.sim.armed and b.sim.landed == LandedState.ON_GROUND
    assert spy.late == []


@pytest.mark.parametrize(("kind", "label"), [(L, "NAV_LAND"), (H, "DO_SET_MODE")], ids=str)
def test_the_same_stop_twice_only_the_later_retransmits(
    spy: Spy, kind: TaskKind, label: str
) -> None:
    """PX4 hears no more commands and its mode is not the one asked for (AUTO.LOITER for
    a LAND; AUTO.LAND for a HOLD): only the later task retransmits. [main: both did,
    confirmations 0 0 1 1 2 2 3 3]"""
    b = _flying()
    if kind is H:
        assert b.run_task(2, L).ok
    b.drop = lambda msg, direction: direction == "down"
    mark = len(b.sent)
    b.request(3, kind)
    b.request(4, kind)
    _superseded(b, 3, str(kind))
    b.run(10.0, stop=lambda: b.finished(4) is not None)
    last = b.finished(4)
    assert last is not None and (last.ok, last.reason) == (False, "no_ack")
    assert [(c[0], c[2]) for c in _after(b, mark)] == [(label, i) for i in (0, 0, 1, 2, 3)]
    assert spy.late == []


# ---- the failed take-off's DISARM ------------------------------------------------------


def _failed_takeoff() -> Bench:
    """A take-off that armed, then got no answer to NAV_TAKEOFF: it sent its one DISARM."""
    b = Bench(SLOW_SPOOL)
    b.run(3.0)
    b.drop = lambda msg, direction: (
        isinstance(msg, VehicleCommand) and msg.command == MavCmd.NAV_TAKEOFF
    )
    done = b.run_task(1, TaskKind.TAKEOFF, 4.0)
    assert (done.ok, done.reason) == (False, "takeoff_no_ack")
    assert b.sent[-1].command == MavCmd.COMPONENT_ARM_DISARM and b.sent[-1].params[0] == 0.0
    b.drop = None
    return b


@pytest.mark.parametrize("kind", [TaskKind.ABORT, TaskKind.HOLD, TaskKind.TAKEOFF])
def test_a_failed_takeoffs_disarm_x_a_new_request(spy: Spy, kind: TaskKind) -> None:
    """The DISARM is no task: nothing to supersede, the new request runs; its answer is
    owed (``OwedAcks``) and settles none of the new task's commands."""
    b = _failed_takeoff()
    done = b.run_task(2, kind, 4.0 if kind is TaskKind.TAKEOFF else None)
    b.run(12.0)
    assert not b.sim.armed and b.sim.landed == LandedState.ON_GROUND
    if kind is TaskKind.ABORT:
        assert done.ok and done.reason in ("COMPONENT_ARM_DISARM", "on_ground_disarmed")
    elif kind is TaskKind.HOLD:
        assert done.ok
    else:
        # armed still in our state, or the DISARM through: either way never a false arm
        assert done.reason in ("not_ready: armed", "takeoff_no_ack") or done.ok
    assert spy.late == []


# ---- owed answers of the superseded task -----------------------------------------------


def _ready(mode: Px4Mode, *, in_air: bool, now: float = 0.0) -> VehicleCore:
    """A core whose state says: PX4, pre-arm checks passed, 3D fix, home; armed and in the
    air, or disarmed on the ground (ready to take off)."""
    core = VehicleCore()
    armed, status = (128, MavState.ACTIVE) if in_air else (0, MavState.STANDBY)
    landed = LandedState.IN_AIR if in_air else LandedState.ON_GROUND
    for obs in (
        Heartbeat(12, 2, 1 | armed, mode.custom_mode, status),
        SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
        ExtendedSysState(landed),
        GpsRawInt(GpsFixType.FIX_3D, 12),
        HomePosition(0, 0, 488000),
    ):
        core.receive_datagram(obs, None, now)
    return core


def test_the_superseded_lands_late_refusal_does_not_fail_the_later_land() -> None:
    """Both LANDs send NAV_LAND (one number); the first one's answer DENIED arrives after the
    second was sent. It is the superseded task's debt, paid and dropped. [main: both tasks
    took it, the later LAND failed DENIED]"""
    core = _ready(MODE_LOITER, in_air=True)
    core.request(VehicleRequest(1, TaskKind.LAND), 1.0)
    core.request(VehicleRequest(2, TaskKind.LAND), 1.1)
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.NAV_LAND] * 2
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.DENIED), None, 1.2)
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.ACCEPTED), None, 1.21)
    # fresh: received an ack timeout after the later LAND's send (docs/px4.md, "Fresh state")
    core.receive_datagram(Heartbeat(12, 2, 1 | 128, MODE_LAND.custom_mode, 4), None, 1.6)
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(e.token, e.ok, e.reason) for e in ends] == [
        (1, False, "superseded: land"),
        (2, True, ""),
    ]
    assert core.owed.paid == 1
    assert core.datagrams_to_send() == []


def test_the_superseded_takeoffs_late_arm_answer_does_not_settle_the_aborts_disarm() -> None:
    """ARM and DISARM share COMPONENT_ARM_DISARM: the ARM's ACCEPTED, late, is owed."""
    core = _ready(MODE_LOITER, in_air=False)
    core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0), 1.0)
    assert [c.params[0] for c in core.datagrams_to_send()] == [1.0]  # ARM
    core.request(VehicleRequest(2, TaskKind.ABORT), 1.1)
    assert [c.params[0] for c in core.datagrams_to_send()] == [0.0]  # the ABORT's DISARM
    paid = core.owed.paid
    core.receive_datagram(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED), None, 1.2)
    assert core.owed.paid == paid + 1  # the ARM's answer, not the DISARM's
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(e.token, e.reason) for e in ends] == [(1, "superseded: abort")]
    # the disarmed HEARTBEAT held since 0.0 predates the ARM: only a fresh one confirms
    core.receive_datagram(Heartbeat(12, 2, 1, MODE_LOITER.custom_mode, 3), None, 1.7)
    ends = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(e.token, e.reason) for e in ends] == [
        (2, "COMPONENT_ARM_DISARM"),  # by a fresh state (disarmed), never by the ARM's answer
    ]
    assert core.last_takeoff is not None and core.last_takeoff.phase is TakeoffPhase.FAILED
    assert core.datagrams_to_send() == []  # nothing from the take-off, ever again


# ---- any order -------------------------------------------------------------------------

KINDS = st.sampled_from(list(TaskKind))


@settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    plan=st.lists(st.tuples(KINDS, st.floats(0.0, 6.0)), min_size=1, max_size=6),
    lossy=st.booleans(),
)
def test_any_interleaving_one_end_per_request_and_no_late_command(
    plan: list[tuple[TaskKind, float]], lossy: bool
) -> None:
    """Requests of any kinds at any gaps (a quarter of acks lost, or none): every request
    ends in exactly one ``TaskFinished``, and no task puts a command on the wire once a later
    one started or once it ended. Bounded: at most 6 requests, 6 s apart, 30 s after."""
    with Spy().installed() as spy:
        b = Bench()
        b.run(3.0)
        if lossy:
            count = iter(range(10**6))
            b.drop = lambda msg, direction: isinstance(msg, CommandAck) and next(count) % 4 == 0
        for token, (kind, gap) in enumerate(plan, start=1):
            b.run(gap)
            b.request(token, kind, 4.0 if kind is TaskKind.TAKEOFF else None)
        b.run(30.0, stop=lambda: not b.core.busy())
        ends = [e.token for e in b.events if isinstance(e, TaskFinished)]
        assert sorted(ends) == list(range(1, len(plan) + 1))
        assert spy.late == []
        assert len(b.core._tasks) <= 1  # noqa: SLF001 - the invariant the rules keep


def test_the_spy_sees_a_task_that_sends_after_a_later_one_started() -> None:
    """The property above would catch the defect: two tasks at once, the older sending."""
    with Spy().installed() as spy:
        vehicle = _ready(MODE_LOITER, in_air=False).state
        first = TakeoffSequence(vehicle, None)
        first.start(0.0)
        first.commands_to_send()
        second = TakeoffSequence(vehicle, None)
        second.start(0.1)
        first.handle_timer(0.6)  # the first one retransmits ARM
        first.commands_to_send()
        assert spy.late and spy.late[0][0] == "TakeoffSequence"
