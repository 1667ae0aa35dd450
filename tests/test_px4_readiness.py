"""The readiness predicate on virtual time: every condition, its order, and link loss."""

from __future__ import annotations

import json
import random
from dataclasses import replace

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import VirtualLink

from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavSeverity,
    MavState,
)
from swarmd.px4.messages import (
    MODE_LOITER,
    MODE_TAKEOFF,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    StatusText,
    SysStatus,
)
from swarmd.px4.readiness import (
    CONDITIONS,
    ReadinessConfig,
    Reason,
    VehicleState,
    readiness,
)

CONFIG = ReadinessConfig(min_battery_pct=30.0)
GOOD_HB = Heartbeat(12, 2, 1, MODE_LOITER.custom_mode, MavState.STANDBY)
IN_TAKEOFF_MODE = replace(GOOD_HB, custom_mode=MODE_TAKEOFF.custom_mode)  # flies on ARM
GOOD_SYS = SysStatus(SENSOR_PREARM_CHECK | 0x2F, 80, 16200)
GOOD: tuple[Observation, ...] = (
    GOOD_HB,
    GOOD_SYS,
    ExtendedSysState(LandedState.ON_GROUND),
    GpsRawInt(GpsFixType.FIX_3D, 12),
    HomePosition(473977420, 85455940, 488000),
)


def state_with(*observations: Observation, now: float = 0.0) -> VehicleState:
    state = VehicleState()
    for obs in observations:
        state.observe(obs, now)
    return state


def test_healthy_vehicle_is_ready() -> None:
    verdict = readiness(state_with(*GOOD), 0.5, CONFIG)
    assert verdict.ready and verdict.reason is None
    assert verdict.armed is False and verdict.mode == "AUTO.LOITER"
    assert verdict.landed_state == "ON_GROUND" and verdict.gps_fix == 3 and verdict.home
    assert verdict.battery_pct == 80 and verdict.prearm is True
    json.dumps(verdict.as_dict())  # JSON-ready for swarmctl


BREAKAGES: list[tuple[str, tuple[Observation, ...], ReadinessConfig, Reason]] = [
    ("nothing heard", (), CONFIG, Reason.NO_HEARTBEAT),
    ("ArduPilot", (replace(GOOD_HB, autopilot=3),), CONFIG, Reason.NOT_PX4),
    ("armed", (replace(GOOD_HB, base_mode=129, system_status=4),), CONFIG, Reason.ARMED),
    ("failsafe", (replace(GOOD_HB, system_status=MavState.CRITICAL),), CONFIG, Reason.NOT_STANDBY),
    ("booting", (replace(GOOD_HB, system_status=MavState.BOOT),), CONFIG, Reason.NOT_STANDBY),
    ("takeoff mode", (IN_TAKEOFF_MODE,), CONFIG, Reason.FLIGHT_MODE),
    ("prearm clear", (replace(GOOD_SYS, sensors_health=0x2F),), CONFIG, Reason.PREARM_FAILED),
    (
        "prearm only in present/enabled (never counts on PX4)",
        (SysStatus(0x2F, 80, 16200, SENSOR_PREARM_CHECK, SENSOR_PREARM_CHECK),),
        CONFIG,
        Reason.PREARM_FAILED,
    ),
    ("in air", (ExtendedSysState(LandedState.IN_AIR),), CONFIG, Reason.NOT_ON_GROUND),
    ("landed unknown", (ExtendedSysState(LandedState.UNDEFINED),), CONFIG, Reason.NOT_ON_GROUND),
    ("2D fix", (GpsRawInt(GpsFixType.FIX_2D, 5),), CONFIG, Reason.NO_3D_FIX),
    ("battery low", (replace(GOOD_SYS, battery_remaining=29),), CONFIG, Reason.BATTERY_LOW),
    ("battery unknown", (replace(GOOD_SYS, battery_remaining=-1),), CONFIG, Reason.BATTERY_UNKNOWN),
]


@pytest.mark.parametrize(("label", "override", "config", "reason"), BREAKAGES)
def test_each_broken_condition_is_the_reason(
    label: str, override: tuple[Observation, ...], config: ReadinessConfig, reason: Reason
) -> None:
    observations = GOOD + override if override else ()
    verdict = readiness(state_with(*observations), 0.1, config)
    assert not verdict.ready, label
    assert verdict.reason is reason, (label, verdict.detail)
    assert verdict.detail and "\n" not in verdict.detail


def test_missing_home_and_its_config_switch() -> None:
    no_home = GOOD[:-1]
    assert readiness(state_with(*no_home), 0.0, CONFIG).reason is Reason.NO_HOME
    relaxed = replace(CONFIG, require_home=False)
    assert readiness(state_with(*no_home), 0.0, relaxed).ready


