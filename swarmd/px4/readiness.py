"""Is the vehicle ready for take-off? Judged only from PX4's own messages.

Theory of operation: a backend decodes what the autopilot streams (HEARTBEAT 1 Hz, SYS_STATUS
5 Hz, EXTENDED_SYS_STATE 5 Hz, GPS_RAW_INT, HOME_POSITION 0.5 Hz in PX4's ONBOARD mavlink
mode) into ``swarmd.px4.messages`` observations and feeds them to ``VehicleState.observe``.
``readiness(state, now, config)`` is a pure function of that state and the time: it walks
the conditions of ``CONDITIONS`` in order and reports the first that fails, so an operator
always sees one stable reason code and one human line. Order matters: a topic the backend
cannot read (``TopicLayout``, XRCE only) hides the facts everything else judges, so it
comes first; a dead link makes every other field stale, so it comes next; "armed" and "not
in STANDBY" explain a missing PREARM bit, so they come before it, and so does the flight
mode (PX4 judges PREARM against the current mode's requirements); PX4's own verdict (PREARM)
comes before swarmd's stricter checks (3D fix, home, battery) because PX4 arms without GNSS
by default (COM_ARM_WO_GPS=1) and a swarm needs global position, hence both.

The flight mode (``arm_mode_problem``, one rule for both backends: MAVLink's
``custom_mode`` and XRCE's ``nav_state`` both arrive as ``Heartbeat.mode``): PX4 flies on
ARM alone in some modes. Armed in AUTO.TAKEOFF it climbs to ``MIS_TAKEOFF_ALT``, in
AUTO.MISSION it starts the uploaded mission, in OFFBOARD it follows whatever setpoints
another program streams (docs.px4.io flight_modes_mc/takeoff, flight_modes/offboard:
"before arming in offboard mode"). Another ground station or an RC switch may have put the
disarmed vehicle there, and our ARM would start that flight. So readiness accepts only the
modes of ``STAYS_ON_GROUND``, known to keep an armed vehicle on the ground until told more
(an allow-list: a mode PX4 adds later is refused until someone checks what it does on ARM;
an external ROS 2 mode is refused for good, its code being another program's).

Sans-IO: no clock, no I/O. ``now`` is monotonic seconds (the driver's ``loop.time()``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Final

from swarmd.px4.constants import (
    MAV_AUTOPILOT_PX4,
    GpsFixType,
    LandedState,
    MavSeverity,
    MavState,
    Px4AutoSubMode,
    Px4MainMode,
    Px4PosctlSubMode,
)
from swarmd.px4.messages import (
    MODE_LOITER,
    MODE_TAKEOFF,
    ArmingBlockers,
    CommandAck,
    ExtendedSysState,
    GlobalPositionInt,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    Px4Mode,
    StateReset,
    StatusText,
    SysStatus,
    TopicLayout,
)

# PX4 telemetry_status.HEARTBEAT_TIMEOUT_US = 2.5 s ("tolerate one missing + jitter"); also
# keeps "link loss flips readiness within 3 s" true with a 1 Hz heartbeat.
DEFAULT_HEARTBEAT_TIMEOUT_S: Final = 2.5


@dataclass(frozen=True, slots=True)
class ReadinessConfig:
    """Thresholds of the readiness predicate (the daemon config's ``px4`` section)."""

    heartbeat_timeout_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S
    min_battery_pct: float = 30.0
    min_fix_type: int = GpsFixType.FIX_3D
    require_home: bool = True
    # SYS_STATUS.battery_remaining = -1 means "no estimate": refuse unless told otherwise
    allow_unknown_battery: bool = False


class Reason(StrEnum):
    """Stable reason codes, in the order they are checked (docs/px4.md has the table)."""

    UNKNOWN_LAYOUT = "unknown_layout"
    NO_HEARTBEAT = "no_heartbeat"
    HEARTBEAT_STALE = "heartbeat_stale"
    NOT_PX4 = "not_px4"
    ARMED = "armed"
    NOT_STANDBY = "not_standby"
    FLIGHT_MODE = "flight_mode"
    PREARM_FAILED = "prearm_failed"
    FAILSAFE_FLAG = "failsafe_flag"
    NOT_ON_GROUND = "not_on_ground"
    NO_3D_FIX = "no_3d_fix"
    NO_HOME = "no_home"
    BATTERY_UNKNOWN = "battery_unknown"
    BATTERY_LOW = "battery_low"


# The modes in which an armed vehicle on the ground stays there until told more (module
# docstring), each with why. Every other mode is refused (``arm_mode_problem``).
STAYS_ON_GROUND: Final[dict[Px4Mode, str]] = {
    # manual modes: thrust is the pilot's throttle stick, nothing climbs without it
    Px4Mode(Px4MainMode.MANUAL): "thrust is the pilot's throttle stick",
    Px4Mode(Px4MainMode.STABILIZED): "thrust is the pilot's throttle stick",
    Px4Mode(Px4MainMode.ACRO): "thrust is the pilot's throttle stick",
    # assisted modes: the throttle stick is a climb rate and a centred (or absent) stick
    # holds the altitude, on the ground too (docs.px4.io flight_modes_mc/altitude, position).
    # POSCTL is sub-mode 0 only: POSCTL.ORBIT is NAVIGATION_STATE_ORBIT, which flies
    Px4Mode(Px4MainMode.ALTCTL): "climbs only on the pilot's throttle stick",
    Px4Mode(Px4MainMode.POSCTL): "climbs only on the pilot's throttle stick",
    # Position Slow (nav_state 6, PX4 1.15+): Position mode with lower speed limits, the
    # sticks mean the same (docs.px4.io flight_modes_mc/position_slow)
    Px4Mode(Px4MainMode.POSCTL, Px4PosctlSubMode.SLOW): "climbs only on the pilot's throttle "
    "stick (Position mode, slower)",
    # Hold: navigator's Loiter gives an idle setpoint while landed (navigator/loiter.cpp,
    # NAV_CMD_IDLE); the mode MAVSDK arms in and a multicopter without RC boots in
    MODE_LOITER: "Hold idles on the ground (PX4 navigator, Loiter)",
}
# External modes (nav_state 23-30, PX4 1.15+): a ROS 2 program registers each and PX4 runs
# its code (PX4 user guide, "PX4 external (ROS 2) modes"); what it does on ARM is that
# program's choice, which swarmd cannot check, so refused whatever it is
_EXTERNAL_MODES: Final = tuple(
    Px4Mode(Px4MainMode.AUTO, sub)
    for sub in range(Px4AutoSubMode.EXTERNAL1, Px4AutoSubMode.EXTERNAL8 + 1)
)
# Why some refused modes are refused, for the operator's detail only (the rule is the list
# above): PX4 docs, flight_modes_mc/takeoff, flight_modes_mc/mission, flight_modes/offboard,
# flight_modes_fw/altitude_cruise
_FLIES_ON_ARM: Final[dict[Px4Mode, str]] = {
    MODE_TAKEOFF: "climbs to MIS_TAKEOFF_ALT on ARM alone",
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.VTOL_TAKEOFF): "climbs on ARM alone",
    Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.MISSION): "starts its mission on ARM alone",
    Px4Mode(Px4MainMode.OFFBOARD): "follows another program's setpoints on ARM alone",
    Px4Mode(Px4MainMode.ALTITUDE_CRUISE): "is a fixed-wing mode not checked on ARM",
    Px4Mode(Px4MainMode.TERMINATION): "is flight termination",
    **{
        mode: "is an external mode: another program's code decides what it does on ARM"
        for mode in _EXTERNAL_MODES
    },
}


