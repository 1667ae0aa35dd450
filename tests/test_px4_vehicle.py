"""The vehicle core on virtual time: take-off, LAND, HOLD and ABORT against the simulated
PX4 (``swarmd_lab.px4.sim_model``), and scripted answers for what the simulator never says."""

from __future__ import annotations

import heapq
import itertools
import random
from collections.abc import Callable

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle

from swarmd.px4.actions import NOT_CONFIRMED, ActionFinished, ActionKind, VehicleAction
from swarmd.px4.command_sender import CommandSent
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
    BootClock,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.readiness import Reason, VehicleState
from swarmd.px4.takeoff import TakeoffSucceeded
from swarmd.px4.vehicle import (
    ON_GROUND_DISARMED,
    ReadinessChanged,
    TaskFinished,
    TaskKind,
    VehicleCore,
    VehicleEvent,
    VehicleRequest,
)

LATENCY_S = 0.005
Drop = Callable[[Observation | VehicleCommand, str], bool]


class Bench:
    """A ``SimVehicle`` and a ``VehicleCore`` joined on virtual time, no codec, no loop."""

    def __init__(
        self,
        config: SimConfig | None = None,
        drop: Drop | None = None,
        latency_s: float = LATENCY_S,  # one way, each direction
    ) -> None:
        self.now = 0.0
        self.latency_s = latency_s
        self.sim = SimVehicle(config or SimConfig(gps_fix_after_s=0.5), random.Random(1), 0.0)
        self.core = VehicleCore()
        self.drop = drop
        self.events: list[VehicleEvent] = []
        self.sent: list[VehicleCommand] = []
        self._queue: list[tuple[float, int, str, Observation | VehicleCommand | BootClock]] = []
        self._seq = itertools.count()

    def run(self, seconds: float, stop: Callable[[], bool] | None = None) -> None:
        end = self.now + seconds
        while not (stop is not None and stop()):
            candidates = [self.sim.get_timer()]
            if self._queue:
                candidates.append(self._queue[0][0])
            if (timer := self.core.get_timer()) is not None:
                candidates.append(timer)
            t = min(candidates)
            if t > end:
                self.now = end
                return
            self.now = max(self.now, t)
            if self._queue and self._queue[0][0] <= self.now:
                _, _, direction, msg = heapq.heappop(self._queue)
                self._deliver(direction, msg)
            elif self.sim.get_timer() <= self.now:
                self.sim.handle_timer(self.now)
                self._pump_sim()
            else:
                self.core.handle_timer(self.now)
            self._pump_core()

    def _deliver(self, direction: str, msg: Observation | VehicleCommand | BootClock) -> None:
        """A message reaches its side now (down: the vehicle, up: the core)."""
        if direction == "down":
            assert isinstance(msg, VehicleCommand)
            self.sim.receive(msg, (self.sim.config.sysid, 191), self.now)
            self._pump_sim()
        elif not isinstance(msg, VehicleCommand | BootClock):  # BootClock: MAVLink's alone
            self.core.receive_datagram(msg, None, self.now)

    def request(self, token: int, kind: TaskKind, alt_m: float | None = None) -> None:
        self.core.request(VehicleRequest(token, kind, alt_m), self.now)
        self._pump_core()

    def finished(self, token: int) -> TaskFinished | None:
        return next(
            (e for e in self.events if isinstance(e, TaskFinished) and e.token == token), None
        )

    def run_task(self, token: int, kind: TaskKind, alt_m: float | None = None) -> TaskFinished:
        self.request(token, kind, alt_m)
        self.run(30.0, stop=lambda: self.finished(token) is not None)
        done = self.finished(token)
        assert done is not None, (kind, self.events[-5:])
        return done

    def fly(self) -> None:
        self.run(3.0)  # GPS fix, home, readiness
        assert self.run_task(1, TaskKind.TAKEOFF, 4.0).ok
        self.run(10.0, stop=lambda: self.sim.landed == LandedState.IN_AIR)
        assert self.sim.landed == LandedState.IN_AIR

    def _enqueue(self, direction: str, msg: Observation | VehicleCommand | BootClock) -> None:
        if self.drop is not None and not isinstance(msg, BootClock) and self.drop(msg, direction):
            return
        heapq.heappush(self._queue, (self.now + self.latency_s, next(self._seq), direction, msg))

    def _pump_sim(self) -> None:
        for msg in self.sim.messages_to_send():
            self._enqueue("up", msg)

    def _pump_core(self) -> None:
        for cmd in self.core.datagrams_to_send():
            self.sent.append(cmd)
            self._enqueue("down", cmd)
        self.events += iter(self.core.next_event, None)


