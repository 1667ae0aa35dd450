"""MAVLink and PX4 numbers the bridge and the simulator use, named once.

Values are the MAVLink ``common`` dialect's and PX4's own (``px4_custom_mode.h``); the tests
cross-check every one against pymavlink's generated dialect, so a typo here fails a test
instead of silently mis-reading a field. Kept separate from pymavlink so the pure readiness
and take-off logic imports nothing but the standard library.
"""

from __future__ import annotations

from enum import IntEnum
from typing import Final

# Component ids (MAV_COMPONENT)
COMP_ID_AUTOPILOT1: Final = 1
COMP_ID_ONBOARD_COMPUTER: Final = 191  # the companion's own id (MAVSDK CompanionComputer)

# MAV_TYPE / MAV_AUTOPILOT
MAV_TYPE_QUADROTOR: Final = 2
MAV_TYPE_ONBOARD_CONTROLLER: Final = 18
MAV_AUTOPILOT_INVALID: Final = 8
MAV_AUTOPILOT_PX4: Final = 12

# MAV_MODE_FLAG bits in HEARTBEAT.base_mode
MODE_FLAG_CUSTOM_MODE_ENABLED: Final = 1
MODE_FLAG_SAFETY_ARMED: Final = 128

# MAV_SYS_STATUS_SENSOR bits
SENSOR_PREARM_CHECK: Final = 0x10000000  # bit 28; PX4 sets it in *health* only (SYS_STATUS.hpp)
SENSOR_EXTENSION_USED: Final = 0x80000000  # PX4 ORs it into present/enabled/health always

# COMMAND_LONG magic value that forces arming/disarming past the checks; never sent by swarmd
ARM_FORCE_MAGIC: Final = 21196


class MavState(IntEnum):
    """HEARTBEAT.system_status (MAV_STATE)."""

    UNINIT = 0
    BOOT = 1
    CALIBRATING = 2
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7
    FLIGHT_TERMINATION = 8


class LandedState(IntEnum):
    """EXTENDED_SYS_STATE.landed_state (MAV_LANDED_STATE)."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class GpsFixType(IntEnum):
    """GPS_RAW_INT.fix_type (GPS_FIX_TYPE)."""

    NO_GPS = 0
    NO_FIX = 1
    FIX_2D = 2
    FIX_3D = 3
    DGPS = 4
    RTK_FLOAT = 5
    RTK_FIXED = 6
    STATIC = 7
    PPP = 8


class MavResult(IntEnum):
    """COMMAND_ACK.result (MAV_RESULT). pymavlink 2.4.50 lacks CANCELLED (6); we name it."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5
    CANCELLED = 6
    COMMAND_LONG_ONLY = 7
    COMMAND_INT_ONLY = 8
    UNSUPPORTED_MAV_FRAME = 9


class MavCmd(IntEnum):
    """The MAV_CMD ids swarmd sends or the simulator answers."""

    NAV_LAND = 21
    NAV_TAKEOFF = 22
    DO_SET_MODE = 176
    COMPONENT_ARM_DISARM = 400
    SET_MESSAGE_INTERVAL = 511
    REQUEST_MESSAGE = 512


class MavSeverity(IntEnum):
    """STATUSTEXT.severity (MAV_SEVERITY)."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class Px4MainMode(IntEnum):
    """PX4_CUSTOM_MAIN_MODE (px4_custom_mode.h). 9 (SIMPLE) is reserved and never sent, so
    unnamed here: it reads ``MODE(9,0)``."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE = 8
    TERMINATION = 10  # nav_state 13 (flight termination)
    ALTITUDE_CRUISE = 11  # nav_state 8, PX4 1.17 (fixed-wing Altitude Cruise)


class Px4PosctlSubMode(IntEnum):
    """PX4_CUSTOM_SUB_MODE_POSCTL (px4_custom_mode.h); only meaningful with main mode POSCTL.
    ORBIT is ``vehicle_status`` NAVIGATION_STATE_ORBIT (``get_px4_custom_mode``)."""

    POSCTL = 0
    ORBIT = 1
    SLOW = 2


class Px4AutoSubMode(IntEnum):
    """PX4_CUSTOM_SUB_MODE_AUTO (px4_custom_mode.h); only meaningful with main mode AUTO."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    RTGS = 7
    FOLLOW_TARGET = 8
    PRECLAND = 9
    VTOL_TAKEOFF = 10
    # nav_state 23-30 (PX4 >= 1.15): modes another program registers and runs over ROS 2
    # (PX4 user guide, "PX4 external (ROS 2) modes")
    EXTERNAL1 = 11
    EXTERNAL2 = 12
    EXTERNAL3 = 13
    EXTERNAL4 = 14
    EXTERNAL5 = 15
    EXTERNAL6 = 16
    EXTERNAL7 = 17
    EXTERNAL8 = 18


# Message ids used by the simulator's REQUEST_MESSAGE handling
MSG_ID_HOME_POSITION: Final = 242
