"""A take-off never arms a vehicle whose flight mode flies on ARM alone (readiness
``flight_mode``; docs/px4.md, "Readiness predicate" and "Fresh state").

Another ground station or an RC switch may leave the disarmed vehicle in AUTO.TAKEOFF (PX4
climbs to MIS_TAKEOFF_ALT on ARM), AUTO.MISSION (starts its mission) or OFFBOARD (follows
another program's setpoints). The wire spy here is what the vehicle core hands its backend
(``VehicleCore.datagrams_to_send``) or what reached the simulator (``VirtualLink.sent_down``):
no ARM may be among it while the vehicle is in such a mode, or in one swarmd does not know.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import VirtualLink

from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
    Px4AutoSubMode,
    Px4MainMode,
    Px4PosctlSubMode,
)
from swarmd.px4.messages import (
    MODE_LOITER,
    MODE_TAKEOFF,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    Px4Mode,
    StateReset,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.readiness import (
    STAYS_ON_GROUND,
    ReadinessConfig,
    Reason,
    VehicleState,
    readiness,
)
from swarmd.px4.takeoff import FailReason, TakeoffFailed, TakeoffSequence
from swarmd.px4.vehicle import TaskFinished, VehicleCore
from swarmd.px4.xrce_translate import Px4Translator
from swarmd.xrce import px4 as topics
from swarmd.xrce.px4_layouts import LAYOUTS

MODE_MISSION = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.MISSION)
MODE_OFFBOARD = Px4Mode(Px4MainMode.OFFBOARD)
FLIES_ON_ARM = [MODE_TAKEOFF, MODE_MISSION, MODE_OFFBOARD]


def _is_arm(command: VehicleCommand) -> bool:
    return command.command == MavCmd.COMPONENT_ARM_DISARM and command.params[0] == 1.0


def _is_disarm(command: VehicleCommand) -> bool:
    return command.command == MavCmd.COMPONENT_ARM_DISARM and command.params[0] == 0.0


# ---- the simulator: a vehicle another ground station left in such a mode ------------------


def _ready_link() -> VirtualLink:
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = VirtualLink(sim, VehicleState(), 0.0)
    link.run_until(5.0)
    assert readiness(link.state, link.now, ReadinessConfig()).ready  # Hold: the sim's boot mode
    return link


@pytest.mark.parametrize("mode", FLIES_ON_ARM, ids=lambda m: m.name)
def test_a_mode_that_flies_on_arm_is_not_ready_and_no_arm_goes_out(mode: Px4Mode) -> None:
    """[main: ready, ARM sent; PX4 would climb, start its mission or follow setpoints]"""
    link = _ready_link()
    link.sim.mode = mode  # another ground station's switch, disarmed on the ground
    link.run_until(link.now + 1.5)  # a HEARTBEAT shows it
    verdict = readiness(link.state, link.now, ReadinessConfig())
    assert (verdict.ready, verdict.reason) == (False, Reason.FLIGHT_MODE)
    assert mode.name in verdict.detail and verdict.mode == mode.name
    seq = TakeoffSequence(link.state, 10.0)
    link.start(seq)
    link.run_until(link.now + 10.0, stop=lambda: seq.done)
    assert isinstance(seq.outcome, TakeoffFailed), seq.outcome
    assert (seq.outcome.reason, seq.outcome.cause) == (FailReason.NOT_READY, "flight_mode")
    assert link.sent_down == []
    assert not link.sim.armed


def test_the_allowed_modes_and_why() -> None:
    """An allow-list, each entry with its reason; the sim's boot mode (Hold) is on it, so
    demos, flights and loopback tests keep taking off."""
    assert MODE_LOITER in STAYS_ON_GROUND
    assert all(why for why in STAYS_ON_GROUND.values())
    assert not set(FLIES_ON_ARM) & set(STAYS_ON_GROUND)
    orbit = Px4Mode(Px4MainMode.POSCTL, Px4PosctlSubMode.ORBIT)
    assert orbit not in STAYS_ON_GROUND and orbit.name == "POSCTL.ORBIT"
    slow = Px4Mode(Px4MainMode.POSCTL, Px4PosctlSubMode.SLOW)  # Position Slow
    assert slow in STAYS_ON_GROUND and slow.name == "POSCTL.SLOW"


# ---- the vehicle core, fed by hand: the test plays PX4 -----------------------------------


@dataclass
class Core:
    """A ``VehicleCore`` whose every output command is kept with the mode it was sent in."""

    core: VehicleCore = field(default_factory=VehicleCore)
    now: float = 0.0
    mode: Px4Mode = MODE_LOITER
    armed: bool = False
    wire: list[tuple[VehicleCommand, Px4Mode | None]] = field(default_factory=list)
    finished: list[TaskFinished] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.telemetry()

    def heartbeat(self) -> Heartbeat:
        status = MavState.ACTIVE if self.armed else MavState.STANDBY
        return Heartbeat(12, 2, 1 | (128 if self.armed else 0), self.mode.custom_mode, status)

    def telemetry(self) -> None:
        for obs in (
            self.heartbeat(),
            SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
            ExtendedSysState(LandedState.ON_GROUND),
            GpsRawInt(GpsFixType.FIX_3D, 12),
            HomePosition(0, 0, 488000),
        ):
            self.feed(obs)

    def feed(self, obs: Observation) -> None:
        self.core.receive_datagram(obs, None, self.now)
        self._collect()

    def takeoff(self, token: int = 1) -> None:
        self.core.takeoff(token, 10.0, self.now)
        self._collect()

    def advance(self, dt: float) -> None:
        """Run the core's timers for ``dt`` seconds (retransmissions happen here)."""
        end = self.now + dt
        while (timer := self.core.get_timer()) is not None and timer <= end:
            self.now = max(self.now, timer)
            self.core.handle_timer(self.now)
            self._collect()
        self.now = end

    def arms(self) -> list[VehicleCommand]:
        return [c for c, _ in self.wire if _is_arm(c)]

    def _collect(self) -> None:
        hb = self.core.state.heartbeat
        held = None if hb is None else hb.mode
        self.wire += [(c, held) for c in self.core.datagrams_to_send()]
        while (event := self.core.next_event()) is not None:
            if isinstance(event, TaskFinished):
                self.finished.append(event)