def arm_mode_problem(heartbeat: Heartbeat | None) -> str | None:
    """Why an ARM in the vehicle's current mode might start a flight nobody asked for, or
    None when the mode is one of ``STAYS_ON_GROUND``. No HEARTBEAT: the mode is unknown,
    which is a problem too. One rule for readiness and for every ARM the take-off sends."""
    if heartbeat is None:
        return "no HEARTBEAT: the flight mode is unknown"
    mode = heartbeat.mode
    if mode in STAYS_ON_GROUND:
        return None
    allowed = ", ".join(m.name for m in STAYS_ON_GROUND)
    what = _FLIES_ON_ARM.get(mode, "is not a mode known to stay on the ground when armed")
    return f"mode {mode.name}{_raw_mode(heartbeat)} {what}; a take-off arms only in {allowed}"


def _raw_mode(heartbeat: Heartbeat) -> str:
    """The number PX4 sent, for a mode swarmd cannot name: a free ``nav_state`` slot or a
    later PX4's mode reads MODE(0,0) over XRCE, and MODE(main,sub) says only part of a
    MAVLink ``custom_mode``; the raw number is what the operator looks up."""
    if heartbeat.mode.known:
        return ""
    if heartbeat.nav_state is not None:
        return f" (vehicle_status.nav_state {heartbeat.nav_state})"
    return f" (HEARTBEAT.custom_mode {heartbeat.custom_mode:#010x})"


