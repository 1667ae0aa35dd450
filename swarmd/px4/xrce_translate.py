"""PX4 uXRCE-DDS topics -> the backend-neutral observations, and ``VehicleCommand`` -> a sample.

Pure (no I/O). The mapping is docs/px4.md's table: ``vehicle_status`` gives the
``Heartbeat`` (armed = ``arming_state`` 2, mode from ``nav_state``, STANDBY/ACTIVE/CRITICAL
from arming and ``failsafe``, autopilot PX4) and, with ``battery_status``, the ``SysStatus``
(PREARM health bit = ``pre_flight_checks_pass``); ``vehicle_land_detected`` the
``ExtendedSysState`` (never LANDING, which needs ``vehicle_status``'s nav_state);
``vehicle_gps_position`` the ``GpsRawInt``; ``home_position`` (valid only) the
``HomePosition``; ``vehicle_command_ack`` addressed to us the ``CommandAck``.

One vehicle: ``vehicle_status.system_id`` (PX4's ``MAV_SYS_ID``) must be this vehicle's
MAVLink system id. A ``vehicle_status`` of any other vehicle is dropped and counted
(``foreign_samples``), and so is every other topic of the session until a ``vehicle_status``
has said whose it is (the other topics carry no system id of their own).

A new session (``new_session``: the agent's SessionCreated) may be a rebooted PX4, so it
forgets the identity and every vehicle fact the mapping carries (nav_state, landed, PREARM,
battery, failsafe flags, release) and returns a ``StateReset`` for the vehicle state: nothing
of the last life (its landed flag above all, which a PX4 rebooted on the ground would
otherwise keep for up to a second) is said of the new one.

A sample whose layout matches no PX4 release (v1.14..v1.17) is not guessed at: it is
counted, ``problem`` names it, and a ``TopicLayout`` naming it makes readiness false with
reason ``unknown_layout`` until that topic decodes again (another ``TopicLayout``, problem
None).
"""

from __future__ import annotations

import math
from typing import Final

from swarmd.px4.constants import (
    COMP_ID_ONBOARD_COMPUTER,
    MAV_AUTOPILOT_PX4,
    MODE_FLAG_SAFETY_ARMED,
    SENSOR_PREARM_CHECK,
    MavState,
)
from swarmd.px4.messages import (
    ArmingBlockers,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    StateReset,
    SysStatus,
    TopicLayout,
    VehicleCommand,
)
from swarmd.xrce import px4 as topics
from swarmd.xrce.px4_table import Layout

