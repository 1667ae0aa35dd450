"""The fresh-state rule over XRCE (docs/px4.md, "Fresh state"): which PX4 samples become the
state that may confirm a LAND, HOLD or ABORT, and that a sample older than the command does not.

Over XRCE the state comes from uORB topics (``xrce_translate``): ``vehicle_status`` gives the
HEARTBEAT and, with the last ``vehicle_land_detected``, EXTENDED_SYS_STATE; each is stamped
with the arrival of the sample, as a MAVLink message is. So a LAND, HOLD or DISARM is
confirmed by the first ``vehicle_status`` received one ack timeout after its send, never by
one in flight. PX4 publishes ``vehicle_status`` every 0.5 s (the recorded session:
``bench/xrce_topic_gaps.py``), well inside the 3 s confirm window.

The attack found here: ``vehicle_land_detected`` carries no nav_state. Its LANDING was derived
from the last ``vehicle_status`` held, which may predate the command (a HOLD that took, its
``vehicle_status`` samples lost on the best-effort stream), and stamped with the land sample's
arrival: a LAND whose NAV_LAND was lost was reported done while PX4 loitered.

Virtual time; samples in PX4 1.16's layouts, read by the translator the agent uses.
"""

from __future__ import annotations

import pytest

from swarmd.px4.actions import NOT_CONFIRMED
from swarmd.px4.constants import COMP_ID_ONBOARD_COMPUTER, LandedState, MavCmd
from swarmd.px4.messages import command_name
from swarmd.px4.readiness import Reason
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleRequest
from swarmd.px4.xrce_translate import NAV_AUTO_LAND, Px4Translator
from tests.test_xrce_translate import SYSID, _sample

RELEASE = "1.16"
NAV_LOITER, NAV_MANUAL = 4, 0


class Px4Samples:
    """PX4's uORB samples through the translator into a ``VehicleCore``, on virtual time
    (the core's timer fires in between, as the driver does)."""

    def __init__(self) -> None:
        self.translator = Px4Translator(sysid=SYSID)
        self.core = VehicleCore()
        self.done: list[TaskFinished] = []

    def at(self, t: float) -> None:
        for _ in range(100):  # bounded: a task has a handful of deadlines
            timer = self.core.get_timer()
            if timer is None or timer > t or not self.core.busy():
                break
            self.core.handle_timer(timer)
        self.done += [e for e in iter(self.core.next_event, None) if isinstance(e, TaskFinished)]

    def feed(self, t: float, message: str, **values: float | int | bool) -> None:
        self.at(t)
        for obs in self.translator.sample(*_sample(RELEASE, message, **values)):
            self.core.receive_datagram(obs, None, t)
        self.at(t)

    def status(self, t: float, *, armed: bool, nav: int) -> None:
        self.feed(t, "VehicleStatus", arming_state=2 if armed else 1, nav_state=nav,
                  pre_flight_checks_pass=True)  # fmt: skip

    def land_detected(self, t: float, *, landed: bool) -> None:
        self.feed(t, "VehicleLandDetected", landed=landed)

    def accepted(self, t: float, command: MavCmd) -> None:
        self.feed(t, "VehicleCommandAck", command=command, result=0, target_system=SYSID,
                  target_component=COMP_ID_ONBOARD_COMPUTER)  # fmt: skip

    def request(self, t: float, token: int, kind: TaskKind) -> list[MavCmd]:
        self.at(t)
        self.core.request(VehicleRequest(token, kind), t)
        self.at(t)
        return [MavCmd(c.command) for c in self.core.datagrams_to_send()]

    def new_session(self, t: float) -> None:
        """The agent's SessionCreated of PX4's new life, fed as the backend feeds it."""
        self.at(t)
        for obs in self.translator.new_session():
            self.core.receive_datagram(obs, None, t)
        self.at(t)

    def finished(self, token: int) -> TaskFinished | None:
        return next((e for e in self.done if e.token == token), None)


def _vehicle(*, armed: bool, nav: int, landed: bool) -> Px4Samples:
    """A PX4 heard for a second: vehicle_status first (it says whose the session is)."""
    px4 = Px4Samples()
    px4.status(9.0, armed=armed, nav=nav)
    px4.land_detected(9.05, landed=landed)
    px4.status(9.5, armed=armed, nav=nav)
    return px4


# kind: (before: armed, nav_state, landed), the command it sends, (after: armed, nav_state)
CASES = {
    "land": (TaskKind.LAND, (True, NAV_LOITER, False), MavCmd.NAV_LAND, (True, NAV_AUTO_LAND)),
    "hold": (TaskKind.HOLD, (True, NAV_AUTO_LAND, False), MavCmd.DO_SET_MODE, (True, NAV_LOITER)),
    "abort_in_the_air": (
        TaskKind.ABORT, (True, NAV_LOITER, False), MavCmd.NAV_LAND, (True, NAV_AUTO_LAND),
    ),
    "abort_armed_on_the_ground": (
        TaskKind.ABORT, (True, NAV_LOITER, True), MavCmd.COMPONENT_ARM_DISARM, (False, NAV_LOITER),
    ),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CASES))
