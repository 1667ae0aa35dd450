"""MAVLink 2 bytes <-> ``swarmd.px4.messages``, through pymavlink's generated codec only.

pymavlink's ``dialects.v20.common.MAVLink(file=None)`` is a pure codec: ``parse_buffer``
turns bytes into message objects, ``<msg>_encode(...).pack(mav)`` turns fields into a
MAVLink 2 frame (0xFD). We never use ``mavutil``: its connections poll and block (reference
section 1.7). ``common`` holds every message the PX4 readiness predicate needs.

Network input never raises out of ``feed``: corrupt frames are counted in ``bad_frames``
(``robust_parsing`` turns them into ``MAVLink_bad_data``), unmodelled messages in
``ignored``, and an unexpected parser exception resets the parser and is counted too.

With a signing key (``swarmd.px4.signing``) every frame we encode is signed (pymavlink's
``sign_packet``) and every frame we decode must carry a good signature from a fresh stream:
the rest are dropped before decoding and counted per verdict in ``signing_counts``.
``accept_unsigned`` names message ids let through unsigned anyway (the simulator copies
PX4's allowlist); swarmd lets nothing through unsigned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from swarmd.px4.messages import (
    BootClock,
    CommandAck,
    ExtendedSysState,
    GlobalPositionInt,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    StatusText,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.signing import KEY_BYTES, Verdict, Verifier


@dataclass(frozen=True, slots=True)
class SetupSigning:
    """SETUP_SIGNING (256): a signing key for the target (MAVLink-only, never observed by
    readiness; ``swarmctl px4 setup-signing`` sends it, the simulator obeys it as PX4 does)."""

    target_system: int
    target_component: int
    secret_key: bytes
    initial_timestamp: int


Message = Observation | VehicleCommand | SetupSigning | BootClock

# Messages PX4 streams with its boot clock ``time_boot_ms`` ("Timestamp (time since system
# boot)", MAVLink common.xml) and nothing readiness reads: decoded for that field alone
# (``BootClock``), so ``boot_watch`` can tell a rebooted PX4 (docs/px4.md, "Fresh state").
# PX4's ONBOARD mode streams ATTITUDE 100 Hz, ATTITUDE_QUATERNION 50 Hz, LOCAL_POSITION_NED
# 30 Hz and SYSTEM_TIME 1 Hz (mavlink_main.cpp); GLOBAL_POSITION_INT (50 Hz) carries it too.
BOOT_CLOCK_MESSAGES = frozenset(
    {"SYSTEM_TIME", "ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED"}
)

_UINT16_MAX = 0xFFFF


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded message and who sent it (MAVLink header)."""

    msg: Message
    src_system: int
    src_component: int
    signed: bool = False  # True: its signature checked against our key (signing on)

    @property
    def boot_clock(self) -> tuple[str, int] | None:
        """(message name, ``time_boot_ms``) when the message carries PX4's boot clock."""
        match self.msg:
            case BootClock():
                return self.msg.message, self.msg.time_boot_ms
            case GlobalPositionInt():
                return "GLOBAL_POSITION_INT", self.msg.time_boot_ms
        return None


