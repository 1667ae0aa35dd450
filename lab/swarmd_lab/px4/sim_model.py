"""A MAVLink vehicle **simulator** that behaves like PX4 as the reference describes (sans-IO).

This is not PX4 and nothing pretends it is: it exists so swarmd's readiness and take-off
logic can be exercised with real MAVLink bytes where no PX4 binary can be installed
(reference section 3). It reproduces the PX4 behaviour swarmd depends on, each cited where
it is implemented, and docs/px4.md lists where it departs from PX4.

Theory of operation: ``SimVehicle`` is driven by ``receive(msg, src, now)`` (commands from
a companion or GCS) and ``handle_timer(now)`` (the next stream or physics deadline,
``get_timer()``); it emits ``(message, is_broadcast)`` through ``messages_to_send()`` and
log records through ``next_log()``. Streams follow PX4's ONBOARD mavlink mode
(``mavlink_main.cpp``): HEARTBEAT 1 Hz, SYS_STATUS 5 Hz, EXTENDED_SYS_STATE 5 Hz,
HOME_POSITION 0.5 Hz, SYSTEM_TIME 1 Hz (the boot clock); GPS_RAW_INT at 5 Hz (PX4: per GNSS
update) and GLOBAL_POSITION_INT at 10 Hz (PX4: 50 Hz; fewer frames, same information).
``reboot`` power-cycles it: silent while it boots, then a new life (docs/px4.md, "Fresh
state"). Stream phases are drawn from the
injected ``random.Random`` so two simulators never tick in lockstep.
"""

from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass
from typing import Any, Final

from swarmd.px4.constants import (
    ARM_FORCE_MAGIC,
    COMP_ID_AUTOPILOT1,
    MAV_AUTOPILOT_PX4,
    MAV_TYPE_QUADROTOR,
    MODE_FLAG_CUSTOM_MODE_ENABLED,
    MODE_FLAG_SAFETY_ARMED,
    MSG_ID_HOME_POSITION,
    SENSOR_EXTENSION_USED,
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavSeverity,
    MavState,
    Px4MainMode,
)
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    MODE_TAKEOFF,
    BootClock,
    CommandAck,
    ExtendedSysState,
    GlobalPositionInt,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    Px4Mode,
    StatusText,
    SysStatus,
    VehicleCommand,
)

# Sensor bits PX4 reports healthy on a good bench vehicle: 3D gyro/accel/mag, abs pressure
# (bits 0, 1, 2, 3) and GPS (5); PREARM (28) is added only when arming would be allowed.
_SENSORS: Final = 0b101111
# the land detector's three stages (ground contact, maybe landed, landed) each take a third of
# LNDMC_TRIG_TIME while their conditions hold (PX4 MulticopterLandDetector)
LAND_STAGES: Final = 3
_GPS_BIT: Final = 1 << 5
PHYSICS_DT_S: Final = 0.1


@dataclass(frozen=True, slots=True)
class SimConfig:
    """The simulated vehicle. Defaults are PX4's parameter defaults where one exists."""

    sysid: int = 1
    gps_fix_after_s: float = 2.0
    battery_pct: float = 90.0
    fail_prearm: bool = False  # a sensor that never passes its pre-flight check
    no_home: bool = False  # never publish HOME_POSITION (PX4 can arm without it)
    reject_arms: int = 0  # answer the first N arm commands TEMPORARILY_REJECTED
    home_lat_deg: float = 47.397742  # PX4 SITL's default home (Zurich)
    home_lon_deg: float = 8.545594
    home_amsl_m: float = 488.0
    takeoff_speed_mps: float = 1.5  # MPC_TKO_SPEED
    land_speed_mps: float = 0.7  # MPC_LAND_SPEED
    spool_up_s: float = 1.0  # COM_SPOOLUP_TIME: motors spin up before any climb
    takeoff_ramp_s: float = 3.0  # MPC_TKO_RAMP_T: the climb rate ramps 0 -> MPC_TKO_SPEED
    land_vz_max_mps: float = 0.25  # LNDMC_Z_VEL_MAX: faster vertically is not landed
    land_trigger_s: float = 1.0  # LNDMC_TRIG_TIME: ground contact -> maybe landed -> landed
    mis_takeoff_alt_m: float = 2.5  # MIS_TAKEOFF_ALT
    disarm_preflight_s: float = 10.0  # COM_DISARM_PRFLT
    disarm_land_s: float = 2.0  # COM_DISARM_LAND
    battery_low_pct: float = 15.0  # BAT_LOW_THR: arming refused below it (simplified)
    battery_drain_pct_per_s: float = 0.05  # while armed


