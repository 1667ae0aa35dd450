"""The MAVLink vehicle simulator's PX4-like behaviour (it is a simulator, not PX4)."""

from __future__ import annotations

import math
import random
from collections import Counter

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle

from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
)
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    MODE_TAKEOFF,
    BootClock,
    CommandAck,
    Heartbeat,
    Observation,
    StatusText,
    SysStatus,
    VehicleCommand,
)

COMPANION = (1, 191)


def run(sim: SimVehicle, until: float, now: float) -> tuple[float, list[Observation | BootClock]]:
    out: list[Observation | BootClock] = []
    while sim.get_timer() <= until:
        now = sim.get_timer()
        sim.handle_timer(now)
        out += sim.messages_to_send()
    return until, out


def command(sim: SimVehicle, now: float, cmd: VehicleCommand) -> tuple[MavResult, list[str]]:
    sim.receive(cmd, COMPANION, now)
    out = sim.messages_to_send()
    acks = [m for m in out if isinstance(m, CommandAck)]
    assert len(acks) == 1 and acks[0].command == cmd.command
    assert (acks[0].target_system, acks[0].target_component) == COMPANION
    texts = [m.text for m in out if isinstance(m, StatusText)]
    return MavResult(acks[0].result), texts


def armed(sim: SimVehicle) -> bool:
    """A call, not the attribute: mypy would narrow ``sim.armed`` across the steps."""
    return sim.armed


ARM = VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=1.0)
DISARM = VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=0.0)


def test_stream_rates_follow_px4_onboard_mode() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0), random.Random(1), 0.0)
    _, out = run(sim, 20.0, 0.0)
    counts = Counter(type(m).__name__ for m in out)
    assert 20 <= counts["Heartbeat"] <= 21  # 1 Hz
    assert 99 <= counts["SysStatus"] <= 101  # 5 Hz
    assert 99 <= counts["ExtendedSysState"] <= 101  # 5 Hz
    assert 9 <= counts["HomePosition"] <= 11  # 0.5 Hz
    assert 99 <= counts["GpsRawInt"] <= 101
    hb = next(m for m in out if isinstance(m, Heartbeat))
    assert (hb.autopilot, hb.system_status, hb.mode) == (12, MavState.STANDBY, MODE_LOITER)


def test_prearm_bit_appears_with_the_gps_fix_in_health_only() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=3.0), random.Random(1), 0.0)
    _, before = run(sim, 2.9, 0.0)
    _, after = run(sim, 4.0, 2.9)
    sys_before = [m for m in before if isinstance(m, SysStatus)]
    sys_after = [m for m in after if isinstance(m, SysStatus)]
    assert sys_before and not any(m.prearm_ok for m in sys_before)
    assert sys_after[-1].prearm_ok
    assert not sys_after[-1].sensors_present & SENSOR_PREARM_CHECK
    assert not sys_after[-1].sensors_enabled & SENSOR_PREARM_CHECK


def test_arming_denied_is_temporarily_rejected_with_a_statustext() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0, fail_prearm=True), random.Random(1), 0.0)
    now, _ = run(sim, 1.0, 0.0)
    result, texts = command(sim, now, ARM)
    assert result is MavResult.TEMPORARILY_REJECTED
    assert any(t.startswith("Preflight Fail:") for t in texts)
    assert not armed(sim)


def test_arm_param_rules() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0), random.Random(1), 0.0)
    now, _ = run(sim, 1.0, 0.0)
    assert command(sim, now, VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=2.0))[0] is (
        MavResult.DENIED
    )
    assert command(sim, now, ARM)[0] is MavResult.ACCEPTED
    assert command(sim, now, ARM)[0] is MavResult.ACCEPTED  # idempotent, as PX4
    assert command(sim, now, DISARM)[0] is MavResult.ACCEPTED  # on the ground


def test_auto_disarm_after_10_s_on_the_ground() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0), random.Random(1), 0.0)
    now, _ = run(sim, 1.0, 0.0)
    assert command(sim, now, ARM)[0] is MavResult.ACCEPTED
    now, _ = run(sim, now + 9.8, now)
    assert armed(sim)
    now, out = run(sim, now + 0.4, now)
    assert not armed(sim)
    assert "Disarmed by auto preflight disarming" in [
        m.text for m in out if isinstance(m, StatusText)
    ]