def test_each_action_is_confirmed_by_the_first_vehicle_status_an_ack_timeout_after_its_send(
    case: str,
) -> None:
    """PX4 carries the command out at once: its ACCEPTED and the vehicle_status and
    vehicle_land_detected samples that show it within the 0.5 s after the send do not end
    the task (any of them could have been in flight from before); the first vehicle_status
    after that does, an ABORT with the command it sent as its reason."""
    kind, (armed, nav, landed), command, (armed_after, nav_after) = CASES[case]
    px4 = _vehicle(armed=armed, nav=nav, landed=landed)
    assert px4.request(10.0, 1, kind) == [command]
    px4.status(10.1, armed=armed_after, nav=nav_after)
    px4.accepted(10.2, command)
    px4.land_detected(10.3, landed=landed)
    px4.status(10.45, armed=armed_after, nav=nav_after)
    assert px4.finished(1) is None
    px4.status(10.55, armed=armed_after, nav=nav_after)
    done = px4.finished(1)
    assert done is not None and done.ok
    if kind is TaskKind.ABORT:
        assert done.reason == command_name(command)


def test_a_vehicle_status_in_flight_with_the_effect_then_none_ends_not_confirmed() -> None:
    """A HOLD whose effect shows only in samples received within the ack timeout, and then
    PX4 is heard in AUTO.LAND again (the mode change never took): ``not_confirmed``."""
    px4 = _vehicle(armed=True, nav=NAV_AUTO_LAND, landed=False)
    assert px4.request(10.0, 1, TaskKind.HOLD) == [MavCmd.DO_SET_MODE]
    px4.status(10.1, armed=True, nav=NAV_LOITER)
    px4.accepted(10.2, MavCmd.DO_SET_MODE)
    for i in range(8):
        px4.status(10.6 + 0.5 * i, armed=True, nav=NAV_AUTO_LAND)
    px4.at(20.0)
    done = px4.finished(1)
    assert done is not None and (done.ok, done.reason) == (False, NOT_CONFIRMED)


def test_a_land_detected_sample_with_an_older_nav_state_does_not_confirm_a_land() -> None:
    """PX4 lands (vehicle_status AUTO.LAND); the operator sends HOLD, then LAND at once. PX4
    takes the HOLD and loiters; the NAV_LAND is lost every time, and so are the
    vehicle_status samples of the next half second. A vehicle_land_detected (in the air)
    arrives 0.6 s after the LAND. Its LANDING came from the AUTO.LAND held from before the
    HOLD, yet it was stamped fresh: the LAND was reported done with the vehicle hovering.
    Now LANDING comes only with a vehicle_status (the sample that carries nav_state); the LAND
    is sent again and, never answered, fails. [main: LAND ok at 10.6]"""
    px4 = _vehicle(armed=True, nav=NAV_AUTO_LAND, landed=False)
    assert px4.request(10.0, 1, TaskKind.HOLD) == [MavCmd.DO_SET_MODE]
    assert px4.request(10.02, 2, TaskKind.LAND) == [MavCmd.NAV_LAND]
    px4.land_detected(10.6, landed=False)
    assert px4.finished(2) is None
    for i in range(6):  # PX4 loiters (the HOLD took); the land detector keeps publishing
        px4.status(10.9 + 0.5 * i, armed=True, nav=NAV_LOITER)
        px4.land_detected(11.0 + 0.5 * i, landed=False)
    px4.at(20.0)
    land = px4.finished(2)
    assert land is not None and not land.ok


# ---- a PX4 that reboots (docs/security.md, case 6) --------------------------------------------


def test_an_aborts_disarm_is_done_by_a_rebooted_px4s_first_disarmed_status() -> None:
    """ABORT armed on the ground; its DISARM is lost and PX4 reboots (a new XRCE session).
    The new life's first vehicle_status says disarmed, an ack timeout after the send: the
    ABORT is done, and that is true (a rebooted PX4 is disarmed: PX4 arms only on a command)."""
    px4 = _vehicle(armed=True, nav=NAV_LOITER, landed=True)
    assert px4.request(10.0, 1, TaskKind.ABORT) == [MavCmd.COMPONENT_ARM_DISARM]
    px4.new_session(11.1)  # the agent's SessionCreated of the new life
    px4.status(11.2, armed=False, nav=NAV_MANUAL)  # SITL restarts within a second
    done = px4.finished(1)
    assert done is not None and done.ok