_STREAMS: Final[dict[str, float]] = {  # name -> period in seconds (PX4 ONBOARD mode rates)
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 0.2,
    "EXTENDED_SYS_STATE": 0.2,
    "GPS_RAW_INT": 0.2,
    "GLOBAL_POSITION_INT": 0.1,
    "HOME_POSITION": 2.0,
}
# SYSTEM_TIME (1 Hz in PX4's ONBOARD list) carries the boot clock before any fix; first, so
# a boot's first update sends it with the HEARTBEAT (its phase draws no random number, so
# the seeded schedules of the streams above are those of before it was added)
_ALL_STREAMS: Final[dict[str, float]] = {"SYSTEM_TIME": 1.0, **_STREAMS}
REBOOT_S: Final = 3.0  # silent while booting: a flight controller boots in seconds


class SimVehicle:
    """The simulated autopilot (component 1 of system ``config.sysid``).

    Driven by ``receive`` and ``handle_timer``; outputs ``messages_to_send``, ``get_timer``,
    ``next_log``. Never raises on received messages.
    """

    def __init__(self, config: SimConfig, rng: random.Random, now: float) -> None:
        self.config = config
        self._rng = rng
        self._log: deque[tuple[str, dict[str, Any]]] = deque()
        self._power_on(now)
        self._due = {name: now + rng.uniform(0.0, period) for name, period in _STREAMS.items()}
        self._due["HEARTBEAT"] = now  # announce at once
        self._due["SYSTEM_TIME"] = now  # every PX4 stream sends at its first update

    def reboot(self, now: float, boot_s: float = REBOOT_S) -> None:
        """Power-cycle at ``now``: silent for ``boot_s`` (PX4 loads NuttX, parameters,
        sensors, the estimator), then a new life, disarmed on the ground with no fix and no
        home, its boot clock (``time_boot_ms``) counted from ``now``. Commands sent
        meanwhile are never heard."""
        self._power_on(now)
        self.awake_at = now + boot_s
        self._due = dict.fromkeys(_ALL_STREAMS, self.awake_at)  # first update: all at once
        self._log_event("reboot", now, boot_s=boot_s)

    def _power_on(self, now: float) -> None:
        self.boot = now
        self.awake_at = now
        self.armed = False
        self.mode: Px4Mode = MODE_LOITER  # PX4 boots a multicopter in Hold without RC
        self.landed = LandedState.ON_GROUND
        self.alt_m = 0.0  # above home
        self.climb_mps = 0.0  # vertical speed, up positive
        # the land detector (PX4 vehicle_land_detected): all three true on the ground
        self.ground_contact = self.maybe_landed = self.landed_detected = True
        self.touchdown_at: float | None = None  # when the descent stopped at the ground
        self.target_alt_m = self.config.mis_takeoff_alt_m
        self.battery = self.config.battery_pct
        self.fix = GpsFixType.NO_FIX
        self.satellites = 0
        self.home_set = False
        self.armed_at: float | None = None
        self.taken_off = False  # since arming (PX4 _have_taken_off_since_arming)
        self.landed_at: float | None = None
        self._arm_rejects_left = self.config.reject_arms
        self._out: list[Observation | BootClock] = []
        self._physics_at = now + PHYSICS_DT_S
        self._last_physics = now
        self.commands_received = 0

    # ---- inputs -------------------------------------------------------------------------

    def receive(self, msg: object, src: tuple[int, int], now: float) -> None:
        """A message from (system, component); only COMMAND_LONG for us is acted on.

        ``object``: whatever the codec decoded (it may be MAVLink-only, like SETUP_SIGNING);
        naming the codec's type here would import pymavlink into this sans-IO model."""
        if not isinstance(msg, VehicleCommand) or now < self.awake_at:
            return  # companion / GCS heartbeats etc.; nothing is heard while booting
        if msg.target_system not in (0, self.config.sysid):
            return  # PX4 ignores commands for another system
        if msg.target_component not in (0, COMP_ID_AUTOPILOT1):
            return
        self.commands_received += 1
        self._physics(now)
        result = self._command(msg, now)
        self._log_event(
            "command", now, command=msg.label, confirmation=msg.confirmation,
            result=result.name, src=list(src),
        )  # fmt: skip
        self._out.append(CommandAck(msg.command, int(result), 0, src[0], src[1]))

    def handle_timer(self, now: float) -> None:
        self._physics(now)
        if now < self.awake_at:
            self._out.clear()  # booting: the mavlink module has not started yet
        for name, period in _ALL_STREAMS.items():
            if now >= self._due[name]:
                self._stream(name, now)
                # keep the grid (no drift) but never queue a burst after a long stall
                self._due[name] = max(self._due[name] + period, now)

    # ---- outputs ------------------------------------------------------------------------

    def get_timer(self) -> float:
        return min(self._physics_at, *self._due.values())

    def messages_to_send(self) -> list[Observation | BootClock]:
        out, self._out = self._out, []
        return out

    def next_log(self) -> tuple[str, dict[str, Any]] | None:
        return self._log.popleft() if self._log else None

    # ---- PX4-like state -----------------------------------------------------------------

    @property
    def global_position_ok(self) -> bool:
        return self.fix >= GpsFixType.FIX_3D

    def prearm_failure(self) -> str | None:
        """PX4's arming verdict *in the current mode* (SYS_STATUS.hpp can_arm_mode_flags)."""
        if self.config.fail_prearm:
            return "Preflight Fail: Accel 0 uncalibrated (simulated by --fail-prearm)"
        if self.battery < self.config.battery_low_pct:
            return "Preflight Fail: low battery"
        if self.mode.main == Px4MainMode.AUTO and not self.global_position_ok:
            # Hold/Takeoff need a global position estimate; PX4 clears the bit without it
            return "Preflight Fail: No valid global position estimate"
        return None

    def heartbeat(self) -> Heartbeat:
        base = MODE_FLAG_CUSTOM_MODE_ENABLED | (MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        status = MavState.ACTIVE if self.armed else MavState.STANDBY
        return Heartbeat(
            autopilot=MAV_AUTOPILOT_PX4,
            vehicle_type=MAV_TYPE_QUADROTOR,
            base_mode=base,
            custom_mode=self.mode.custom_mode,
            system_status=status,
        )

    def sys_status(self) -> SysStatus:
        present = _SENSORS | SENSOR_EXTENSION_USED
        health = present if self.global_position_ok else present & ~_GPS_BIT
        if self.config.fail_prearm:
            health &= ~0b10  # the accelerometer the failure names
        if self.prearm_failure() is None:
            health |= SENSOR_PREARM_CHECK  # health only, never present/enabled (PX4 >= 1.14)
        return SysStatus(
            sensors_health=health,
            battery_remaining=max(0, min(100, round(self.battery))),
            voltage_battery_mv=14000 + round(self.battery * 28),  # 4S pack: 14.0 .. 16.8 V
            sensors_present=present,
            sensors_enabled=present,
        )

    # ---- commands -----------------------------------------------------------------------

    def _command(self, cmd: VehicleCommand, now: float) -> MavResult:
        p = cmd.params
        match cmd.command:
            case MavCmd.COMPONENT_ARM_DISARM:
                return self._arm_disarm(p[0], p[1], now)
            case MavCmd.NAV_TAKEOFF:
                return self._takeoff(p[6], now)
            case MavCmd.DO_SET_MODE:
                return self._set_mode(p[1], p[2], now)
            case MavCmd.NAV_LAND:
                if self.landed == LandedState.ON_GROUND and not self.armed:
                    return MavResult.TEMPORARILY_REJECTED
                self._set_mode_to(MODE_LAND, now)
                self._text(MavSeverity.INFO, "Landing at current position", now)
                return MavResult.ACCEPTED
            case MavCmd.REQUEST_MESSAGE:
                if not (math.isfinite(p[0]) and round(p[0]) == MSG_ID_HOME_POSITION):
                    return MavResult.UNSUPPORTED  # the simulator serves HOME_POSITION only
                if not self.home_set:
                    return MavResult.FAILED
                self._out.append(self._home())
                return MavResult.ACCEPTED
        return MavResult.UNSUPPORTED

    def _arm_disarm(self, p1: float, p2: float, now: float) -> MavResult:
        if not math.isfinite(p1) or round(p1) not in (0, 1):
            self._text(MavSeverity.ERROR, "Unsupported ARM_DISARM param", now)
            return MavResult.DENIED  # Commander: lroundf(param1) must be 0 or 1
        force = math.isfinite(p2) and round(p2) == ARM_FORCE_MAGIC
        if round(p1) == 1:
            if self.armed:
                return MavResult.ACCEPTED  # idempotent, as PX4
            if self._arm_rejects_left > 0:
                self._arm_rejects_left -= 1
                self._text(MavSeverity.CRITICAL, "Arming denied: simulated rejection", now)
                return MavResult.TEMPORARILY_REJECTED
            failure = None if force else self.prearm_failure()
            if failure is not None:
                self._text(MavSeverity.CRITICAL, failure, now)
                return MavResult.TEMPORARILY_REJECTED  # PX4 answers a denied arm this way
            self.armed, self.armed_at, self.taken_off = True, now, False
            self._text(MavSeverity.INFO, "Armed by external command", now)
            self._log_event("armed", now)
            return MavResult.ACCEPTED
        if not self.armed:
            return MavResult.ACCEPTED
        if self.landed != LandedState.ON_GROUND and not force:
            self._text(MavSeverity.CRITICAL, "Disarming denied: not landed", now)
            return MavResult.TEMPORARILY_REJECTED
        self._disarm("external command", now)
        return MavResult.ACCEPTED

    def _takeoff(self, alt_amsl: float, now: float) -> MavResult:
        if not (self.global_position_ok and self.home_set):
            self._text(MavSeverity.CRITICAL, "Takeoff denied: no global position", now)
            return MavResult.TEMPORARILY_REJECTED
        if self.landed != LandedState.ON_GROUND and self.mode != MODE_TAKEOFF:
            return MavResult.TEMPORARILY_REJECTED  # already flying: not modelled
        # navigator takeoff.cpp: NaN -> home + MIS_TAKEOFF_ALT; lower than that -> raised
        minimum = self.config.mis_takeoff_alt_m
        if math.isnan(alt_amsl):
            target = minimum
            self._text(MavSeverity.INFO, f"Using minimum takeoff altitude: {minimum:.2f} m", now)
        else:
            target = alt_amsl - self.config.home_amsl_m
            if target < minimum:
                if target < minimum - 0.1:
                    self._text(
                        MavSeverity.CRITICAL,
                        f"Using minimum takeoff altitude: {minimum:.2f} m",
                        now,
                    )
                target = minimum
        self.target_alt_m = target
        self._set_mode_to(MODE_TAKEOFF, now)  # disarmed: mode only, climbs once armed
        return MavResult.ACCEPTED

    def _set_mode(self, main: float, sub: float, now: float) -> MavResult:
        if not (math.isfinite(main) and math.isfinite(sub)):
            return MavResult.DENIED
        mode = Px4Mode(round(main), round(sub) if round(main) == Px4MainMode.AUTO else 0)
        if mode == MODE_TAKEOFF:
            return self._takeoff(math.nan, now)
        if mode == MODE_LOITER:
            self._set_mode_to(MODE_LOITER, now)
            return MavResult.ACCEPTED
        if mode == MODE_LAND:
            self._set_mode_to(MODE_LAND, now)
            return MavResult.ACCEPTED
        self._text(MavSeverity.WARNING, f"simulator: mode {mode} not modelled", now)
        return MavResult.TEMPORARILY_REJECTED

    # ---- physics ------------------------------------------------------------------------

    def _physics(self, now: float) -> None:
        while self._physics_at <= now:
            self._step(self._physics_at, self._physics_at - self._last_physics)
            self._last_physics = self._physics_at
            self._physics_at += PHYSICS_DT_S

    def _step(self, t: float, dt: float) -> None:
        c = self.config
        if not self.global_position_ok and t - self.boot >= c.gps_fix_after_s:
            self.fix = GpsFixType.FIX_3D
            self.satellites = self._rng.randint(10, 16)
            self._log_event("gps_fix", t, satellites=self.satellites)
            if not c.no_home:
                self.home_set = True  # PX4 sets home on the first valid global position
                self._text(MavSeverity.INFO, "home set", t)
        if self.armed:
            self.battery = max(0.0, self.battery - c.battery_drain_pct_per_s * dt)
        self.climb_mps = 0.0
        if self.armed and self.mode == MODE_TAKEOFF and self.armed_at is not None:
            climbing_s = t - self.armed_at - c.spool_up_s
            if climbing_s > 0 and self.alt_m < self.target_alt_m:
                # FlightTaskAuto takeoff: the velocity setpoint ramps over MPC_TKO_RAMP_T
                ramp = min(1.0, climbing_s / c.takeoff_ramp_s) if c.takeoff_ramp_s > 0 else 1.0
                self.climb_mps = c.takeoff_speed_mps * ramp
                self.alt_m = min(self.target_alt_m, self.alt_m + self.climb_mps * dt)
            if self.climb_mps > c.land_vz_max_mps and self.landed_detected:
                # lift-off: the detector leaves "landed" at once (no hysteresis going up)
                self.ground_contact = self.maybe_landed = self.landed_detected = False
                self.touchdown_at = None
                self.landed = LandedState.TAKEOFF
                if not self.taken_off:
                    self.taken_off = True
                    self._text(MavSeverity.INFO, "Takeoff detected", t)
            if not self.landed_detected and self.alt_m >= self.target_alt_m - 1e-6:
                self.landed = LandedState.IN_AIR
                self._set_mode_to(MODE_LOITER, t)  # navigator: takeoff done -> Hold
        elif self.landed == LandedState.LANDING and self.mode != MODE_LAND:
            # PX4 reports LANDING only while the setpoint is a land one (mavlink
            # EXTENDED_SYS_STATE: position_setpoint_triplet type LAND); a HOLD in the
            # descent is in the air again
            self.landed = LandedState.IN_AIR
        elif self.armed and self.mode == MODE_LAND and self.landed != LandedState.ON_GROUND:
            self.landed = LandedState.LANDING
            if self.alt_m > 0.0:
                self.climb_mps = -c.land_speed_mps
                self.alt_m = max(0.0, self.alt_m - c.land_speed_mps * dt)
            elif self._land_detector(t):
                self.landed, self.landed_at = LandedState.ON_GROUND, t
                self._text(MavSeverity.INFO, "Landing detected", t)
        if self.armed and self.landed == LandedState.ON_GROUND:
            if not self.taken_off and self.armed_at is not None:
                if t - self.armed_at >= c.disarm_preflight_s:  # COM_DISARM_PRFLT
                    self._disarm("auto preflight disarming", t)
            elif self.landed_at is not None and t - self.landed_at >= c.disarm_land_s:
                self._disarm("landing", t)  # COM_DISARM_LAND

    def _land_detector(self, t: float) -> bool:
        """At the ground and still: ground contact, maybe landed, landed, each after a third
        of LNDMC_TRIG_TIME (PX4's hysteresis); True once ``landed``."""
        if self.touchdown_at is None:
            self.touchdown_at = t
        stage_s = self.config.land_trigger_s / LAND_STAGES
        held = t - self.touchdown_at + 1e-9
        self.ground_contact = held >= stage_s
        self.maybe_landed = held >= 2 * stage_s
        self.landed_detected = held >= 3 * stage_s
        return self.landed_detected

    def _disarm(self, why: str, t: float) -> None:
        self.armed, self.armed_at, self.landed_at = False, None, None
        self._text(MavSeverity.INFO, f"Disarmed by {why}", t)  # PX4's wording
        self._log_event("disarmed", t, why=why)

    def _set_mode_to(self, mode: Px4Mode, t: float) -> None:
        if mode != self.mode:
            self._log_event("mode", t, old=self.mode.name, new=mode.name)
            self.mode = mode

    # ---- streams ------------------------------------------------------------------------

    def _stream(self, name: str, now: float) -> None:
        c = self.config
        lat = round(c.home_lat_deg * 1e7)
        lon = round(c.home_lon_deg * 1e7)
        match name:
            case "HEARTBEAT":
                self._out.append(self.heartbeat())
            case "SYS_STATUS":
                self._out.append(self.sys_status())
            case "EXTENDED_SYS_STATE":
                self._out.append(ExtendedSysState(landed_state=self.landed))
            case "GPS_RAW_INT":
                fixed = self.global_position_ok
                self._out.append(
                    GpsRawInt(
                        fix_type=self.fix,
                        satellites_visible=self.satellites if fixed else self._rng.randint(0, 3),
                        eph_cm=self._rng.randint(70, 120) if fixed else 0xFFFF,
                        lat_e7=lat if fixed else 0,
                        lon_e7=lon if fixed else 0,
                        alt_mm=round((c.home_amsl_m + self.alt_m) * 1000) if fixed else 0,
                    )
                )
            case "GLOBAL_POSITION_INT":
                if self.global_position_ok:
                    self._out.append(
                        GlobalPositionInt(
                            lat_e7=lat,
                            lon_e7=lon,
                            alt_mm=round((c.home_amsl_m + self.alt_m) * 1000),
                            relative_alt_mm=round(self.alt_m * 1000),
                            time_boot_ms=self._boot_ms(now),
                        )
                    )
            case "HOME_POSITION":
                if self.home_set:
                    self._out.append(self._home())
            case "SYSTEM_TIME":
                self._out.append(BootClock("SYSTEM_TIME", self._boot_ms(now)))

    def _boot_ms(self, now: float) -> int:
        return round((now - self.boot) * 1000) & 0xFFFFFFFF  # a uint32: wraps at 49.7 days

    def _home(self) -> HomePosition:
        c = self.config
        return HomePosition(
            latitude_e7=round(c.home_lat_deg * 1e7),
            longitude_e7=round(c.home_lon_deg * 1e7),
            altitude_mm=round(c.home_amsl_m * 1000),
        )

    def _text(self, severity: MavSeverity, text: str, now: float) -> None:
        self._out.append(StatusText(severity, text))
        self._log_event("statustext", now, severity=severity.name, text=text)

    def _log_event(self, event: str, now: float, **fields: Any) -> None:
        self._log.append((event, {"t": round(now - self.boot, 3), **fields}))

    def snapshot(self) -> dict[str, Any]:
        """A JSON-ready view for logs and tests."""
        return {
            "armed": self.armed,
            "mode": self.mode.name,
            "landed_state": self.landed.name,
            "land_detector": [self.ground_contact, self.maybe_landed, self.landed_detected],
            "alt_m": round(self.alt_m, 2),
            "gps_fix": int(self.fix),
            "home": self.home_set,
            "battery_pct": round(self.battery, 1),
            "prearm": self.prearm_failure() is None,
        }
