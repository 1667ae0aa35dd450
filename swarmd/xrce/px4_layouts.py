"""PX4 uORB message layouts for uXRCE-DDS, per release (generated: do not edit).

Made by scripts/gen_px4_layouts.py from px4_msgs at v1.14.0, v1.15.4, v1.16.0, v1.17.0
(PX4's msg/ definitions, BSD-3-Clause). Per release and message: the CDR payload size,
MESSAGE_VERSION, and (offset, struct code, count) of the fields swarmd uses.
"""

from typing import Final

Field = tuple[int, str, int]
Layout = tuple[int, int, dict[str, Field]]  # size, MESSAGE_VERSION, fields

VEHICLESTATUS_1_14: Final[Layout] = (
    71,
    0,
    {
        "timestamp": (0, "Q", 1),
        "arming_state": (24, "B", 1),
        "nav_state": (41, "B", 1),
        "vehicle_type": (45, "B", 1),
        "failsafe": (46, "?", 1),
        "system_id": (56, "B", 1),
        "component_id": (57, "B", 1),
        "pre_flight_checks_pass": (70, "?", 1),
    },
)
VEHICLELANDDETECTED_1_14: Final[Layout] = (
    20,
    0,
    {
        "timestamp": (0, "Q", 1),
        "ground_contact": (9, "?", 1),
        "maybe_landed": (10, "?", 1),
        "landed": (11, "?", 1),
    },
)
FAILSAFEFLAGS_1_14: Final[Layout] = (85, 0, {"timestamp": (0, "Q", 1)})
BATTERYSTATUS_1_14: Final[Layout] = (
    176,
    0,
    {
        "timestamp": (0, "Q", 1),
        "connected": (8, "?", 1),
        "voltage_v": (12, "f", 1),
        "remaining": (36, "f", 1),
    },
)
SENSORGPS_1_14: Final[Layout] = (
    141,
    0,
    {
        "timestamp": (0, "Q", 1),
        "lat": (20, "i", 1),
        "lon": (24, "i", 1),
        "alt": (28, "i", 1),
        "fix_type": (44, "B", 1),
        "eph": (48, "f", 1),
        "satellites_used": (120, "B", 1),
    },
)
HOMEPOSITION_1_14: Final[Layout] = (
    48,
    0,
    {
        "timestamp": (0, "Q", 1),
        "lat": (8, "d", 1),
        "lon": (16, "d", 1),
        "alt": (24, "f", 1),
        "valid_alt": (44, "?", 1),
        "valid_hpos": (45, "?", 1),
    },
)
VEHICLECOMMANDACK_1_14: Final[Layout] = (
    23,
    0,
    {
        "timestamp": (0, "Q", 1),
        "command": (8, "I", 1),
        "result": (12, "B", 1),
        "result_param1": (13, "B", 1),
        "result_param2": (16, "i", 1),
        "target_system": (20, "B", 1),
        "target_component": (21, "B", 1),
        "from_external": (22, "?", 1),
    },
)
VEHICLECOMMAND_1_14: Final[Layout] = (
    54,
    0,
    {
        "timestamp": (0, "Q", 1),
        "param1": (8, "f", 1),
        "param2": (12, "f", 1),
        "param3": (16, "f", 1),
        "param4": (20, "f", 1),
        "param5": (24, "d", 1),
        "param6": (32, "d", 1),
        "param7": (40, "f", 1),
        "command": (44, "I", 1),
        "target_system": (48, "B", 1),
        "target_component": (49, "B", 1),
        "source_system": (50, "B", 1),
        "source_component": (51, "B", 1),
        "confirmation": (52, "B", 1),
        "from_external": (53, "?", 1),
    },
)
VEHICLESTATUS_1_15: Final[Layout] = (
    82,
    0,
    {
        "timestamp": (0, "Q", 1),
        "arming_state": (24, "B", 1),
        "nav_state": (41, "B", 1),
        "vehicle_type": (55, "B", 1),
        "failsafe": (56, "?", 1),
        "system_id": (67, "B", 1),
        "component_id": (68, "B", 1),
        "pre_flight_checks_pass": (81, "?", 1),
    },
)
SENSORGPS_1_15: Final[Layout] = (
    159,
    0,
    {
        "timestamp": (0, "Q", 1),
        "latitude_deg": (24, "d", 1),
        "longitude_deg": (32, "d", 1),
        "altitude_msl_m": (40, "d", 1),
        "fix_type": (64, "B", 1),
        "eph": (68, "f", 1),
        "satellites_used": (136, "B", 1),
    },
)
HOMEPOSITION_1_15: Final[Layout] = (
    52,
    0,
    {
        "timestamp": (0, "Q", 1),
        "lat": (8, "d", 1),
        "lon": (16, "d", 1),
        "alt": (24, "f", 1),
        "valid_alt": (44, "?", 1),
        "valid_hpos": (45, "?", 1),
    },
)
VEHICLECOMMANDACK_1_15: Final[Layout] = (
    25,
    0,
    {
        "timestamp": (0, "Q", 1),
        "command": (8, "I", 1),
        "result": (12, "B", 1),
        "result_param1": (13, "B", 1),
        "result_param2": (16, "i", 1),
        "target_system": (20, "B", 1),
        "target_component": (22, "H", 1),
        "from_external": (24, "?", 1),
    },
)
VEHICLECOMMAND_1_15: Final[Layout] = (
    56,
    0,
    {
        "timestamp": (0, "Q", 1),
        "param1": (8, "f", 1),
        "param2": (12, "f", 1),
        "param3": (16, "f", 1),
        "param4": (20, "f", 1),
        "param5": (24, "d", 1),
        "param6": (32, "d", 1),
        "param7": (40, "f", 1),
        "command": (44, "I", 1),
        "target_system": (48, "B", 1),
        "target_component": (49, "B", 1),
        "source_system": (50, "B", 1),
        "source_component": (52, "H", 1),
        "confirmation": (54, "B", 1),
        "from_external": (55, "?", 1),
    },
)
VEHICLESTATUS_1_16: Final[Layout] = (
    80,
    1,
    {
        "timestamp": (0, "Q", 1),
        "arming_state": (24, "B", 1),
        "nav_state": (41, "B", 1),
        "vehicle_type": (55, "B", 1),
        "failsafe": (56, "?", 1),
        "system_id": (67, "B", 1),
        "component_id": (68, "B", 1),
        "pre_flight_checks_pass": (79, "?", 1),
    },
)
FAILSAFEFLAGS_1_16: Final[Layout] = (86, 0, {"timestamp": (0, "Q", 1)})
BATTERYSTATUS_1_16: Final[Layout] = (
    180,
    0,
    {
        "timestamp": (0, "Q", 1),
        "connected": (8, "?", 1),
        "voltage_v": (12, "f", 1),
        "remaining": (28, "f", 1),
    },
)
FAILSAFEFLAGS_1_17: Final[Layout] = (91, 0, {"timestamp": (0, "Q", 1)})
BATTERYSTATUS_1_17: Final[Layout] = (
    176,
    1,
    {
        "timestamp": (0, "Q", 1),
        "connected": (8, "?", 1),
        "voltage_v": (12, "f", 1),
        "remaining": (28, "f", 1),
    },
)
SENSORGPS_1_17: Final[Layout] = (
    163,
    0,
    {
        "timestamp": (0, "Q", 1),
        "latitude_deg": (24, "d", 1),
        "longitude_deg": (32, "d", 1),
        "altitude_msl_m": (40, "d", 1),
        "fix_type": (64, "B", 1),
        "eph": (68, "f", 1),
        "satellites_used": (136, "B", 1),
    },
)
HOMEPOSITION_1_17: Final[Layout] = (
    60,
    1,
    {
        "timestamp": (0, "Q", 1),
        "lat": (8, "d", 1),
        "lon": (16, "d", 1),
        "alt": (24, "f", 1),
        "valid_alt": (52, "?", 1),
        "valid_hpos": (53, "?", 1),
    },
)

