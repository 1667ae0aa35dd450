"""From the PX4 bridge's readiness verdict to the ``swarmd::Readiness`` wire sample.

Structural (a ``Protocol``), so the data plane does not import the PX4 bridge: anything with
these read-only attributes converts, ``swarmd.px4.readiness.Readiness`` included.
"""

from __future__ import annotations

from typing import Final, Protocol

from swarmd.dataplane.types import MAX_LINK_Q_PERMILLE, MAX_REASON_CHARS, Readiness

# MAV_LANDED_STATE by name, as the bridge reports it (common.xml)
LANDED_STATES: Final = {"UNDEFINED": 0, "ON_GROUND": 1, "IN_AIR": 2, "TAKEOFF": 3, "LANDING": 4}
SATELLITES_UNKNOWN: Final = 255  # GPS_RAW_INT.satellites_visible "unknown"
BATTERY_UNKNOWN: Final = -1  # SYS_STATUS.battery_remaining "unknown"


class ReadinessVerdict(Protocol):
    @property
    def ready(self) -> bool: ...
    @property
    def reason(self) -> object: ...  # a reason code (StrEnum) or None when ready
    @property
    def armed(self) -> bool | None: ...
    @property
    def landed_state(self) -> str | None: ...
    @property
    def gps_fix(self) -> int | None: ...
    @property
    def satellites(self) -> int | None: ...
    @property
    def battery_pct(self) -> int | None: ...


def readiness_sample(
    node: str, seq: int, verdict: ReadinessVerdict, link_q: float, stamp_ms: int = 0
) -> Readiness:
    """The wire sample for ``verdict``; unknowns become the MAVLink "unknown" values and
    ``link_q`` (Q in [0, 1], paper eq. 2) becomes thousandths. ``stamp_ms``: this node's
    clock (``validity.stamp_ms(now)``), echoed back in commands to date them."""
    reason = "" if verdict.reason is None else str(verdict.reason)
    battery = verdict.battery_pct
    return Readiness(
        node=node,
        seq=seq,
        ready=bool(verdict.ready),
        reason=reason.encode("utf-8")[:MAX_REASON_CHARS].decode("utf-8", "ignore"),
        armed=bool(verdict.armed),
        landed_state=LANDED_STATES.get(verdict.landed_state or "", 0),
        gps_fix=min(max(verdict.gps_fix or 0, 0), 255),
        satellites=SATELLITES_UNKNOWN
        if verdict.satellites is None
        else min(max(verdict.satellites, 0), 254),
        battery_pct=BATTERY_UNKNOWN if battery is None else min(max(battery, 0), 100),
        link_q_permille=round(min(max(link_q, 0.0), 1.0) * MAX_LINK_Q_PERMILLE),
        stamp_ms=stamp_ms,
    )