class MavlinkCodec:
    """Stateful (sequence numbers, partial frames) MAVLink 2 encoder/decoder for one link."""

    def __init__(
        self,
        src_system: int,
        src_component: int,
        *,
        signing_key: bytes | None = None,
        link_id: int = 0,
        accept_unsigned: frozenset[int] = frozenset(),
    ) -> None:
        self._tx: Any = mavlink.MAVLink(None, srcSystem=src_system, srcComponent=src_component)
        self._rx: Any = self._new_parser()
        self.bad_frames = 0
        self.ignored = 0
        self.decoded = 0
        self.verifier: Verifier | None = None
        self._accept_unsigned = accept_unsigned
        self._tx.signing.link_id = link_id
        self.set_signing_key(signing_key)

    def set_signing_key(self, key: bytes | None) -> None:
        """Signing on with ``key`` (a fresh verifier: streams start over), or off (None)."""
        if key is None:
            self.verifier = None
            self._tx.signing.secret_key = None
            self._tx.signing.sign_outgoing = False
            return
        if len(key) != KEY_BYTES:
            raise ValueError("a MAVLink signing key is 32 bytes")
        self.verifier = Verifier(key)
        self._tx.signing.secret_key = key
        self._tx.signing.sign_outgoing = True

    @property
    def signing(self) -> bool:
        return self.verifier is not None

    def advance_clock(self, timestamp: int) -> None:
        """Raise the signing clock to ``timestamp`` (10 µs since 2015, ``signing.py``).

        Outgoing timestamps then stay at or after the wall clock, as the spec asks, even
        though pymavlink adds only one tick per frame sent.
        """
        if self.verifier is not None:
            self.verifier.advance(timestamp)
            self._tx.signing.timestamp = max(self._tx.signing.timestamp, timestamp)

    @property
    def signing_counts(self) -> dict[str, int] | None:
        return None if self.verifier is None else dict(self.verifier.counts)

    @staticmethod
    def _new_parser() -> Any:
        rx = mavlink.MAVLink(None)
        rx.robust_parsing = True  # bad CRC / garbage -> MAVLink_bad_data, not an exception
        return rx

    # ---- decode -------------------------------------------------------------------------

    def feed(self, data: bytes, *, datagram: bool = False) -> list[Frame]:
        """All complete frames in ``data`` (plus bytes kept from earlier calls).

        ``datagram=True`` (UDP): a datagram holds whole frames, so bytes left over from the
        previous one are junk and are dropped first. Without that, one stray 0xFD makes the
        parser wait for a 255-byte "frame" and swallow the next dozen real ones.
        """
        if datagram and len(self._rx.buf) > self._rx.buf_index:
            self.bad_frames += 1
            self._rx = self._new_parser()
        try:
            raw = self._rx.parse_buffer(data) or []
        except Exception:  # a pymavlink corner we did not foresee: drop, count, resync
            self.bad_frames += 1
            self._rx = self._new_parser()
            return []
        frames: list[Frame] = []
        for m in raw:
            if m.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            signed = False
            if self.verifier is not None:
                verdict = self.verifier.check(
                    bytes(m.get_msgbuf()), m.get_srcSystem(), m.get_srcComponent()
                )
                signed = verdict is Verdict.OK
                if not signed and m.get_msgId() not in self._accept_unsigned:
                    continue  # counted by the verifier; never decoded
            try:
                msg = decode_message(m)
            except (AttributeError, TypeError, ValueError):
                self.bad_frames += 1
                continue
            if msg is None:
                self.ignored += 1
                continue
            self.decoded += 1
            frames.append(Frame(msg, m.get_srcSystem(), m.get_srcComponent(), signed))
        return frames

    # ---- encode -------------------------------------------------------------------------

    def encode(self, msg: Message) -> bytes:
        """One MAVLink 2 frame for ``msg`` from this codec's (system, component)."""
        packed: bytes = _encoder(self._tx, msg).pack(self._tx)
        return packed


def decode_message(m: Any) -> Message | None:
    """A pymavlink message object -> our dataclass, or None for messages we do not model."""
    if m.get_type() in BOOT_CLOCK_MESSAGES:
        return BootClock(m.get_type(), int(m.time_boot_ms))
    match m.get_type():
        case "HEARTBEAT":
            return Heartbeat(
                autopilot=m.autopilot,
                vehicle_type=m.type,
                base_mode=m.base_mode,
                custom_mode=m.custom_mode,
                system_status=m.system_status,
            )
        case "SYS_STATUS":
            return SysStatus(
                sensors_health=m.onboard_control_sensors_health,
                battery_remaining=m.battery_remaining,
                voltage_battery_mv=m.voltage_battery,
                sensors_present=m.onboard_control_sensors_present,
                sensors_enabled=m.onboard_control_sensors_enabled,
            )
        case "EXTENDED_SYS_STATE":
            return ExtendedSysState(landed_state=m.landed_state, vtol_state=m.vtol_state)
        case "GPS_RAW_INT":
            return GpsRawInt(
                fix_type=m.fix_type,
                satellites_visible=m.satellites_visible,
                eph_cm=m.eph,
                lat_e7=m.lat,
                lon_e7=m.lon,
                alt_mm=m.alt,
            )
        case "HOME_POSITION":
            return HomePosition(
                latitude_e7=m.latitude, longitude_e7=m.longitude, altitude_mm=m.altitude
            )
        case "GLOBAL_POSITION_INT":
            return GlobalPositionInt(
                lat_e7=m.lat,
                lon_e7=m.lon,
                alt_mm=m.alt,
                relative_alt_mm=m.relative_alt,
                time_boot_ms=m.time_boot_ms,
            )
        case "COMMAND_ACK":
            return CommandAck(
                command=m.command,
                result=m.result,
                progress=m.progress,
                target_system=m.target_system,
                target_component=m.target_component,
            )
        case "STATUSTEXT":
            text = m.text
            if isinstance(text, bytes | bytearray):
                text = bytes(text).split(b"\0", 1)[0].decode("utf-8", "replace")
            return StatusText(severity=m.severity, text=str(text))
        case "SETUP_SIGNING":
            return SetupSigning(
                target_system=m.target_system,
                target_component=m.target_component,
                secret_key=bytes(m.secret_key),
                initial_timestamp=m.initial_timestamp,
            )
        case "COMMAND_LONG":
            p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
            return VehicleCommand(
                command=m.command,
                params=tuple(float(x) for x in p),  # type: ignore[arg-type]
                confirmation=m.confirmation,
                target_system=m.target_system,
                target_component=m.target_component,
            )
    return None