@pytest.mark.parametrize("mode", FLIES_ON_ARM, ids=lambda m: m.name)
def test_a_mode_switched_after_readiness_said_ready_is_refused_at_the_arm(mode: Px4Mode) -> None:
    """The commander saw the drone ready in Hold; the switch comes before the take-off
    request reaches it. REJECTED-class outcome, nothing on the wire.
    [main: ARM sent]"""
    c = Core()
    assert c.core.readiness(c.now).ready
    c.now = 0.4
    c.mode = mode
    c.feed(c.heartbeat())
    c.takeoff()
    assert c.wire == []
    (done,) = c.finished
    assert (done.ok, done.reason) == (False, "not_ready: flight_mode")
    assert isinstance(done.outcome, TakeoffFailed) and done.outcome.reason is FailReason.NOT_READY


def test_a_mode_switched_between_two_sends_of_arm_stops_the_retransmissions() -> None:
    """PX4 answers our ARM TEMPORARILY_REJECTED; before the retransmission another ground
    station switches to AUTO.TAKEOFF. No ARM goes out in that mode: ``mode_changed``, and the
    DISARM covers the first ARM (repeated, unanswered, while the vehicle reads on the ground:
    tests/test_px4_disarm_repeat.py). [main: the ARM was retransmitted in AUTO.TAKEOFF]"""
    c = Core()
    c.takeoff()
    assert [conf.confirmation for conf in c.arms()] == [0]
    c.now = 0.1
    c.feed(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.TEMPORARILY_REJECTED, 0, 1, 191))
    c.now = 0.3
    c.mode = MODE_TAKEOFF
    c.feed(c.heartbeat())
    c.advance(5.0)
    assert [conf.confirmation for conf in c.arms()] == [0]
    assert [_is_disarm(cmd) for cmd, _ in c.wire] == [False, True, True, True, True]
    (done,) = c.finished
    assert (done.ok, done.reason) == (False, FailReason.MODE_CHANGED)
    assert isinstance(done.outcome, TakeoffFailed) and "AUTO.TAKEOFF" in done.outcome.detail