def test_readiness_changes_are_events_and_a_silent_link_goes_stale_by_the_timer() -> None:
    b = Bench()
    b.run(3.0)
    verdicts = [e.verdict for e in b.events if isinstance(e, ReadinessChanged)]
    assert verdicts[-1].ready
    b.drop = lambda msg, direction: True  # the link dies
    b.run(5.0)
    last = [e.verdict for e in b.events if isinstance(e, ReadinessChanged)][-1]
    assert not last.ready and str(last.reason) == "heartbeat_stale"
    assert b.core.get_timer() is None  # judged; no timer spinning on a past deadline


def test_takeoff_then_land_confirmed_by_state() -> None:
    b = Bench()
    b.fly()
    done = b.run_task(2, TaskKind.LAND)
    assert (done.ok, done.reason) == (True, "")
    assert isinstance(done.outcome, ActionFinished) and "state shows it" in done.outcome.detail
    assert b.sim.mode == MODE_LAND
    b.run(30.0, stop=lambda: b.sim.landed == LandedState.ON_GROUND)
    assert b.sim.landed == LandedState.ON_GROUND


def test_hold_switches_to_auto_loiter() -> None:
    b = Bench()
    b.fly()
    assert b.sim.mode == MODE_LOITER  # navigator: take-off done -> Hold; land first
    assert b.run_task(2, TaskKind.LAND).ok
    done = b.run_task(3, TaskKind.HOLD)
    assert (done.ok, done.reason) == (True, "")
    assert b.sim.mode == MODE_LOITER
    holds = [c for c in b.sent if c.command == MavCmd.DO_SET_MODE]
    assert len(holds) >= 1 and holds[0].params[:3] == (1.0, 4.0, 3.0)  # custom, AUTO, LOITER


def test_abort_in_the_air_lands() -> None:
    b = Bench()
    b.fly()
    done = b.run_task(2, TaskKind.ABORT)
    assert (done.ok, done.reason) == (True, "NAV_LAND")
    assert b.sim.mode == MODE_LAND


def test_abort_of_a_running_takeoff_disarms_on_the_ground() -> None:
    b = Bench(SimConfig(gps_fix_after_s=0.5, spool_up_s=5.0))
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    b.run(5.0, stop=lambda: bool(b.core.state.armed))  # armed, as the heartbeat says
    assert b.sim.landed == LandedState.ON_GROUND
    done = b.run_task(2, TaskKind.ABORT)
    assert (done.ok, done.reason) == (True, "COMPONENT_ARM_DISARM")
    takeoff = b.finished(1)
    assert takeoff is not None and not takeoff.ok and takeoff.reason == "superseded: abort"
    b.run(1.0)
    assert not armed(b.sim)
    disarms = [c for c in b.sent if c.command == MavCmd.COMPONENT_ARM_DISARM and c.params[0] == 0]
    assert disarms and all(c.params[1] != 21196 for c in disarms)  # never forced


def test_abort_on_the_ground_disarmed_needs_nothing() -> None:
    b = Bench()
    b.run(3.0)
    done = b.run_task(2, TaskKind.ABORT)
    assert (done.ok, done.reason, done.outcome) == (True, ON_GROUND_DISARMED, None)
    assert b.sent == []


def test_land_on_the_ground_disarmed_fails_with_px4s_answer() -> None:
    b = Bench()
    b.run(3.0)
    done = b.run_task(2, TaskKind.LAND)
    assert (done.ok, done.reason) == (False, "TEMPORARILY_REJECTED")
    lands = [c for c in b.sent if c.command == MavCmd.NAV_LAND]
    assert [c.confirmation for c in lands] == [0, 1, 2, 3]


def test_lost_acks_land_by_state() -> None:
    b = Bench()
    b.fly()
    b.drop = lambda msg, direction: isinstance(msg, CommandAck)
    done = b.run_task(2, TaskKind.LAND)
    assert done.ok


