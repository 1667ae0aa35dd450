"""The MAVLink codec and the numbers in swarmd.px4.constants, checked against pymavlink."""

from __future__ import annotations

import math
import subprocess
import sys
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from swarmd.px4.constants import (
    COMP_ID_ONBOARD_COMPUTER,
    MAV_AUTOPILOT_INVALID,
    MAV_AUTOPILOT_PX4,
    MAV_TYPE_ONBOARD_CONTROLLER,
    MODE_FLAG_CUSTOM_MODE_ENABLED,
    MODE_FLAG_SAFETY_ARMED,
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavSeverity,
    MavState,
)
from swarmd.px4.mavlink_codec import MavlinkCodec, Message
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    MODE_TAKEOFF,
    CommandAck,
    ExtendedSysState,
    GlobalPositionInt,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Px4Mode,
    StatusText,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.transport import BadConnectionString, parse_connection


def _pymavlink_enum(prefix: str, name: str) -> int:
    value: int = getattr(mavlink, f"{prefix}{name}")
    return value


@pytest.mark.parametrize(
    ("enum", "prefix"),
    [
        (MavState, "MAV_STATE_"),
        (LandedState, "MAV_LANDED_STATE_"),
        (MavCmd, "MAV_CMD_"),
        (MavSeverity, "MAV_SEVERITY_"),
    ],
)
def test_enums_match_pymavlink(enum: Any, prefix: str) -> None:
    for member in enum:
        assert _pymavlink_enum(prefix, member.name) == member.value, member


def test_result_and_fix_enums_match_pymavlink() -> None:
    for result in MavResult:
        if result >= MavResult.CANCELLED and not hasattr(mavlink, f"MAV_RESULT_{result.name}"):
            continue  # newer than pymavlink 2.4.50's common.xml (reference 1.6)
        assert _pymavlink_enum("MAV_RESULT_", result.name) == result.value
    names = {GpsFixType.FIX_2D: "2D_FIX", GpsFixType.FIX_3D: "3D_FIX"}
    for fix in GpsFixType:
        assert _pymavlink_enum("GPS_FIX_TYPE_", names.get(fix, fix.name)) == fix.value


def test_scalar_constants_match_pymavlink() -> None:
    assert SENSOR_PREARM_CHECK == mavlink.MAV_SYS_STATUS_PREARM_CHECK == 1 << 28
    assert COMP_ID_ONBOARD_COMPUTER == mavlink.MAV_COMP_ID_ONBOARD_COMPUTER == 191
    assert MAV_TYPE_ONBOARD_CONTROLLER == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    assert MAV_AUTOPILOT_PX4 == mavlink.MAV_AUTOPILOT_PX4
    assert MAV_AUTOPILOT_INVALID == mavlink.MAV_AUTOPILOT_INVALID
    assert MODE_FLAG_SAFETY_ARMED == mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert MODE_FLAG_CUSTOM_MODE_ENABLED == mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def test_px4_custom_modes_match_reference_and_mavutil() -> None:
    assert MODE_TAKEOFF.custom_mode == 0x02040000 == 33816576
    assert MODE_LOITER.custom_mode == 0x03040000
    assert Px4Mode.from_custom_mode(0x02040000) == MODE_TAKEOFF
    for mode, name in ((MODE_TAKEOFF, "TAKEOFF"), (MODE_LOITER, "LOITER"), (MODE_LAND, "LAND")):
        assert mavutil.interpret_px4_mode(MODE_FLAG_CUSTOM_MODE_ENABLED, mode.custom_mode) == name
    assert Px4Mode(3).name == "POSCTL"
    assert Px4Mode(42, 7).name == "MODE(42,7)"


def _decode_one(packed: bytes) -> Any:
    frames = MavlinkCodec(9, 191).feed(packed)
    assert len(frames) == 1
    return frames[0]


def test_decodes_fields_by_name_from_pymavlink_built_frames() -> None:
    """Frames built with keyword arguments: a swapped field in our codec cannot hide."""
    tx = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    frame = _decode_one(tx.extended_sys_state_encode(vtol_state=0, landed_state=3).pack(tx))
    assert frame.msg == ExtendedSysState(landed_state=LandedState.TAKEOFF, vtol_state=0)
    assert (frame.src_system, frame.src_component) == (3, 1)
    packed = tx.sys_status_encode(
        onboard_control_sensors_present=1,
        onboard_control_sensors_enabled=2,
        onboard_control_sensors_health=SENSOR_PREARM_CHECK,
        load=0,
        voltage_battery=15800,
        current_battery=-1,
        battery_remaining=77,
        drop_rate_comm=0,
        errors_comm=0,
        errors_count1=0,
        errors_count2=0,
        errors_count3=0,
        errors_count4=0,
    ).pack(tx)
    msg = _decode_one(packed).msg
    assert msg == SysStatus(SENSOR_PREARM_CHECK, 77, 15800, 1, 2)
    assert msg.prearm_ok
    hb = tx.heartbeat_encode(
        type=2, autopilot=12, base_mode=129, custom_mode=0x02040000, system_status=4
    )
    msg = _decode_one(hb.pack(tx)).msg
    assert msg.armed and msg.mode == MODE_TAKEOFF and msg.system_status == MavState.ACTIVE
    gps = tx.gps_raw_int_encode(
        time_usec=0, fix_type=3, lat=1, lon=2, alt=3, eph=90, epv=0, vel=0, cog=0,
        satellites_visible=11,
    )  # fmt: skip
    assert _decode_one(gps.pack(tx)).msg == GpsRawInt(3, 11, 90, 1, 2, 3)
    ack = tx.command_ack_encode(
        command=400, result=1, progress=0, result_param2=0, target_system=9, target_component=191
    )
    assert _decode_one(ack.pack(tx)).msg == CommandAck(400, 1, 0, 9, 191)