MAV_TYPE_QUADROTOR: Final = 2
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED: Final = 1
ARMING_STATE_ARMED: Final = 2
NAV_AUTO_TAKEOFF: Final = 17
NAV_AUTO_LAND: Final = 18
# vehicle_status.nav_state -> PX4 custom mode (main, sub), as PX4's get_px4_custom_mode()
# (px4_custom_mode.h), for every nav_state of vehicle_status.msg 1.14-1.17
# (/work/shared/peers/xrce/px4_msgs; docs/px4.md, "nav_state"): ORBIT (21) is POSCTL with
# sub-mode ORBIT, not plain POSCTL, which readiness lets arm (``STAYS_ON_GROUND``);
# POSITION_SLOW (6, 1.15+) POSCTL.SLOW; ALTITUDE_CRUISE (8, 1.17) its own main mode;
# TERMINATION (13) its own main mode; EXTERNAL1-8 (23-30, 1.15+) AUTO sub-modes 11-18. The
# free slots (7, 9, 11, 16; 8 before 1.17) and anything later read MODE(0,0): unknown,
# which readiness refuses (``flight_mode``). TERMINATION differs from MAVLink on purpose:
# PX4's HEARTBEAT spells it MANUAL and refuses it by its FLIGHT_TERMINATION status, which
# XRCE has no word for; here it is its own mode, off the list (test_px4_arm_mode, termination)
NAV_TO_MODE: Final = {
    0: (1, 0), 1: (2, 0), 2: (3, 0), 3: (4, 4), 4: (4, 3), 5: (4, 5), 6: (3, 2), 8: (11, 0),
    10: (5, 0), 12: (4, 6), 13: (10, 0), 14: (6, 0), 15: (7, 0), 17: (4, 2), 18: (4, 6),
    19: (4, 8), 20: (4, 9), 21: (3, 1), 22: (4, 10),
    **{23 + i: (4, 11 + i) for i in range(8)},
}  # fmt: skip
# FailsafeFlags.msg, "Per-mode requirements": each mode_req_* is a bitmask over nav_state of
# the modes that need a condition, and the condition's flag says it is missing. PX4 refuses
# to arm in, or to switch to, a mode whose requirement is missing (commander ModeChecks).
MODE_REQUIREMENTS: Final = (
    ("mode_req_angular_velocity", "angular_velocity_invalid"),
    ("mode_req_attitude", "attitude_invalid"),
    ("mode_req_local_alt", "local_altitude_invalid"),
    ("mode_req_local_position", "local_position_invalid"),
    ("mode_req_local_position_relaxed", "local_position_invalid_relaxed"),
    ("mode_req_global_position", "global_position_invalid"),
    ("mode_req_global_position_relaxed", "global_position_invalid_relaxed"),  # 1.17+
    ("mode_req_mission", "auto_mission_missing"),
    ("mode_req_offboard_signal", "offboard_control_signal_lost"),
    ("mode_req_home_position", "home_position_invalid"),
    ("mode_req_manual_control", "manual_control_signal_lost"),
    ("mode_req_wind_and_flight_time_compliance", "wind_limit_exceeded"),
    ("mode_req_wind_and_flight_time_compliance", "flight_time_limit_exceeded"),
)
# flags that stop a take-off in any mode: an ESC that did not arm, a critical failure (attitude
# or altitude limit, external ATS), an unhealthy battery; swarmd's conservative choice for a
# swarm take-off, whatever PX4's own arming checks make of them
ALWAYS_BLOCKING: Final = ("fd_esc_arming_failure", "fd_critical_failure", "battery_unhealthy")
LANDED_ON_GROUND, LANDED_IN_AIR, LANDED_TAKEOFF, LANDED_LANDING = 1, 2, 3, 4