def test_no_ack_and_no_effect_fails_no_ack() -> None:
    b = Bench()
    b.fly()
    b.drop = lambda msg, direction: direction == "down"
    done = b.run_task(2, TaskKind.LAND)
    assert (done.ok, done.reason) == (False, "no_ack")


def test_a_second_takeoff_while_one_runs_is_busy() -> None:
    b = Bench()
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    b.request(2, TaskKind.TAKEOFF, 4.0)
    busy = b.finished(2)
    assert busy is not None and (busy.ok, busy.reason) == (False, "busy")
    b.run(30.0, stop=lambda: b.finished(1) is not None)
    first = b.finished(1)
    assert first is not None and isinstance(first.outcome, TakeoffSucceeded)


def armed(sim: SimVehicle) -> bool:
    return sim.armed


# ---- scripted: answers the simulator never gives ------------------------------------------


def _vehicle(mode_custom: int, armed: bool = True) -> VehicleState:
    v = VehicleState()
    for obs in (
        Heartbeat(12, 2, 1 | (128 if armed else 0), mode_custom, MavState.ACTIVE),
        SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
        ExtendedSysState(LandedState.IN_AIR),
        GpsRawInt(GpsFixType.FIX_3D, 12),
        HomePosition(0, 0, 488000),
    ):
        v.observe(obs, 0.0)
    return v


def test_accepted_but_never_shown_is_not_confirmed() -> None:
    """PX4 acks HOLD, but the heartbeats keep another mode: not a success."""
    v = _vehicle(MODE_LAND.custom_mode)
    action = VehicleAction(v, ActionKind.HOLD)
    action.start(0.0)
    action.observe(CommandAck(MavCmd.DO_SET_MODE, MavResult.ACCEPTED), 0.1)
    assert not action.done and action.get_timer() == pytest.approx(3.1)
    action.handle_timer(3.1)
    assert action.outcome is not None
    assert (action.outcome.ok, action.outcome.reason) == (False, NOT_CONFIRMED)


@pytest.mark.parametrize("result", [MavResult.DENIED, MavResult.UNSUPPORTED, MavResult.FAILED])
def test_a_final_refusal_fails_with_its_name(result: MavResult) -> None:
    action = VehicleAction(_vehicle(MODE_LOITER.custom_mode), ActionKind.LAND)
    action.start(0.0)
    action.observe(CommandAck(MavCmd.NAV_LAND, result), 0.1)
    assert action.outcome is not None
    assert (action.outcome.ok, action.outcome.reason) == (False, result.name)
    events = list(iter(action.next_event, None))
    assert [type(e) for e in events][0] is CommandSent


def test_every_task_kind_is_dispatched() -> None:
    """A new TaskKind without a branch fails mypy (assert_never); at runtime each known kind
    ends in exactly one TaskFinished."""
    for i, kind in enumerate(TaskKind):
        core = VehicleCore()
        core.request(VehicleRequest(i, kind, 4.0), 0.0)
        for t in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 6.0):
            core.handle_timer(t)
        events = list(iter(core.next_event, None))
        assert [e.token for e in events if isinstance(e, TaskFinished)] == [i], kind


def test_a_landed_vehicle_takes_off_again_once_put_back_in_hold() -> None:
    """After a LAND, PX4 keeps AUTO.LAND on the ground, off the ``flight_mode`` allow-list
    (session 16), so a second take-off is refused until the vehicle is in Hold again: the
    operator's way back is ``swarmctl hold`` (docs/operations.md, "Readiness reasons"). A
    HOLD on the ground succeeds, and the take-off after it flies."""
    b = Bench()
    b.fly()
    assert b.run_task(2, TaskKind.LAND).ok
    b.run(30.0, stop=lambda: not b.sim.armed)
    assert not b.sim.armed and b.sim.mode == MODE_LAND
    b.run(3.0)
    refused = b.core.readiness(b.now)
    assert not refused.ready and refused.reason is Reason.FLIGHT_MODE, refused
    assert b.run_task(3, TaskKind.HOLD).ok
    b.run(3.0)
    assert b.core.readiness(b.now).ready
    assert b.run_task(4, TaskKind.TAKEOFF, 4.0).ok
