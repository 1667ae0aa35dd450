"""The backend-neutral vocabulary between a flight-controller backend and swarmd's logic.

Readiness and take-off never see a pymavlink object: a backend translates what it receives
into these frozen dataclasses (named after the MAVLink messages whose fields they carry,
because the readiness predicate is specified in those fields) and turns ``VehicleCommand``
into whatever its wire wants (COMMAND_LONG for MAVLink, ``/fmu/in/vehicle_command`` for
XRCE-DDS). The XRCE-DDS backend maps ``VehicleStatus``/``VehicleLandDetected``/
``SensorGps``/``HomePosition``/``BatteryStatus`` onto the same classes (docs/px4.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final

from swarmd.px4.constants import (
    MODE_FLAG_SAFETY_ARMED,
    SENSOR_PREARM_CHECK,
    MavCmd,
    Px4AutoSubMode,
    Px4MainMode,
    Px4PosctlSubMode,
)

NAN = math.nan


# the main modes whose sub-modes PX4 names (px4_custom_mode.h)
_SUB_MODES: Final[dict[Px4MainMode, type[IntEnum]]] = {
    Px4MainMode.AUTO: Px4AutoSubMode,
    Px4MainMode.POSCTL: Px4PosctlSubMode,
}


@dataclass(frozen=True, slots=True)
class Px4Mode:
    """A PX4 flight mode: ``custom_mode = main << 16 | sub << 24`` (px4_custom_mode.h union)."""

    main: int
    sub: int = 0

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Px4Mode:
        return cls(main=(custom_mode >> 16) & 0xFF, sub=(custom_mode >> 24) & 0xFF)

    @property
    def custom_mode(self) -> int:
        return (self.main & 0xFF) << 16 | (self.sub & 0xFF) << 24

    @property
    def name(self) -> str:
        """``AUTO.TAKEOFF``, ``POSCTL``, ``POSCTL.ORBIT``, or ``MODE(main,sub)`` for numbers
        PX4 did not define. A sub-mode is named where PX4 defines one (AUTO, POSCTL) and shown
        as a number on any other main mode, so two modes never read alike."""
        try:
            main = Px4MainMode(self.main)
        except ValueError:
            return f"MODE({self.main},{self.sub})"
        if self.sub == 0 and main != Px4MainMode.AUTO:
            return main.name
        subs = _SUB_MODES.get(main)
        try:
            sub = str(self.sub) if subs is None else subs(self.sub).name
        except ValueError:  # a sub-mode number PX4 did not define
            sub = str(self.sub)
        return f"{main.name}.{sub}"

    @property
    def known(self) -> bool:
        """PX4 defines this (main, sub), so ``name`` spells it out rather than in numbers."""
        try:
            main = Px4MainMode(self.main)
        except ValueError:
            return False
        if self.sub == 0 and main != Px4MainMode.AUTO:
            return True
        subs = _SUB_MODES.get(main)
        return subs is not None and self.sub in {int(m) for m in subs}

    def __str__(self) -> str:
        return self.name


MODE_TAKEOFF = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.TAKEOFF)
MODE_LOITER = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LOITER)  # "Hold"
MODE_LAND = Px4Mode(Px4MainMode.AUTO, Px4AutoSubMode.LAND)


@dataclass(frozen=True, slots=True)
class Heartbeat:
    """HEARTBEAT (0) from the autopilot."""

    autopilot: int
    vehicle_type: int
    base_mode: int
    custom_mode: int
    system_status: int
    # XRCE-DDS: the vehicle_status.nav_state the mode was read from (None over MAVLink). A
    # nav_state PX4 1.14-1.17 leaves free, or one of a later PX4, maps to no mode (0, 0):
    # the number itself is what names it to the operator (readiness ``flight_mode``)
    nav_state: int | None = None

    @property
    def armed(self) -> bool:
        return bool(self.base_mode & MODE_FLAG_SAFETY_ARMED)

    @property
    def mode(self) -> Px4Mode:
        # PX4 always sets CUSTOM_MODE_ENABLED; the custom mode alone identifies the mode
        return Px4Mode.from_custom_mode(self.custom_mode)


@dataclass(frozen=True, slots=True)
class SysStatus:
    """SYS_STATUS (1): PX4's arming verdict and the battery."""

    sensors_health: int
    battery_remaining: int  # percent, -1 unknown
    voltage_battery_mv: int  # UINT16_MAX unknown
    sensors_present: int = 0
    sensors_enabled: int = 0

    @property
    def prearm_ok(self) -> bool:
        # health bit only: PX4 >= 1.14 never sets PREARM in present/enabled (SYS_STATUS.hpp)
        return bool(self.sensors_health & SENSOR_PREARM_CHECK)


@dataclass(frozen=True, slots=True)
class ExtendedSysState:
    """EXTENDED_SYS_STATE (245)."""

    landed_state: int
    vtol_state: int = 0


@dataclass(frozen=True, slots=True)
class GpsRawInt:
    """GPS_RAW_INT (24)."""

    fix_type: int
    satellites_visible: int
    eph_cm: int = 0xFFFF
    lat_e7: int = 0
    lon_e7: int = 0
    alt_mm: int = 0