def test_unknown_battery_can_be_allowed() -> None:
    obs = (*GOOD, replace(GOOD_SYS, battery_remaining=-1))
    assert readiness(state_with(*obs), 0.0, replace(CONFIG, allow_unknown_battery=True)).ready


def test_first_failing_condition_wins_in_documented_order() -> None:
    """Break everything, then repair one condition at a time from the top."""
    order = [
        Reason.ARMED,
        Reason.NOT_STANDBY,
        Reason.FLIGHT_MODE,
        Reason.PREARM_FAILED,
        Reason.NOT_ON_GROUND,
        Reason.NO_3D_FIX,
        Reason.NO_HOME,
        Reason.BATTERY_LOW,
    ]
    hb = replace(
        GOOD_HB, base_mode=129, custom_mode=MODE_TAKEOFF.custom_mode, system_status=MavState.ACTIVE
    )
    sys = SysStatus(0, 5, 14000)
    ext = ExtendedSysState(LandedState.IN_AIR)
    gps = GpsRawInt(GpsFixType.NO_FIX, 0)
    home: HomePosition | None = None
    seen = []
    for step in range(len(order) + 1):
        observations: list[Observation] = [hb, sys, ext, gps]
        if home is not None:
            observations.append(home)
        verdict = readiness(state_with(*observations), 0.0, CONFIG)
        seen.append(verdict.reason)
        if step == 0:
            hb = replace(hb, base_mode=1)
        elif step == 1:
            hb = replace(hb, system_status=MavState.STANDBY)
        elif step == 2:
            hb = replace(hb, custom_mode=MODE_LOITER.custom_mode)
        elif step == 3:
            sys = replace(sys, sensors_health=SENSOR_PREARM_CHECK)
        elif step == 4:
            ext = ExtendedSysState(LandedState.ON_GROUND)
        elif step == 5:
            gps = GpsRawInt(GpsFixType.RTK_FIXED, 20)
        elif step == 6:
            home = HomePosition(1, 2, 3)
        elif step == 7:
            sys = replace(sys, battery_remaining=100)
    assert seen == [*order, None]
    assert len(CONDITIONS) == 12  # + unknown_layout, failsafe_flag (XRCE only; test_xrce_translate)


def test_prearm_reason_quotes_px4() -> None:
    text = StatusText(MavSeverity.CRITICAL, "Preflight Fail: Accel 0 uncalibrated")
    state = state_with(*GOOD, replace(GOOD_SYS, sensors_health=0), text)
    verdict = readiness(state, 0.0, CONFIG)
    assert verdict.reason is Reason.PREARM_FAILED
    assert "Accel 0 uncalibrated" in verdict.detail
    assert verdict.px4_says == text.text
    info = StatusText(MavSeverity.INFO, "Takeoff detected")
    assert state_with(info).last_warning is None  # only warnings and worse are kept


def test_heartbeat_staleness_boundary() -> None:
    state = state_with(*GOOD, now=100.0)
    assert readiness(state, 100.0 + 2.0, CONFIG).ready  # one missed 1 Hz heartbeat: fine
    stale = readiness(state, 100.0 + CONFIG.heartbeat_timeout_s, CONFIG)
    assert stale.reason is Reason.HEARTBEAT_STALE
    assert state.next_deadline(CONFIG) == 100.0 + CONFIG.heartbeat_timeout_s
    assert VehicleState().next_deadline(CONFIG) is None


def test_link_loss_flips_readiness_within_3_s() -> None:
    """Simulated vehicle streaming over MAVLink bytes; at t=20 s the link goes dead."""
    cut_at = 20.0
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(7), 0.0)
    state = VehicleState()

    def drop(msg: object, direction: str, now: float) -> bool:
        return now >= cut_at

    link = VirtualLink(sim, state, 0.0, drop=drop)
    link.run_until(cut_at)
    assert readiness(state, link.now, CONFIG).ready
    last_heard = state.heartbeat_at
    assert last_heard is not None and last_heard <= cut_at
    flipped_at = None
    t = cut_at
    while t < cut_at + 10.0:
        t = round(t + 0.01, 2)
        link.run_until(t)
        if not readiness(state, t, CONFIG).ready:
            flipped_at = t
            break
    assert flipped_at is not None
    assert readiness(state, flipped_at, CONFIG).reason is Reason.HEARTBEAT_STALE
    assert flipped_at - cut_at <= 3.0
    assert flipped_at - last_heard <= 3.0