def test_a_state_reset_while_arming_stops_the_retransmissions() -> None:
    """A new XRCE session while our ARM waits for its answer: the mode is unknown, so no
    retransmission of ARM goes to whatever PX4 now is. [main: ARM retransmitted 3 times]"""
    c = Core()
    c.takeoff()
    c.now = 0.2
    c.feed(StateReset("new session"))
    c.advance(5.0)
    assert len(c.arms()) == 1
    (done,) = c.finished
    assert (done.ok, done.reason) == (False, FailReason.MODE_CHANGED)


def test_an_unknown_mode_is_not_ready_and_says_so() -> None:
    c = Core(mode=Px4Mode(9, 0))
    verdict = c.core.readiness(c.now)
    assert verdict.reason is Reason.FLIGHT_MODE
    assert "MODE(9,0)" in verdict.detail and "not a mode known" in verdict.detail


@pytest.mark.parametrize(
    ("mode", "raw"),
    [
        (Px4Mode(9, 0), "custom_mode 0x00090000"),  # a main mode PX4 does not define
        (Px4Mode(4, 19), "custom_mode 0x13040000"),  # AUTO.19: a later PX4's sub-mode
        (Px4Mode(3, 9), "custom_mode 0x09030000"),  # POSCTL.9
    ],
)
def test_an_unknown_mavlink_mode_names_its_raw_custom_mode(mode: Px4Mode, raw: str) -> None:
    """The detail carries HEARTBEAT.custom_mode as PX4 sent it, the number an operator
    looks up in a later PX4's px4_custom_mode.h [main: MODE(9,0) or AUTO.19 alone]."""
    c = Core(mode=mode)
    verdict = c.core.readiness(c.now)
    assert verdict.reason is Reason.FLIGHT_MODE
    assert raw in verdict.detail
    assert mode.name in verdict.detail


def test_a_known_mode_carries_no_raw_number() -> None:
    c = Core(mode=MODE_TAKEOFF)
    assert "custom_mode" not in c.core.readiness(c.now).detail


# ---- any mode, any order: ARM only ever in a mode that stays on the ground ----------------

ANY_MODE = st.builds(Px4Mode, st.integers(0, 12), st.integers(0, 20)) | st.sampled_from(
    [*FLIES_ON_ARM, *STAYS_ON_GROUND]
)
STEP = st.one_of(
    st.tuples(st.just("mode"), ANY_MODE),
    st.tuples(st.just("takeoff"), st.none()),
    st.tuples(st.just("reject"), st.none()),  # ARM answered TEMPORARILY_REJECTED
    st.tuples(st.just("wait"), st.floats(0.05, 1.0)),
    st.tuples(st.just("reset"), st.none()),  # a new XRCE session
)


@settings(max_examples=300, deadline=None)
@given(start=ANY_MODE, steps=st.lists(STEP, max_size=12))
def test_arm_only_ever_goes_out_in_a_mode_that_stays_on_the_ground(
    start: Px4Mode, steps: list[tuple[str, object]]
) -> None:
    """Whatever the mode changes, rejections, resets and waits, every ARM on the wire was
    sent while the state held a mode of ``STAYS_ON_GROUND``. [main: fails on the first
    example that takes off in AUTO.TAKEOFF]"""
    c = Core(mode=start)
    token = 1
    for kind, arg in steps:
        c.now += 0.01
        if kind == "mode" and isinstance(arg, Px4Mode):
            c.mode = arg
            c.feed(c.heartbeat())
        elif kind == "takeoff":
            c.takeoff(token)
            token += 1
        elif kind == "reject":
            ack = CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.TEMPORARILY_REJECTED, 0, 1, 191)
            c.feed(ack)
        elif kind == "wait" and isinstance(arg, float):
            c.advance(arg)
        elif kind == "reset":
            c.feed(StateReset("new session"))
            c.telemetry()  # the new life's first samples, in whatever mode it is
    c.advance(5.0)
    assert all(held in STAYS_ON_GROUND for cmd, held in c.wire if _is_arm(cmd)), c.wire