LAYOUTS: Final[dict[str, dict[str, Layout]]] = {
    "1.14": {
        "VehicleStatus": VEHICLESTATUS_1_14,
        "VehicleLandDetected": VEHICLELANDDETECTED_1_14,
        "FailsafeFlags": FAILSAFEFLAGS_1_14,
        "BatteryStatus": BATTERYSTATUS_1_14,
        "SensorGps": SENSORGPS_1_14,
        "HomePosition": HOMEPOSITION_1_14,
        "VehicleCommandAck": VEHICLECOMMANDACK_1_14,
        "VehicleCommand": VEHICLECOMMAND_1_14,
    },
    "1.15": {
        "VehicleStatus": VEHICLESTATUS_1_15,
        "VehicleLandDetected": VEHICLELANDDETECTED_1_14,
        "FailsafeFlags": FAILSAFEFLAGS_1_14,
        "BatteryStatus": BATTERYSTATUS_1_14,
        "SensorGps": SENSORGPS_1_15,
        "HomePosition": HOMEPOSITION_1_15,
        "VehicleCommandAck": VEHICLECOMMANDACK_1_15,
        "VehicleCommand": VEHICLECOMMAND_1_15,
    },
    "1.16": {
        "VehicleStatus": VEHICLESTATUS_1_16,
        "VehicleLandDetected": VEHICLELANDDETECTED_1_14,
        "FailsafeFlags": FAILSAFEFLAGS_1_16,
        "BatteryStatus": BATTERYSTATUS_1_16,
        "SensorGps": SENSORGPS_1_15,
        "HomePosition": HOMEPOSITION_1_15,
        "VehicleCommandAck": VEHICLECOMMANDACK_1_15,
        "VehicleCommand": VEHICLECOMMAND_1_15,
    },
    "1.17": {
        "VehicleStatus": VEHICLESTATUS_1_16,
        "VehicleLandDetected": VEHICLELANDDETECTED_1_14,
        "FailsafeFlags": FAILSAFEFLAGS_1_17,
        "BatteryStatus": BATTERYSTATUS_1_17,
        "SensorGps": SENSORGPS_1_17,
        "HomePosition": HOMEPOSITION_1_17,
        "VehicleCommandAck": VEHICLECOMMANDACK_1_15,
        "VehicleCommand": VEHICLECOMMAND_1_15,
    },
}
