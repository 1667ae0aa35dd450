"""PX4 uORB message layouts for uXRCE-DDS, per release (generated: do not edit).

Made by scripts/gen_px4_layouts.py from px4_msgs at v1.14.0, v1.15.4, v1.16.0, v1.17.0
(PX4's msg/ definitions, BSD-3-Clause). Per release and message: the CDR payload size,
MESSAGE_VERSION, and (offset, struct code, count) of the fields swarmd uses.

One table per message, a column per release (``px4_table``): its (size,
MESSAGE_VERSION), then a row per field with its struct code and offset (None: not in
that release). Reading along a row shows how a field moved between releases;
``LAYOUTS`` is the same data by release.
"""

from typing import Final

from swarmd.xrce.px4_table import Layout, per_release

RELEASES: Final = ("1.14", "1.15", "1.16", "1.17")

# fmt: off
_MESSAGES: Final[dict[str, dict[str, Layout]]] = {
    "VehicleStatus": per_release(
        RELEASES,
        ((71, 0), (82, 0), (80, 1), (80, 1)),  # (size, MESSAGE_VERSION) per release
        (
            # field                     code  1.14  1.15  1.16  1.17
            ("timestamp",               "Q",    0,    0,    0,    0),
            ("arming_state",            "B",   24,   24,   24,   24),
            ("nav_state",               "B",   41,   41,   41,   41),
            ("vehicle_type",            "B",   45,   55,   55,   55),
            ("failsafe",                "?",   46,   56,   56,   56),
            ("system_id",               "B",   56,   67,   67,   67),
            ("component_id",            "B",   57,   68,   68,   68),
            ("pre_flight_checks_pass",  "?",   70,   81,   79,   79),
        ),
    ),
    "VehicleLandDetected": per_release(
        RELEASES,
        ((20, 0), (20, 0), (20, 0), (20, 0)),  # (size, MESSAGE_VERSION) per release
        (
            # field             code  1.14  1.15  1.16  1.17
            ("timestamp",       "Q",    0,    0,    0,    0),
            ("ground_contact",  "?",    9,    9,    9,    9),
            ("maybe_landed",    "?",   10,   10,   10,   10),
            ("landed",          "?",   11,   11,   11,   11),
        ),
    ),
    "FailsafeFlags": per_release(
        RELEASES,
        ((85, 0), (85, 0), (86, 0), (91, 0)),  # (size, MESSAGE_VERSION) per release
        (
            # field                                       code  1.14  1.15  1.16  1.17
            ("timestamp",                                 "Q",    0,    0,    0,    0),
            ("mode_req_angular_velocity",                 "I",    8,    8,    8,    8),
            ("mode_req_attitude",                         "I",   12,   12,   12,   12),
            ("mode_req_local_alt",                        "I",   16,   16,   16,   16),
            ("mode_req_local_position",                   "I",   20,   20,   20,   20),
            ("mode_req_local_position_relaxed",           "I",   24,   24,   24,   24),
            ("mode_req_global_position",                  "I",   28,   28,   28,   28),
            ("mode_req_global_position_relaxed",          "I", None, None, None,   32),
            ("mode_req_mission",                          "I",   32,   32,   32,   36),
            ("mode_req_offboard_signal",                  "I",   36,   36,   36,   40),
            ("mode_req_home_position",                    "I",   40,   40,   40,   44),
            ("mode_req_wind_and_flight_time_compliance",  "I",   44,   44,   44,   48),
            ("mode_req_prevent_arming",                   "I",   48,   48,   48,   52),
            ("mode_req_manual_control",                   "I",   52,   52,   52,   56),
            ("mode_req_other",                            "I",   56,   56,   56,   60),
            ("angular_velocity_invalid",                  "?",   60,   60,   60,   64),
            ("attitude_invalid",                          "?",   61,   61,   61,   65),
            ("local_altitude_invalid",                    "?",   62,   62,   62,   66),
            ("local_position_invalid",                    "?",   63,   63,   63,   67),
            ("local_position_invalid_relaxed",            "?",   64,   64,   64,   68),
            ("local_velocity_invalid",                    "?",   65,   65,   65,   69),
            ("global_position_invalid",                   "?",   66,   66,   66,   70),
            ("global_position_invalid_relaxed",           "?", None, None, None,   71),
            ("auto_mission_missing",                      "?",   67,   67,   67,   72),
            ("offboard_control_signal_lost",              "?",   68,   68,   68,   73),
            ("home_position_invalid",                     "?",   69,   69,   69,   74),
            ("manual_control_signal_lost",                "?",   70,   70,   70,   75),
            ("gcs_connection_lost",                       "?",   71,   71,   71,   76),
            ("battery_warning",                           "B",   72,   72,   72,   77),
            ("battery_low_remaining_time",                "?",   73,   73,   73,   78),
            ("battery_unhealthy",                         "?",   74,   74,   74,   79),
            ("primary_geofence_breached",                 "?",   75, None, None, None),
            ("geofence_breached",                         "?", None,   75,   75,   80),
            ("mission_failure",                           "?",   76,   76,   76,   81),
            ("vtol_fixed_wing_system_failure",            "?",   77,   77,   77,   82),
            ("wind_limit_exceeded",                       "?",   78,   78,   78,   83),
            ("flight_time_limit_exceeded",                "?",   79,   79,   79,   84),
            ("local_position_accuracy_low",               "?",   80,   80,   80, None),
            ("position_accuracy_low",                     "?", None, None, None,   85),
            ("navigator_failure",                         "?", None, None,   81,   86),
            ("fd_critical_failure",                       "?",   81,   81,   82,   87),
            ("fd_esc_arming_failure",                     "?",   82,   82,   83,   88),
            ("fd_imbalanced_prop",                        "?",   83,   83,   84,   89),
            ("fd_motor_failure",                          "?",   84,   84,   85,   90),
        ),
    ),
    "BatteryStatus": per_release(
        RELEASES,
        ((176, 0), (176, 0), (180, 0), (176, 1)),  # (size, MESSAGE_VERSION) per release
        (
            # field        code  1.14  1.15  1.16  1.17
            ("timestamp",  "Q",    0,    0,    0,    0),
            ("connected",  "?",    8,    8,    8,    8),
            ("voltage_v",  "f",   12,   12,   12,   12),
            ("remaining",  "f",   36,   36,   28,   28),
        ),
    ),
    "SensorGps": per_release(
        RELEASES,
        ((141, 0), (159, 0), (159, 0), (163, 0)),  # (size, MESSAGE_VERSION) per release
        (
            # field              code  1.14  1.15  1.16  1.17
            ("timestamp",        "Q",    0,    0,    0,    0),
            ("lat",              "i",   20, None, None, None),
            ("lon",              "i",   24, None, None, None),
            ("alt",              "i",   28, None, None, None),
            ("latitude_deg",     "d", None,   24,   24,   24),
            ("longitude_deg",    "d", None,   32,   32,   32),
            ("altitude_msl_m",   "d", None,   40,   40,   40),
            ("fix_type",         "B",   44,   64,   64,   64),
            ("eph",              "f",   48,   68,   68,   68),
            ("satellites_used",  "B",  120,  136,  136,  136),
        ),
    ),
    "HomePosition": per_release(
        RELEASES,
        ((48, 0), (52, 0), (52, 0), (60, 1)),  # (size, MESSAGE_VERSION) per release
        (
            # field         code  1.14  1.15  1.16  1.17
            ("timestamp",   "Q",    0,    0,    0,    0),
            ("lat",         "d",    8,    8,    8,    8),
            ("lon",         "d",   16,   16,   16,   16),
            ("alt",         "f",   24,   24,   24,   24),
            ("valid_alt",   "?",   44,   44,   44,   52),
            ("valid_hpos",  "?",   45,   45,   45,   53),
        ),
    ),
    "VehicleCommandAck": per_release(
        RELEASES,
        ((23, 0), (25, 0), (25, 0), (25, 0)),  # (size, MESSAGE_VERSION) per release
        (
            # field               code  1.14  1.15  1.16  1.17
            ("timestamp",         "Q",    0,    0,    0,    0),
            ("command",           "I",    8,    8,    8,    8),
            ("result",            "B",   12,   12,   12,   12),
            ("result_param1",     "B",   13,   13,   13,   13),
            ("result_param2",     "i",   16,   16,   16,   16),
            ("target_system",     "B",   20,   20,   20,   20),
            ("target_component",  "B",   21, None, None, None),
            ("target_component",  "H", None,   22,   22,   22),
            ("from_external",     "?",   22,   24,   24,   24),
        ),
    ),
    "VehicleCommand": per_release(
        RELEASES,
        ((54, 0), (56, 0), (56, 0), (56, 0)),  # (size, MESSAGE_VERSION) per release
        (
            # field               code  1.14  1.15  1.16  1.17
            ("timestamp",         "Q",    0,    0,    0,    0),
            ("param1",            "f",    8,    8,    8,    8),
            ("param2",            "f",   12,   12,   12,   12),
            ("param3",            "f",   16,   16,   16,   16),
            ("param4",            "f",   20,   20,   20,   20),
            ("param5",            "d",   24,   24,   24,   24),
            ("param6",            "d",   32,   32,   32,   32),
            ("param7",            "f",   40,   40,   40,   40),
            ("command",           "I",   44,   44,   44,   44),
            ("target_system",     "B",   48,   48,   48,   48),
            ("target_component",  "B",   49,   49,   49,   49),
            ("source_system",     "B",   50,   50,   50,   50),
            ("source_component",  "B",   51, None, None, None),
            ("source_component",  "H", None,   52,   52,   52),
            ("confirmation",      "B",   52,   54,   54,   54),
            ("from_external",     "?",   53,   55,   55,   55),
        ),
    ),
}
# fmt: on

LAYOUTS: Final[dict[str, dict[str, Layout]]] = {
    release: {message: layouts[release] for message, layouts in _MESSAGES.items()}
    for release in RELEASES
}