# ---- XRCE-DDS: the same rule on vehicle_status.nav_state ---------------------------------


def _status(release: str, nav_state: int) -> tuple[str, bytes]:
    layout = LAYOUTS[release]["VehicleStatus"]
    topic = next(t for t, m in topics.TOPIC_MESSAGES.items() if m == "VehicleStatus")
    values: dict[str, float | int | bool] = {
        "system_id": 3,
        "nav_state": nav_state,
        "pre_flight_checks_pass": True,
    }
    return topics.dds_topic(topic, "out", layout[1]), topics.encode_fields(layout, values)


# Every nav_state of vehicle_status.msg 1.14-1.17 (/work/shared/peers/xrce/px4_msgs), the
# mode PX4's get_px4_custom_mode reports for it over MAVLink, and whether a take-off arms
# there (docs/px4.md, "nav_state"). The free slots and anything past NAVIGATION_STATE_MAX
# (31) are unknown: MODE(0,0), refused.
NAV_STATES: list[tuple[int, str, bool]] = [
    (0, "MANUAL", True),
    (1, "ALTCTL", True),
    (2, "POSCTL", True),
    (3, "AUTO.MISSION", False),
    (4, "AUTO.LOITER", True),
    (5, "AUTO.RTL", False),
    (6, "POSCTL.SLOW", True),  # POSITION_SLOW, 1.15+
    (7, "MODE(0,0)", False),  # FREE5
    (8, "ALTITUDE_CRUISE", False),  # 1.17 (UNUSED3/FREE4 before)
    (9, "MODE(0,0)", False),  # FREE3
    (10, "ACRO", True),
    (11, "MODE(0,0)", False),  # FREE2
    (12, "AUTO.LAND", False),  # DESCEND
    (13, "TERMINATION", False),
    (14, "OFFBOARD", False),
    (15, "STABILIZED", True),
    (16, "MODE(0,0)", False),  # FREE1
    (17, "AUTO.TAKEOFF", False),
    (18, "AUTO.LAND", False),
    (19, "AUTO.FOLLOW_TARGET", False),
    (20, "AUTO.PRECLAND", False),
    (21, "POSCTL.ORBIT", False),
    (22, "AUTO.VTOL_TAKEOFF", False),
    *[(23 + i, f"AUTO.EXTERNAL{i + 1}", False) for i in range(8)],  # 1.15+, ROS 2 modes
    (31, "MODE(0,0)", False),  # NAVIGATION_STATE_MAX
    (255, "MODE(0,0)", False),
]


@pytest.mark.parametrize(("nav_state", "name", "ready"), NAV_STATES)
@pytest.mark.parametrize("release", ["1.14", "1.17"])
def test_xrce_nav_state_is_judged_by_the_same_rule(
    release: str, nav_state: int, name: str, ready: bool
) -> None:
    """The mode is named as PX4 names it, and the detail names it. [main: ready in every
    nav_state; ORBIT read as POSCTL; session 16: 6 POSITION_SLOW, 8, 13, 23-30 read
    MODE(0,0) (6 refused, the others unnamed) or 13 AUTO.LAND]"""
    t = Px4Translator(sysid=3)
    state = VehicleState()
    for obs in t.sample(*_status(release, nav_state)):
        state.observe(obs, 0.0)
    for obs in (ExtendedSysState(LandedState.ON_GROUND), GpsRawInt(GpsFixType.FIX_3D, 12)):
        state.observe(obs, 0.0)
    config = ReadinessConfig(require_home=False, allow_unknown_battery=True)
    verdict = readiness(state, 0.0, config)
    assert verdict.mode == name
    assert verdict.ready is ready, verdict.detail
    if not ready:
        assert verdict.reason is Reason.FLIGHT_MODE
        assert name in verdict.detail
    # an unknown nav_state is named by its number, the only name it has [main: MODE(0,0)
    # alone, nav_state 7 and 31 read alike]; a known one needs none
    raw = f"vehicle_status.nav_state {nav_state}"
    assert (raw in verdict.detail) is (name == "MODE(0,0)")