@dataclass(slots=True)
class VehicleState:
    """The latest of each autopilot message and when it arrived (monotonic seconds)."""

    heartbeat: Heartbeat | None = None
    heartbeat_at: float | None = None
    sys_status: SysStatus | None = None
    sys_status_at: float | None = None
    extended: ExtendedSysState | None = None
    extended_at: float | None = None
    gps: GpsRawInt | None = None
    home: HomePosition | None = None
    position: GlobalPositionInt | None = None
    last_ack: CommandAck | None = None
    last_warning: StatusText | None = None  # latest STATUSTEXT of severity WARNING or worse
    last_warning_at: float | None = None
    # topic -> why its samples cannot be read (XRCE: a layout of no known PX4 release)
    layout_problems: dict[str, str] = field(default_factory=dict)
    arming_blockers: tuple[str, ...] = ()  # PX4 failsafe_flags that stop arm or take-off
    received: int = 0

    def observe(self, obs: Observation, now: float) -> None:
        """Record one decoded autopilot message received at ``now``."""
        self.received += 1
        match obs:
            case Heartbeat():
                self.heartbeat, self.heartbeat_at = obs, now
            case SysStatus():
                self.sys_status, self.sys_status_at = obs, now
            case ExtendedSysState():
                self.extended, self.extended_at = obs, now
            case GpsRawInt():
                self.gps = obs
            case HomePosition():
                self.home = obs
            case GlobalPositionInt():
                self.position = obs
            case CommandAck():
                self.last_ack = obs
            case StatusText():
                if obs.severity <= MavSeverity.WARNING:
                    self.last_warning, self.last_warning_at = obs, now
            case ArmingBlockers():
                self.arming_blockers = obs.flags
            case TopicLayout():
                if obs.problem is None:
                    self.layout_problems.pop(obs.topic, None)
                else:
                    self.layout_problems[obs.topic] = obs.problem
            case StateReset():
                self.forget_vehicle()

    def forget_vehicle(self) -> None:
        """Every fact of the vehicle becomes unknown (``StateReset``: a new XRCE session, or
        PX4's MAVLink boot clock gone back, may be a rebooted PX4). Readiness says
        ``no_heartbeat`` and no action is confirmed until the new life's messages arrive; what
        the backend cannot read stays (``layout_problems``, lifted only by a sample that
        decodes)."""
        self.heartbeat = self.heartbeat_at = None
        self.sys_status = self.sys_status_at = None
        self.extended = self.extended_at = None
        self.gps = self.home = self.position = None
        self.last_ack = None
        self.last_warning = self.last_warning_at = None
        self.arming_blockers = ()

    @property
    def armed(self) -> bool | None:
        return None if self.heartbeat is None else self.heartbeat.armed

    @property
    def landed_state(self) -> LandedState | None:
        if self.extended is None:
            return None
        try:
            return LandedState(self.extended.landed_state)
        except ValueError:
            return LandedState.UNDEFINED

    def heard_within(self, now: float, max_age_s: float) -> bool:
        """Did a HEARTBEAT arrive less than ``max_age_s`` before ``now``? The rest of the
        state is the last word of a vehicle that may since have rebooted or gone silent:
        it vouches for nothing older (readiness' ``heartbeat_stale``, the same limit)."""
        return self.heartbeat_at is not None and now - self.heartbeat_at < max_age_s

    def next_deadline(self, config: ReadinessConfig) -> float | None:
        """When readiness will change by time alone (the heartbeat going stale), or None."""
        if self.heartbeat_at is None:
            return None
        return self.heartbeat_at + config.heartbeat_timeout_s