@dataclass(frozen=True, slots=True)
class HomePosition:
    """HOME_POSITION (242): latitude/longitude in 1e-7 degrees, altitude in mm AMSL."""

    latitude_e7: int
    longitude_e7: int
    altitude_mm: int

    @property
    def altitude_amsl_m(self) -> float:
        return self.altitude_mm / 1000.0


@dataclass(frozen=True, slots=True)
class GlobalPositionInt:
    """GLOBAL_POSITION_INT (33): altitudes in mm (AMSL and above home)."""

    lat_e7: int
    lon_e7: int
    alt_mm: int
    relative_alt_mm: int
    time_boot_ms: int = 0


@dataclass(frozen=True, slots=True)
class CommandAck:
    """COMMAND_ACK (77)."""

    command: int
    result: int
    progress: int = 0
    target_system: int = 0
    target_component: int = 0


@dataclass(frozen=True, slots=True)
class StatusText:
    """STATUSTEXT (253): PX4's human-readable reasons ("Preflight Fail: ...")."""

    severity: int
    text: str


@dataclass(frozen=True, slots=True)
class ArmingBlockers:
    """PX4 flags that stop the arm or the take-off (XRCE-DDS ``failsafe_flags``; empty: none).

    MAVLink has no counterpart: there PX4's verdict arrives only as the PREARM bit and
    STATUSTEXT, which readiness reads already.
    """

    flags: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class TopicLayout:
    """A backend's word on whether it can read one of its topics (XRCE-DDS only).

    ``problem`` names a sample whose layout matches no known PX4 release (topic, length);
    None says the topic decodes again. MAVLink never produces it: its messages carry their
    own id and CRC_EXTRA, so an unknown layout there is a dropped frame, not a guess.
    """

    topic: str
    problem: str | None


@dataclass(frozen=True, slots=True)
class StateReset:
    """A backend's word that everything it said of the vehicle so far may be another life's.

    XRCE-DDS sends it on a new session (PX4 rebooted, or its client reconnected), MAVLink
    when PX4's boot clock went back (``boot_watch``): the vehicle's facts (armed, mode,
    landed, battery, position) are unknown until the new life's messages say them again
    (docs/px4.md, "Fresh state").
    """

    why: str


@dataclass(frozen=True, slots=True)
class BootClock:
    """A MAVLink message read only for its ``time_boot_ms`` (SYSTEM_TIME, ATTITUDE, ...).

    PX4's boot clock tells one life from the next (``boot_watch``); it is never an
    observation: the backend judges it and hands the vehicle state a ``StateReset`` at most.
    """

    message: str  # the MAVLink message name, e.g. "SYSTEM_TIME"
    time_boot_ms: int


@dataclass(frozen=True, slots=True)
class VehicleCommand:
    """A command for the autopilot (COMMAND_LONG 76 on MAVLink, VehicleCommand on DDS).

    ``params`` holds param1..param7; PX4 wants NaN in every parameter a command does not use
    (MAVSDK ``maybe_reserved``), so that is the default. ``target_system`` 0 means "the
    backend's vehicle"; the backend fills it in. ``confirmation`` counts retransmissions
    (MAVLink command protocol: 0 first, then 1, 2, ...).

    ``not_after`` is never on the wire: the end of the operator's validity for a command
    that starts motion (a take-off's ARM and NAV_TAKEOFF), on the sender's clock
    (``loop.time()``); a backend that repairs frames by itself (the XRCE reliable stream)
    repairs none past it (docs/dataplane.md, "Validity at the vehicle"). None: no bound.
    """

    command: int
    params: tuple[float, float, float, float, float, float, float] = (NAN,) * 7
    confirmation: int = 0
    target_system: int = 0
    target_component: int = 1
    not_after: float | None = field(default=None, compare=False)

    @classmethod
    def make(
        cls,
        command: int,
        *,
        p1: float = NAN,
        p2: float = NAN,
        p3: float = NAN,
        p4: float = NAN,
        p5: float = NAN,
        p6: float = NAN,
        p7: float = NAN,
        confirmation: int = 0,
    ) -> VehicleCommand:
        return cls(command, (p1, p2, p3, p4, p5, p6, p7), confirmation)

    def retransmission(self, confirmation: int) -> VehicleCommand:
        return VehicleCommand(
            self.command, self.params, min(confirmation, 255), self.target_system,
            self.target_component, self.not_after,
        )  # fmt: skip

    @property
    def label(self) -> str:
        return command_name(self.command)


Observation = (
    Heartbeat
    | SysStatus
    | ExtendedSysState
    | GpsRawInt
    | HomePosition
    | GlobalPositionInt
    | CommandAck
    | StatusText
    | TopicLayout
    | ArmingBlockers
    | StateReset
)
"""What a backend hands to the vehicle state and the take-off sequence."""


def command_name(command: int) -> str:
    """``NAV_TAKEOFF`` for 22; ``MAV_CMD(n)`` for ids swarmd does not name."""
    try:
        return MavCmd(command).name
    except ValueError:
        return f"MAV_CMD({command})"