def test_a_land_is_never_done_by_a_rebooted_px4_on_the_ground() -> None:
    """LAND in the air; the NAV_LAND is lost and PX4 restarts (SITL, or a brown-out on the
    bench). The new life is disarmed, on the ground, in its boot mode: no AUTO.LAND, no
    LANDING, so the LAND that never ran is never reported done; it fails."""
    px4 = _vehicle(armed=True, nav=NAV_LOITER, landed=False)
    assert px4.request(10.0, 1, TaskKind.LAND) == [MavCmd.NAV_LAND]
    px4.new_session(10.9)
    for i in range(8):
        px4.status(11.0 + 0.5 * i, armed=False, nav=NAV_MANUAL)
        px4.land_detected(11.1 + 0.5 * i, landed=True)
    px4.at(20.0)
    done = px4.finished(1)
    assert done is not None and not done.ok


def _ready_on_the_ground() -> Px4Samples:
    """A PX4 heard for a second, disarmed on the ground, with all readiness needs."""
    px4 = _vehicle(armed=False, nav=NAV_LOITER, landed=True)
    px4.feed(9.6, "BatteryStatus", remaining=0.9, voltage_v=16.0)
    px4.feed(9.6, "SensorGps", fix_type=3, satellites_used=12, eph=0.9, latitude_deg=47.39,
             longitude_deg=8.54, altitude_msl_m=488.0)  # fmt: skip
    px4.feed(9.6, "HomePosition", lat=47.39, lon=8.54, alt=488.0, valid_alt=True,
             valid_hpos=True)  # fmt: skip
    px4.status(9.9, armed=False, nav=NAV_LOITER)
    assert px4.core.readiness(9.9).ready
    return px4


def test_a_new_session_says_nothing_of_the_last_lifes_landed_state_to_an_abort() -> None:
    """PX4 flew (in the air, armed, Hold), then rebooted on the ground (a brown-out in a hard
    landing). The new life's first vehicle_status (disarmed, Manual) came before its first
    vehicle_land_detected (PX4 may take about a second). The last life's ``landed`` (False)
    made that status read IN_AIR, so an ABORT then sent NAV_LAND to a disarmed vehicle on the
    ground. Now the new session forgets it: landed unknown, disarmed by a fresh status, so
    the ABORT has nothing to do (``ABORT: land, disarm or nothing``). [main: NAV_LAND sent]"""
    px4 = _vehicle(armed=True, nav=NAV_LOITER, landed=False)
    px4.new_session(10.0)
    px4.status(10.4, armed=False, nav=NAV_MANUAL)
    assert px4.request(10.5, 1, TaskKind.ABORT) == []
    assert px4.core.state.landed_state is None
    done = px4.finished(1)
    assert done is not None and done.ok and done.reason == "on_ground_disarmed"
    px4.land_detected(10.9, landed=True)  # the new life's land detector: on the ground
    assert px4.core.state.landed_state is LandedState.ON_GROUND


def test_an_abort_between_a_new_session_and_its_first_status_lands() -> None:
    """In the moment between the new session and its first vehicle_status nothing is known:
    the ABORT lands, as with a link gone quiet (the state is too old to say "on the ground"),
    and a LAND is never confirmed by the last life's heartbeat. (Documents the choice; main
    did the same here, from the last life's IN_AIR.)"""
    px4 = _vehicle(armed=True, nav=NAV_AUTO_LAND, landed=False)
    px4.new_session(10.0)
    assert px4.core.state.heartbeat is None and px4.core.state.armed is None
    assert px4.request(10.1, 1, TaskKind.ABORT) == [MavCmd.NAV_LAND]
    px4.at(10.7)  # an ack timeout after the send; the last life said AUTO.LAND
    assert px4.finished(1) is None


def test_readiness_does_not_judge_a_new_life_by_the_last_ones_samples() -> None:
    """A vehicle ready on the ground reboots: its new life's first vehicle_status alone made
    it ready again with the last life's GPS fix, home, battery and landed state, before any
    of those samples of the new life arrived. Now each must come again. [main: ready]"""
    px4 = _ready_on_the_ground()
    px4.new_session(10.0)
    assert px4.core.readiness(10.0).reason is Reason.NO_HEARTBEAT
    px4.status(10.4, armed=False, nav=NAV_LOITER)
    verdict = px4.core.readiness(10.4)
    assert not verdict.ready and verdict.battery_pct is None and verdict.gps_fix is None
    assert verdict.landed_state is None and not verdict.home
    for name, values in (
        ("BatteryStatus", {"remaining": 0.9, "voltage_v": 16.0}),
        ("VehicleLandDetected", {"landed": True}),
        ("SensorGps", {"fix_type": 3, "satellites_used": 12, "eph": 0.9,
                       "latitude_deg": 47.39, "longitude_deg": 8.54, "altitude_msl_m": 488.0}),
        ("HomePosition", {"lat": 47.39, "lon": 8.54, "alt": 488.0, "valid_alt": True,
                          "valid_hpos": True}),
    ):  # fmt: skip
        px4.feed(10.6, name, **values)
    px4.status(10.9, armed=False, nav=NAV_LOITER)
    assert px4.core.readiness(10.9).ready