def test_prearm_only_counts_in_health() -> None:
    """PX4 >= 1.14 sets PREARM in health only; present/enabled alone means nothing."""
    assert not SysStatus(0, 80, 16000, SENSOR_PREARM_CHECK, SENSOR_PREARM_CHECK).prearm_ok
    assert SysStatus(SENSOR_PREARM_CHECK, 80, 16000, 0, 0).prearm_ok


def test_round_trip_every_message_through_bytes() -> None:
    vehicle = MavlinkCodec(1, 1)
    companion = MavlinkCodec(1, 191)
    messages: list[Message] = [
        Heartbeat(12, 2, 129, MODE_TAKEOFF.custom_mode, 4),
        SysStatus(SENSOR_PREARM_CHECK | 0x2F, 55, 15540, 0x2F, 0x2F),
        ExtendedSysState(LandedState.IN_AIR),
        GpsRawInt(6, 20, 80, 473977420, 85455940, 488000),
        HomePosition(473977420, 85455940, 488000),
        GlobalPositionInt(473977420, 85455940, 498000, 10000, 1234),
        CommandAck(22, 0, 0, 1, 191),
        StatusText(2, "Preflight Fail: Accel 0 uncalibrated"),
    ]
    for msg in messages:
        (frame,) = companion.feed(vehicle.encode(msg))
        assert frame.msg == msg
    cmd = VehicleCommand(22, (math.nan,) * 6 + (498.0,), 2, 1, 1)
    (frame,) = vehicle.feed(companion.encode(cmd))
    got = frame.msg
    assert isinstance(got, VehicleCommand)
    assert got.command == 22 and got.confirmation == 2
    assert all(math.isnan(p) for p in got.params[:6]) and got.params[6] == 498.0
    assert (frame.src_system, frame.src_component) == (1, 191)


def test_frames_are_mavlink2_and_survive_any_split() -> None:
    data = MavlinkCodec(1, 1).encode(Heartbeat(12, 2, 1, 0, 3))
    assert data[0] == 0xFD  # MAVLink 2 magic
    for cut in range(1, len(data)):
        rx = MavlinkCodec(1, 191)
        assert rx.feed(data[:cut]) == []
        assert len(rx.feed(data[cut:])) == 1


def test_corrupt_frame_is_counted_not_raised() -> None:
    good = MavlinkCodec(1, 1).encode(Heartbeat(12, 2, 1, 0, 3))
    bad = bytearray(good)
    bad[-1] ^= 0xFF  # CRC
    rx = MavlinkCodec(1, 191)
    assert rx.feed(bytes(bad)) == []
    assert rx.bad_frames == 1
    assert len(rx.feed(good)) == 1  # and the parser resynchronises


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_garbage_datagram_never_costs_the_next_datagram(junk: bytes) -> None:
    rx = MavlinkCodec(1, 191)
    rx.feed(junk, datagram=True)  # must not raise
    good = MavlinkCodec(1, 1).encode(Heartbeat(12, 2, 1, 0, 3))
    (frame,) = rx.feed(good, datagram=True)
    assert isinstance(frame.msg, Heartbeat)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300))
def test_garbage_on_a_byte_stream_is_survived(junk: bytes) -> None:
    """On a UART the parser resynchronises by itself after at most one maximal frame."""
    rx = MavlinkCodec(1, 191)
    rx.feed(junk)
    good = MavlinkCodec(1, 1).encode(Heartbeat(12, 2, 1, 0, 3))
    got = [f for _ in range(30) for f in rx.feed(good)]  # 30 x 21 bytes > 2 x 280
    assert len(got) >= 15


def test_connection_strings() -> None:
    assert str(parse_connection("udpin:0.0.0.0:14540")) == "udpin:0.0.0.0:14540"
    assert parse_connection("udpout:127.0.0.1:14580").port == 14580
    assert parse_connection("udpin://0.0.0.0:14540").host == "0.0.0.0"  # MAVSDK spelling
    serial = parse_connection("serial:/dev/ttyTHS1:921600")
    assert (serial.kind, serial.device, serial.baud) == ("serial", "/dev/ttyTHS1", 921600)
    for bad, hint in [
        ("tcp:1.2.3.4:5760", "no known scheme"),
        ("udpin:14540", "HOST:PORT"),
        ("serial:/dev/ttyTHS1:123456", "not a termios speed"),
        ("udpout:127.0.0.1:0", "out of range"),
    ]:
        with pytest.raises(BadConnectionString, match=hint) as info:
            parse_connection(bad)
        assert "\n" not in str(info.value) and "fix:" in str(info.value)


def test_pure_modules_import_no_io() -> None:
    """readiness, take-off and the simulator model stay sans-IO (style.md rule 1)."""
    code = (
        "import sys; import swarmd.px4.readiness, swarmd.px4.takeoff, swarmd_lab.px4.sim_model;"
        "print(sorted(m for m in ('asyncio', 'socket', 'selectors', 'pymavlink')"
        " if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "[]"