@pytest.mark.parametrize("sub", range(11, 19))  # PX4_CUSTOM_SUB_MODE_EXTERNAL1-8
def test_an_external_mode_over_mavlink_is_named_and_refused_as_another_programs_code(
    sub: int,
) -> None:
    """HEARTBEAT custom_mode AUTO with sub-mode 11-18 (PX4_CUSTOM_SUB_MODE_EXTERNAL1-8): a
    ROS 2 program's mode. [session 16: read AUTO.11 and 'not a mode known']"""
    c = Core(mode=Px4Mode(Px4MainMode.AUTO, sub))
    verdict = c.core.readiness(c.now)
    assert verdict.reason is Reason.FLIGHT_MODE
    assert f"AUTO.EXTERNAL{sub - 10}" in verdict.detail and "external mode" in verdict.detail


def test_flight_termination_is_never_ready_whichever_backend_spells_it() -> None:
    """PX4's own custom mode for NAVIGATION_STATE_TERMINATION is MANUAL
    (``get_px4_custom_mode``), which ``STAYS_ON_GROUND`` allows: over MAVLink the HEARTBEAT's
    system_status (FLIGHT_TERMINATION, PX4's HEARTBEAT stream) is what refuses it. The XRCE
    translator has no such status, so it reads nav_state 13 as TERMINATION, off the list.
    Pins both refusals: a translator changed to PX4's spelling (MANUAL) would let a
    terminated vehicle read ready over XRCE. [holds on main]"""
    config = ReadinessConfig(require_home=False, allow_unknown_battery=True)
    facts: tuple[Observation, ...] = (
        ExtendedSysState(LandedState.ON_GROUND),
        GpsRawInt(GpsFixType.FIX_3D, 12),
    )
    mavlink = VehicleState()
    terminated = Heartbeat(
        autopilot=12,  # MAV_AUTOPILOT_PX4
        vehicle_type=2,
        base_mode=1,
        custom_mode=Px4Mode(Px4MainMode.MANUAL).custom_mode,
        system_status=MavState.FLIGHT_TERMINATION,
    )
    for obs in (terminated, *facts):
        mavlink.observe(obs, 0.0)
    assert not readiness(mavlink, 0.0, config).ready
    for release in ("1.14", "1.17"):
        xrce = VehicleState()
        for obs in Px4Translator(sysid=3).sample(*_status(release, 13)):
            xrce.observe(obs, 0.0)
        for obs in facts:
            xrce.observe(obs, 0.0)
        verdict = readiness(xrce, 0.0, config)
        assert not verdict.ready and verdict.reason is Reason.FLIGHT_MODE, verdict.detail


@pytest.mark.parametrize("release", ["1.14", "1.17"])
def test_every_nav_state_px4_can_send_reads_as_a_short_printable_line(release: str) -> None:
    """Review 17: the raw ``nav_state`` in the readiness detail is peer-controlled; it is a
    u8 read as an int, so whatever PX4 (or a forger on its link) sends, the detail stays
    one short line of printable ASCII: data, not a terminal sequence, in ``swarmctl``, the
    log and ``--json`` alike (pins: holds on main)."""
    t = Px4Translator(sysid=3)
    config = ReadinessConfig(require_home=False, allow_unknown_battery=True)
    for nav_state in range(256):
        state = VehicleState()
        for obs in t.sample(*_status(release, nav_state)):
            state.observe(obs, 0.0)
        for obs in (ExtendedSysState(LandedState.ON_GROUND), GpsRawInt(GpsFixType.FIX_3D, 12)):
            state.observe(obs, 0.0)
        detail = readiness(state, 0.0, config).detail
        assert detail.isascii() and detail.isprintable() and len(detail) <= 200, detail