def test_commands_for_another_system_are_ignored() -> None:
    sim = SimVehicle(SimConfig(sysid=2, gps_fix_after_s=0.0), random.Random(1), 0.0)
    run(sim, 1.0, 0.0)
    other = VehicleCommand(MavCmd.COMPONENT_ARM_DISARM, (1.0,) + (math.nan,) * 6, 0, 1, 1)
    sim.receive(other, COMPANION, 1.0)
    assert sim.messages_to_send() == [] and not armed(sim)


def test_climb_hold_land_and_disarm() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0), random.Random(1), 0.0)
    now, _ = run(sim, 1.0, 0.0)
    takeoff = VehicleCommand.make(MavCmd.NAV_TAKEOFF, p7=488.0 + 6.0)
    assert command(sim, now, takeoff)[0] is MavResult.ACCEPTED  # disarmed: mode only
    assert sim.mode == MODE_TAKEOFF and sim.alt_m == 0.0
    assert command(sim, now, ARM)[0] is MavResult.ACCEPTED
    states, alts = [], []
    while sim.landed != LandedState.IN_AIR and now < 20.0:
        now, _ = run(sim, now + 0.1, now)
        states.append(sim.landed)
        alts.append(sim.alt_m)
    assert states[0] == LandedState.ON_GROUND and LandedState.TAKEOFF in states
    assert alts == sorted(alts) and sim.alt_m == pytest.approx(6.0)
    # 1 s spool-up (COM_SPOOLUP_TIME), 3 s ramp to 1.5 m/s (MPC_TKO_RAMP_T, MPC_TKO_SPEED:
    # 2.3 m), the other 3.7 m at 1.5 m/s: 6.5 s from the arm to IN_AIR
    assert 6.0 <= now - 1.0 <= 7.0
    # the land detector let go when the climb passed LNDMC_Z_VEL_MAX, 0.5 s into the ramp
    assert states.index(LandedState.TAKEOFF) * 0.1 == pytest.approx(1.5, abs=0.15)
    assert sim.mode == MODE_LOITER
    assert command(sim, now, DISARM)[0] is MavResult.TEMPORARILY_REJECTED  # not in the air
    land = VehicleCommand.make(MavCmd.NAV_LAND)
    assert command(sim, now, land)[0] is MavResult.ACCEPTED
    assert sim.mode == MODE_LAND
    now, _ = run(sim, now + 6.0 / 0.7 + 0.3, now)
    assert sim.snapshot()["landed_state"] == "LANDING"  # touched down, not yet "landed"
    assert sim.alt_m == 0.0
    now, _ = run(sim, now + 1.2, now)  # LNDMC_TRIG_TIME: three stages of 1/3 s
    assert sim.landed == LandedState.ON_GROUND and armed(sim)
    assert (sim.ground_contact, sim.maybe_landed, sim.landed_detected) == (True, True, True)
    now, _ = run(sim, now + 2.1, now)  # COM_DISARM_LAND
    assert not armed(sim)


def test_low_takeoff_altitude_is_raised_to_mis_takeoff_alt() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0), random.Random(1), 0.0)
    now, _ = run(sim, 1.0, 0.0)
    result, texts = command(sim, now, VehicleCommand.make(MavCmd.NAV_TAKEOFF, p7=488.5))
    assert result is MavResult.ACCEPTED and sim.target_alt_m == 2.5
    assert "Using minimum takeoff altitude: 2.50 m" in texts


def test_no_home_never_sends_home_position() -> None:
    sim = SimVehicle(SimConfig(gps_fix_after_s=0.0, no_home=True), random.Random(1), 0.0)
    now, out = run(sim, 10.0, 0.0)
    assert not any(type(m).__name__ == "HomePosition" for m in out)
    req = VehicleCommand.make(MavCmd.REQUEST_MESSAGE, p1=242.0)
    assert command(sim, now, req)[0] is MavResult.FAILED


def test_same_seed_same_bytes() -> None:
    def trace(seed: int) -> bytes:
        sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(seed), 0.0)
        codec = MavlinkCodec(1, 1)
        _, out = run(sim, 5.0, 0.0)
        return b"".join(codec.encode(m) for m in out)

    assert trace(5) == trace(5)
    assert trace(5) != trace(6)
