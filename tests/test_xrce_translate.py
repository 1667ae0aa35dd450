"""PX4 topic samples -> observations, per release; unknown layouts are named, not guessed."""

from __future__ import annotations

import asyncio
import math

import pytest

from swarmd.px4.messages import (
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    SysStatus,
    TopicLayout,
    VehicleCommand,
)
from swarmd.px4.readiness import ReadinessConfig, Reason, VehicleState, readiness
from swarmd.px4.vehicle import VehicleCore
from swarmd.px4.xrce_backend import Mode, XrceBackend
from swarmd.px4.xrce_translate import Px4Translator
from swarmd.xrce import px4 as topics
from swarmd.xrce.events import SampleReceived
from swarmd.xrce.px4_layouts import LAYOUTS

RELEASES = ["1.14", "1.15", "1.16", "1.17"]
SYSID = 3  # the translators' vehicle; PX4 puts its MAV_SYS_ID in vehicle_status.system_id


def _sample(release: str, message: str, **values: float | int | bool) -> tuple[str, bytes]:
    if message == "VehicleStatus":
        values = {"system_id": SYSID, **values}
    layout = LAYOUTS[release][message]
    topic = next(t for t, m in topics.TOPIC_MESSAGES.items() if m == message)
    name = topics.dds_topic(topic, "out", layout[1])
    return name, topics.encode_fields(layout, values)


@pytest.mark.parametrize("release", RELEASES)
def test_every_release_maps_to_observations(release: str) -> None:
    t = Px4Translator(sysid=SYSID)
    obs = t.sample(*_sample(release, "VehicleStatus", arming_state=2, nav_state=17,
                            pre_flight_checks_pass=True))  # fmt: skip
    hb, sys_status = obs
    assert isinstance(hb, Heartbeat) and hb.armed and hb.mode.name == "AUTO.TAKEOFF"
    assert isinstance(sys_status, SysStatus) and sys_status.prearm_ok
    assert release in (t.px4_version or "").split("/")
    (land,) = t.sample(*_sample(release, "VehicleLandDetected", landed=False))
    assert land == ExtendedSysState(3)  # TAKEOFF while nav_state is AUTO_TAKEOFF
    gps_fields: dict[str, float | int | bool] = {"fix_type": 3, "satellites_used": 12, "eph": 0.9}
    if release == "1.14":
        gps_fields.update(lat=473977418, lon=85455938, alt=488000)
    else:
        gps_fields.update(latitude_deg=47.3977418, longitude_deg=8.5455938, altitude_msl_m=488.0)
    (gps,) = t.sample(*_sample(release, "SensorGps", **gps_fields))
    assert gps == GpsRawInt(3, 12, 90, 473977418, 85455938, 488000)
    (home,) = t.sample(*_sample(release, "HomePosition", lat=47.0, lon=8.0, alt=488.5,
                                valid_alt=True, valid_hpos=True))  # fmt: skip
    assert home == HomePosition(470000000, 80000000, 488500)
    assert t.sample(*_sample(release, "HomePosition", valid_alt=False, valid_hpos=True)) == []
    (ack,) = t.sample(*_sample(release, "VehicleCommandAck", command=400, result=0,
                               target_system=3, target_component=191))  # fmt: skip
    assert ack == CommandAck(400, 0, 0, 3, 191)
    # an ack for a ROS 2 node (component 1) is not ours
    assert t.sample(*_sample(release, "VehicleCommandAck", command=400, target_system=3,
                             target_component=1)) == []  # fmt: skip
    assert t.foreign_acks == 1


@pytest.mark.parametrize("release", RELEASES)
def test_vehicle_command_layout_per_release(release: str) -> None:
    t = Px4Translator(sysid=SYSID)
    t.releases = {release}
    raw = t.command(VehicleCommand.make(22, p7=500.0, confirmation=2), timestamp_us=123)
    f = topics.decode_fields(LAYOUTS[release]["VehicleCommand"], raw)
    assert len(raw) == (54 if release == "1.14" else 56)
    assert (f["command"], f["param7"], f["confirmation"], f["from_external"]) == (22, 500, 2, 1)
    assert (f["target_system"], f["target_component"], f["source_component"]) == (3, 1, 191)
    assert math.isnan(float(f["param1"])) and f["timestamp"] == 123


def test_unknown_layout_makes_readiness_false_and_names_it() -> None:
    t = Px4Translator(sysid=SYSID)
    obs = t.sample("rt/fmu/out/vehicle_status_v2", bytes(81))
    problem = "unknown PX4 layout: vehicle_status_v2 of 81 B (not v1.14..v1.17)"
    assert obs == [TopicLayout("vehicle_status", problem)] and str(t.problem) == problem
    state = VehicleState()
    state.observe(obs[0], 0.0)
    verdict = readiness(state, 0.1, ReadinessConfig(require_home=False))
    assert not verdict.ready and verdict.reason is Reason.UNKNOWN_LAYOUT  # not no_heartbeat
    assert verdict.detail == problem
    # a plausible length under the wrong suffix is not guessed either
    assert t.sample("rt/fmu/out/vehicle_status", bytes(80)) == [
        TopicLayout(
            "vehicle_status", "unknown PX4 layout: vehicle_status of 80 B (not v1.14..v1.17)"
        )
    ]
    # a readable sample of that topic lifts it (once), and readiness judges the rest again
    good = _sample("1.16", "VehicleStatus", pre_flight_checks_pass=True)
    cleared, hb, _ = t.sample(*good)
    assert cleared == TopicLayout("vehicle_status", None) and isinstance(hb, Heartbeat)
    assert len(t.sample(*good)) == 2  # once
    assert t.problem is None
    for o in (cleared, hb):
        state.observe(o, 0.2)
    assert readiness(state, 0.3, ReadinessConfig(require_home=False)).reason is not (
        Reason.UNKNOWN_LAYOUT
    )


