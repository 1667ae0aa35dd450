"""The PX4 bridge's readiness verdict becomes a valid ``swarmd::Readiness`` wire sample."""

from __future__ import annotations

from dataclasses import replace

from swarmd.dataplane.convert import readiness_sample
from swarmd.dataplane.types import Readiness, decode_sample, encode_sample
from swarmd.px4.readiness import Readiness as Verdict
from swarmd.px4.readiness import ReadinessConfig, Reason, VehicleState, readiness


def test_a_vehicle_never_heard_converts_to_unknowns() -> None:
    verdict = readiness(VehicleState(), 0.0, ReadinessConfig())
    sample = readiness_sample("m01", 7, verdict, link_q=0.4567)
    assert sample == Readiness("m01", 7, False, "no_heartbeat", False, 0, 0, 255, -1, 457)
    assert decode_sample(encode_sample(sample), Readiness) == sample


def test_a_ready_vehicle_converts_field_by_field() -> None:
    verdict = Verdict(
        ready=True,
        reason=None,
        detail="ready for take-off",
        heartbeat_age_s=0.1,
        armed=False,
        mode="POSCTL",
        system_status="STANDBY",
        prearm=True,
        landed_state="ON_GROUND",
        gps_fix=3,
        satellites=14,
        home=True,
        battery_pct=87,
        px4_says=None,
    )
    sample = readiness_sample("m02", 20, verdict, link_q=1.2)
    assert sample == Readiness("m02", 20, True, "", False, 1, 3, 14, 87, 1000)
    failing = readiness_sample("m02", 21, replace(verdict, reason=Reason.BATTERY_LOW), 0.5)
    assert failing.reason == "battery_low"
    encode_sample(failing)