@dataclass(frozen=True, slots=True)
class Readiness:
    """The verdict plus the facts behind it, JSON-ready through ``as_dict``."""

    ready: bool
    reason: Reason | None  # the first failing condition; None when ready
    detail: str  # one line for humans
    heartbeat_age_s: float | None
    armed: bool | None
    mode: str | None
    system_status: str | None
    prearm: bool | None
    landed_state: str | None
    gps_fix: int | None
    satellites: int | None
    home: bool
    battery_pct: int | None
    px4_says: str | None  # latest PX4 warning text, e.g. "Preflight Fail: ..."

    def as_dict(self) -> dict[str, Any]:
        return {
            "ready": self.ready,
            "reason": None if self.reason is None else str(self.reason),
            "detail": self.detail,
            "heartbeat_age_s": (
                None if self.heartbeat_age_s is None else round(self.heartbeat_age_s, 3)
            ),
            "armed": self.armed,
            "mode": self.mode,
            "system_status": self.system_status,
            "prearm": self.prearm,
            "landed_state": self.landed_state,
            "gps_fix": self.gps_fix,
            "satellites": self.satellites,
            "home": self.home,
            "battery_pct": self.battery_pct,
            "px4_says": self.px4_says,
        }


Check = Callable[[VehicleState, float, ReadinessConfig], tuple[Reason, str] | None]