def test_topic_names() -> None:
    assert topics.parse_topic_name("rt/uav1/fmu/out/vehicle_status_v1") == topics.TopicName(
        "uav1", "out", "vehicle_status", 1
    )
    assert topics.parse_topic_name("rq/fmu/vehicle_commandRequest") is None
    assert topics.topic_names("vehicle_status", "out") == [
        "rt/fmu/out/vehicle_status", "rt/fmu/out/vehicle_status_v1",
    ]  # fmt: skip


@pytest.mark.parametrize("mode", ["xrce-agent", "xrce-client"])
def test_unknown_layout_reaches_readiness_through_either_backend(mode: Mode) -> None:
    """Both XRCE backends hand a sample of an unknown layout to the vehicle core as a named
    ``unknown_layout`` (the session engines are tested apart; this is the backend's seam)."""
    backend = XrceBackend(mode, "udp:127.0.0.1:8888")
    core = VehicleCore(readiness_config=ReadinessConfig(require_home=False))
    loop = asyncio.new_event_loop()
    try:
        backend._loop = loop
        backend._sink = lambda obs, now: core.receive_datagram(obs, None, now)
        topic = topics.dds_topic("vehicle_land_detected", "out")
        backend._event(SampleReceived(("127.0.0.1", 1), topic, "t", bytes(7)))
        verdict = core.readiness(loop.time())
    finally:
        loop.close()
    assert verdict.reason is Reason.UNKNOWN_LAYOUT, verdict
    assert verdict.detail == "unknown PX4 layout: vehicle_land_detected of 7 B (not v1.14..v1.17)"
    assert backend.stats()["layout_problem"] == verdict.detail


@pytest.mark.parametrize("release", RELEASES)
def test_failsafe_flags_that_block_arming_make_readiness_false_and_name_the_flag(
    release: str,
) -> None:
    t = Px4Translator(sysid=SYSID)
    state = VehicleState()
    config = ReadinessConfig(require_home=False)

    def feed(message: str, **values: float | int | bool) -> None:
        for obs in t.sample(*_sample(release, message, **values)):
            state.observe(obs, 0.0)

    # a vehicle ready in every other respect, holding (nav_state 4, AUTO.LOITER)
    feed("VehicleStatus", nav_state=4, pre_flight_checks_pass=True)
    feed("BatteryStatus", remaining=0.9, voltage_v=16.0)
    feed("VehicleLandDetected", landed=True)
    feed("SensorGps", fix_type=3, satellites_used=12, eph=0.9)
    assert readiness(state, 0.0, config).ready
    # PX4's commander masks (bit = nav_state), as px4_like_client fills them
    masks = {"mode_req_global_position": 0x0038003C, "mode_req_home_position": 0x20,
             "mode_req_prevent_arming": 0}  # fmt: skip
    feed("FailsafeFlags", **masks)
    assert readiness(state, 0.0, config).ready  # every flag clear
    # no home: only RTL (bit 5) needs one, so neither arming in Hold nor the take-off stops
    feed("FailsafeFlags", **masks, home_position_invalid=True)
    assert readiness(state, 0.0, config).ready
    # no global position: AUTO.TAKEOFF (bit 17) needs it
    feed("FailsafeFlags", **masks, global_position_invalid=True, home_position_invalid=True)
    verdict = readiness(state, 0.0, config)
    assert verdict.reason is Reason.FAILSAFE_FLAG and "global_position_invalid" in verdict.detail
    assert "home_position_invalid" not in verdict.detail
    # an ESC that failed to arm stops any take-off; arming prevented in the current mode too
    feed("FailsafeFlags", **{**masks, "mode_req_prevent_arming": 1 << 4},
         fd_esc_arming_failure=True)  # fmt: skip
    verdict = readiness(state, 0.0, config)
    assert verdict.reason is Reason.FAILSAFE_FLAG
    assert "fd_esc_arming_failure" in verdict.detail and "mode_req_prevent_arming" in verdict.detail
    feed("FailsafeFlags", **masks)  # cleared again
    assert readiness(state, 0.0, config).ready


def test_landed_state_follows_nav_state_changes_without_a_new_land_detector_sample() -> None:
    """A lift-off reported before AUTO.TAKEOFF, then the climb and the hover: the landed state
    moves with vehicle_status too, as PX4's EXTENDED_SYS_STATE does (never stuck on the
    state of the last vehicle_land_detected)."""
    t = Px4Translator(sysid=SYSID)
    hb, _ = t.sample(*_sample("1.15", "VehicleStatus", arming_state=2, nav_state=4))
    assert isinstance(hb, Heartbeat)  # nothing known of the land detector yet: no landed state
    (ground,) = t.sample(*_sample("1.15", "VehicleLandDetected", landed=True))
    assert ground == ExtendedSysState(1)  # ON_GROUND
    (lift,) = t.sample(*_sample("1.15", "VehicleLandDetected", landed=False))
    assert lift == ExtendedSysState(2)  # IN_AIR: nav_state still AUTO.LOITER
    *_, climbing = t.sample(*_sample("1.15", "VehicleStatus", arming_state=2, nav_state=17))
    assert climbing == ExtendedSysState(3)  # TAKEOFF at once, not at the next land sample
    *_, hover = t.sample(*_sample("1.15", "VehicleStatus", arming_state=2, nav_state=4))
    assert hover == ExtendedSysState(2)  # IN_AIR as soon as the take-off ends
    *_, landing = t.sample(*_sample("1.15", "VehicleStatus", arming_state=2, nav_state=18))
    assert landing == ExtendedSysState(4)  # LANDING