def _encoder(tx: Any, msg: Message) -> Any:
    match msg:
        case Heartbeat():
            return tx.heartbeat_encode(
                msg.vehicle_type, msg.autopilot, msg.base_mode, msg.custom_mode, msg.system_status
            )
        case SysStatus():
            return tx.sys_status_encode(
                msg.sensors_present,
                msg.sensors_enabled,
                msg.sensors_health,
                0,  # load
                msg.voltage_battery_mv,
                -1,  # current_battery: not measured
                msg.battery_remaining,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        case ExtendedSysState():
            return tx.extended_sys_state_encode(msg.vtol_state, msg.landed_state)
        case GpsRawInt():
            return tx.gps_raw_int_encode(
                0,  # time_usec
                msg.fix_type,
                msg.lat_e7,
                msg.lon_e7,
                msg.alt_mm,
                msg.eph_cm,
                _UINT16_MAX,  # epv unknown
                _UINT16_MAX,  # vel unknown
                _UINT16_MAX,  # cog unknown
                msg.satellites_visible,
            )
        case HomePosition():
            return tx.home_position_encode(
                msg.latitude_e7,
                msg.longitude_e7,
                msg.altitude_mm,
                0.0,
                0.0,
                0.0,
                [1.0, 0.0, 0.0, 0.0],
                math.nan,
                math.nan,
                math.nan,
            )
        case GlobalPositionInt():
            return tx.global_position_int_encode(
                msg.time_boot_ms, msg.lat_e7, msg.lon_e7, msg.alt_mm, msg.relative_alt_mm, 0, 0, 0,
                _UINT16_MAX,
            )  # fmt: skip
        case CommandAck():
            return tx.command_ack_encode(
                msg.command, msg.result, msg.progress, 0, msg.target_system, msg.target_component
            )
        case StatusText():
            return tx.statustext_encode(msg.severity, msg.text.encode("utf-8")[:50])
        case SetupSigning():
            return tx.setup_signing_encode(
                msg.target_system, msg.target_component, list(msg.secret_key), msg.initial_timestamp
            )
        case BootClock():
            return _boot_clock_encoder(tx, msg)
        case VehicleCommand():
            return tx.command_long_encode(
                msg.target_system, msg.target_component, msg.command, msg.confirmation, *msg.params
            )
    raise TypeError(f"cannot encode {type(msg).__name__}")


def _boot_clock_encoder(tx: Any, msg: BootClock) -> Any:
    # the simulator and the tests send these; every field but the boot clock is zero
    t = msg.time_boot_ms
    match msg.message:
        case "SYSTEM_TIME":
            return tx.system_time_encode(0, t)
        case "ATTITUDE":
            return tx.attitude_encode(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        case "ATTITUDE_QUATERNION":
            return tx.attitude_quaternion_encode(t, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        case "LOCAL_POSITION_NED":
            return tx.local_position_ned_encode(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    raise TypeError(f"cannot encode {msg.message}")