def _layout(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.layout_problems:
        # first: a topic swarmd cannot read hides the very facts the other checks judge
        # (an unread vehicle_status is otherwise just "no_heartbeat")
        return Reason.UNKNOWN_LAYOUT, "; ".join(
            s.layout_problems[topic] for topic in sorted(s.layout_problems)
        )
    return None


def _link(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.heartbeat_at is None:
        return Reason.NO_HEARTBEAT, "no HEARTBEAT from the autopilot yet"
    age = now - s.heartbeat_at
    if age >= c.heartbeat_timeout_s:
        return Reason.HEARTBEAT_STALE, (
            f"last HEARTBEAT {age:.1f} s ago (limit {c.heartbeat_timeout_s:g} s)"
        )
    return None


def _px4(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.heartbeat is None:  # _link reported it already
        return None
    if s.heartbeat.autopilot != MAV_AUTOPILOT_PX4:
        return Reason.NOT_PX4, f"HEARTBEAT.autopilot={s.heartbeat.autopilot}, expected 12 (PX4)"
    return None


def _disarmed(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.heartbeat is None:
        return None
    if s.heartbeat.armed:
        return Reason.ARMED, f"already armed (mode {s.heartbeat.mode})"
    return None


def _standby(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.heartbeat is None:
        return None
    status = s.heartbeat.system_status
    if status != MavState.STANDBY:
        return Reason.NOT_STANDBY, f"system_status={_state_name(status)}, expected STANDBY"
    return None


def _mode(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.heartbeat is None:  # _link reported it already
        return None
    problem = arm_mode_problem(s.heartbeat)
    return None if problem is None else (Reason.FLIGHT_MODE, problem)


def _prearm(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.sys_status is None:
        return Reason.PREARM_FAILED, "no SYS_STATUS yet"
    if not s.sys_status.prearm_ok:
        said = f": PX4 says {s.last_warning.text!r}" if s.last_warning is not None else ""
        return Reason.PREARM_FAILED, f"PREARM_CHECK not set in SYS_STATUS health{said}"
    return None


def _failsafe(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.arming_blockers:
        # after PREARM: PX4's own verdict first, then the named flag behind it (XRCE only)
        return Reason.FAILSAFE_FLAG, (
            f"PX4 failsafe_flags: {', '.join(s.arming_blockers)} (blocks arming or take-off)"
        )
    return None


def _ground(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    landed = s.landed_state
    if landed is None:
        return Reason.NOT_ON_GROUND, "no EXTENDED_SYS_STATE yet"
    if landed != LandedState.ON_GROUND:
        return Reason.NOT_ON_GROUND, f"landed_state={landed.name}, expected ON_GROUND"
    return None


def _fix(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.gps is None:
        return Reason.NO_3D_FIX, "no GPS_RAW_INT yet"
    if s.gps.fix_type < c.min_fix_type:
        return Reason.NO_3D_FIX, (
            f"GPS fix_type={_fix_name(s.gps.fix_type)} with {s.gps.satellites_visible} "
            f"satellites, need >= {_fix_name(c.min_fix_type)}"
        )
    return None


def _home(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if c.require_home and s.home is None:
        return Reason.NO_HOME, "no HOME_POSITION received"
    return None


def _battery(s: VehicleState, now: float, c: ReadinessConfig) -> tuple[Reason, str] | None:
    if s.sys_status is None:  # _prearm reported it already
        return None
    pct = s.sys_status.battery_remaining
    if pct < 0:
        if c.allow_unknown_battery:
            return None
        return Reason.BATTERY_UNKNOWN, "SYS_STATUS.battery_remaining=-1 (no estimate)"
    if pct < c.min_battery_pct:
        return Reason.BATTERY_LOW, f"battery {pct}% < {c.min_battery_pct:g}%"
    return None


CONDITIONS: Final[tuple[Check, ...]] = (
    _layout,
    _link,
    _px4,
    _disarmed,
    _standby,
    _mode,
    _prearm,
    _failsafe,
    _ground,
    _fix,
    _home,
    _battery,
)


def readiness(state: VehicleState, now: float, config: ReadinessConfig) -> Readiness:
    """The take-off verdict at ``now``: ready, or the first failing condition."""
    failure: tuple[Reason, str] | None = None
    for check in CONDITIONS:
        failure = check(state, now, config)
        if failure is not None:
            break
    hb, sys, gps = state.heartbeat, state.sys_status, state.gps
    landed = state.landed_state
    return Readiness(
        ready=failure is None,
        reason=None if failure is None else failure[0],
        detail="ready for take-off" if failure is None else failure[1],
        heartbeat_age_s=None if state.heartbeat_at is None else now - state.heartbeat_at,
        armed=None if hb is None else hb.armed,
        mode=None if hb is None else hb.mode.name,
        system_status=None if hb is None else _state_name(hb.system_status),
        prearm=None if sys is None else sys.prearm_ok,
        landed_state=None if landed is None else landed.name,
        gps_fix=None if gps is None else gps.fix_type,
        satellites=None if gps is None else gps.satellites_visible,
        home=state.home is not None,
        battery_pct=None if sys is None or sys.battery_remaining < 0 else sys.battery_remaining,
        px4_says=None if state.last_warning is None else state.last_warning.text,
    )


def _state_name(value: int) -> str:
    try:
        return MavState(value).name
    except ValueError:
        return f"MAV_STATE({value})"


def _fix_name(value: int) -> str:
    try:
        return GpsFixType(value).name
    except ValueError:
        return f"FIX({value})"