class Px4Translator:
    """Keeps the little state the mapping needs (nav state, battery, release seen)."""

    def __init__(self, sysid: int, compid: int = COMP_ID_ONBOARD_COMPUTER) -> None:
        self.sysid = sysid
        self.compid = compid
        self.releases: set[str] = set(topics.RELEASES)  # narrowed by every sample
        self.problem: str | None = None
        self._unreadable: set[str] = set()  # topics whose last sample had an unknown layout
        self.unknown_layouts = 0
        self.foreign_acks = 0
        # samples dropped because the session's vehicle_status named another system id (or
        # none yet); foreign_system_id: the last such id seen, for the operator
        self.foreign_samples = 0
        self.unidentified_samples = 0
        self.foreign_system_id: int | None = None
        self._identified = False  # the session's last vehicle_status carried our system id
        self.blockers: tuple[str, ...] | None = None  # from failsafe_flags; None: none yet
        self._nav_state: int | None = None
        # vehicle_land_detected's last ``landed``: EXTENDED_SYS_STATE's landed state depends on
        # it and on vehicle_status's nav_state, so either topic changes it (see _landed_state)
        self._landed: bool | None = None
        self._prearm: bool | None = None
        self._battery_pct = -1
        self._voltage_mv = 0xFFFF

    @property
    def px4_version(self) -> str | None:
        """The releases every sample so far fits, e.g. ``1.16`` or ``1.16/1.17``."""
        if self.releases == set(topics.RELEASES):
            return None
        return "/".join(sorted(self.releases)) or "unknown"

    def command_release(self) -> str:
        """The release whose VehicleCommand layout to write (newest still possible)."""
        pool = self.releases or set(topics.RELEASES)
        return max(pool, key=lambda r: tuple(map(int, r.split("."))))

    def new_session(self) -> list[Observation]:
        """The agent's session changed: whose samples they are, and every fact of the vehicle,
        are unknown until the new session's samples say them (module docstring). Returns the
        ``StateReset`` the vehicle state must see before the new session's first sample."""
        self._identified = False
        self._forget_vehicle()
        return [StateReset("new XRCE session")]

    def _forget_vehicle(self) -> None:
        # what __init__ sets for the vehicle (not the counters, nor the unreadable topics:
        # their TopicLayout problem stays until a sample of the topic decodes)
        self.releases = set(topics.RELEASES)  # a reboot may be a new firmware
        self.blockers = None
        self._nav_state = None
        self._landed = None
        self._prearm = None
        self._battery_pct = -1
        self._voltage_mv = 0xFFFF

    def sample(self, topic_name: str, data: bytes) -> list[Observation]:
        if topics.is_command_reply(topic_name):  # the vehicle_command service's reply
            topic_name = topics.dds_topic("vehicle_command_ack", "out")
        name = topics.parse_topic_name(topic_name)
        if name is None or name.topic not in topics.TOPIC_MESSAGES or name.direction != "out":
            return []
        message = topics.TOPIC_MESSAGES[name.topic]
        found = topics.layout_for(message, name.version, len(data))
        if found is None:
            self.unknown_layouts += 1
            label = f"{name.topic}{f'_v{name.version}' if name.version else ''}"
            self.problem = f"unknown PX4 layout: {label} of {len(data)} B (not v1.14..v1.17)"
            self._unreadable.add(name.topic)
            return [TopicLayout(name.topic, self.problem)]
        layout, releases = found
        if not self._is_ours(name.topic, layout, data):
            return []
        cleared: list[Observation] = []
        if name.topic in self._unreadable:
            self._unreadable.discard(name.topic)
            cleared.append(TopicLayout(name.topic, None))
            if not self._unreadable:
                self.problem = None
        return cleared + self._decoded(name.topic, layout, releases, data)

    def _is_ours(self, topic: str, layout: Layout, data: bytes) -> bool:
        """Whether a sample of a known layout is this vehicle's (module docstring)."""
        if topic == "vehicle_status":
            system_id = int(topics.decode_fields(layout, data)["system_id"])
            self._identified = system_id == self.sysid
            if not self._identified:
                self.foreign_samples += 1
                self.foreign_system_id = system_id
            return self._identified
        if not self._identified:
            self.unidentified_samples += 1
            return False
        return True

    def _decoded(
        self, topic: str, layout: Layout, releases: tuple[str, ...], data: bytes
    ) -> list[Observation]:
        narrowed = self.releases & set(releases)
        if narrowed:
            self.releases = narrowed
        f = topics.decode_fields(layout, data)
        match topic:
            case "vehicle_status":
                return self._status(f)
            case "battery_status":
                remaining = float(f["remaining"])
                self._battery_pct = (
                    -1 if math.isnan(remaining) or remaining < 0 else round(remaining * 100)
                )
                volts = float(f["voltage_v"])
                self._voltage_mv = round(volts * 1000) if 0 < volts < 65 else 0xFFFF
                return [] if self._prearm is None else [self._sys_status()]
            case "vehicle_land_detected":
                self._landed = bool(f["landed"])
                landed = self._landed_state(self._landed)
                if landed == LANDED_LANDING:
                    # LANDING is nav_state AUTO.LAND, which only vehicle_status carries; ours
                    # may predate a command (a HOLD that took, its vehicle_status lost), and
                    # this sample's arrival time would make it fresh enough to confirm a LAND
                    # (docs/px4.md, "Fresh state"): the next vehicle_status says it instead
                    return []
                return [ExtendedSysState(landed)]
            case "vehicle_gps_position":
                return [self._gps(f)]
            case "home_position":
                if not (f["valid_alt"] and f["valid_hpos"]):
                    return []
                return [
                    HomePosition(
                        round(float(f["lat"]) * 1e7),
                        round(float(f["lon"]) * 1e7),
                        round(float(f["alt"]) * 1000),
                    )
                ]
            case "vehicle_command_ack":
                return self._ack(f)
            case "failsafe_flags":
                self.blockers = self._blockers(f)
                return [ArmingBlockers(self.blockers)]
        return []

    def command(self, cmd: VehicleCommand, timestamp_us: int) -> bytes:
        return topics.vehicle_command(
            self.command_release(),
            command=cmd.command,
            params=cmd.params,
            target_system=self.sysid,
            target_component=cmd.target_component or 1,
            source_system=self.sysid,
            source_component=self.compid,
            confirmation=cmd.confirmation,
            timestamp_us=timestamp_us,
        )

    # ---- the mapping ---------------------------------------------------------------------

    def _status(self, f: dict[str, float | int | bool]) -> list[Observation]:
        armed = int(f["arming_state"]) == ARMING_STATE_ARMED
        nav = int(f["nav_state"])
        self._nav_state = nav
        main, sub = NAV_TO_MODE.get(nav, (0, 0))
        if f["failsafe"]:
            status = MavState.CRITICAL
        else:
            status = MavState.ACTIVE if armed else MavState.STANDBY
        self._prearm = bool(f["pre_flight_checks_pass"])
        hb = Heartbeat(
            autopilot=MAV_AUTOPILOT_PX4,
            vehicle_type=MAV_TYPE_QUADROTOR,
            base_mode=MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MODE_FLAG_SAFETY_ARMED if armed else 0),
            custom_mode=(main & 0xFF) << 16 | (sub & 0xFF) << 24,
            system_status=status,
            nav_state=nav,
        )
        out: list[Observation] = [hb, self._sys_status()]
        if self._landed is not None:
            # PX4's mavlink EXTENDED_SYS_STATE stream derives the landed state from both
            # topics at each send; deriving it only when vehicle_land_detected arrives kept a
            # stale nav_state (a lift-off seen before AUTO.TAKEOFF read IN_AIR, then TAKEOFF
            # until the next land-detector sample, and IN_AIR again only after that).
            out.append(ExtendedSysState(self._landed_state(self._landed)))
        return out

    def _blockers(self, f: dict[str, float | int | bool]) -> tuple[str, ...]:
        """The set flags that stop arming in the current mode or switching to AUTO.TAKEOFF."""
        modes = {NAV_AUTO_TAKEOFF} | ({self._nav_state} if self._nav_state is not None else set())
        out: list[str] = [flag for flag in ALWAYS_BLOCKING if f.get(flag)]
        for mask, flag in MODE_REQUIREMENTS:
            if f.get(flag) and any(int(f.get(mask, 0)) >> m & 1 for m in modes):
                out.append(flag)
        if self._nav_state is not None and int(f["mode_req_prevent_arming"]) >> self._nav_state & 1:
            out.append(f"mode_req_prevent_arming (nav_state {self._nav_state})")
        return tuple(dict.fromkeys(out))

    def _sys_status(self) -> SysStatus:
        return SysStatus(
            sensors_health=SENSOR_PREARM_CHECK if self._prearm else 0,
            battery_remaining=self._battery_pct,
            voltage_battery_mv=self._voltage_mv,
        )

    def _landed_state(self, landed: bool) -> int:
        if landed:
            return LANDED_ON_GROUND
        if self._nav_state == NAV_AUTO_TAKEOFF:
            return LANDED_TAKEOFF
        if self._nav_state == NAV_AUTO_LAND:
            return LANDED_LANDING
        return LANDED_IN_AIR

    def _gps(self, f: dict[str, float | int | bool]) -> GpsRawInt:
        if "latitude_deg" in f:  # 1.15+: degrees and metres as float64
            lat, lon = round(float(f["latitude_deg"]) * 1e7), round(float(f["longitude_deg"]) * 1e7)
            alt = round(float(f["altitude_msl_m"]) * 1000)
        else:  # 1.14: 1e-7 degrees and millimetres
            lat, lon, alt = int(f["lat"]), int(f["lon"]), int(f["alt"])
        eph = float(f["eph"])
        return GpsRawInt(
            fix_type=int(f["fix_type"]),
            satellites_visible=int(f["satellites_used"]),
            eph_cm=min(round(eph * 100), 0xFFFF) if math.isfinite(eph) and eph >= 0 else 0xFFFF,
            lat_e7=lat,
            lon_e7=lon,
            alt_mm=alt,
        )

    def _ack(self, f: dict[str, float | int | bool]) -> list[Observation]:
        target_system, target_component = int(f["target_system"]), int(f["target_component"])
        if target_system not in (0, self.sysid) or target_component not in (0, self.compid):
            self.foreign_acks += 1  # an answer to a ROS 2 node or the GCS
            return []
        return [
            CommandAck(
                command=int(f["command"]),
                result=int(f["result"]),
                progress=int(f["result_param1"]),
                target_system=target_system,
                target_component=target_component,
            )
        ]
