"""PX4's uXRCE-DDS topics: names, layouts per release (v1.14 to v1.17), samples <-> fields.

Topic names are ``rt/[<ns>/]fmu/{out,in}/<name>[_v<MESSAGE_VERSION>]`` (the suffix from
PX4 1.16, when a message's MESSAGE_VERSION is non-zero); samples are PX4's uORB structs in
little-endian CDR without the encapsulation header (``px4_layouts``). A sample's layout is
chosen by its topic's message, the ``_vN`` suffix and the payload length; when no release
matches, or releases disagree on a field swarmd reads, the layout is unknown and the caller
says so (readiness false with a reason naming it).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass
from typing import Final

from swarmd.xrce.px4_layouts import LAYOUTS
from swarmd.xrce.px4_table import Field, Layout

RELEASES: Final = tuple(LAYOUTS)  # "1.14" .. "1.17"
# uORB topic -> message (the topics swarmd reads and writes)
TOPIC_MESSAGES: Final = {
    "vehicle_status": "VehicleStatus",
    "vehicle_land_detected": "VehicleLandDetected",
    "failsafe_flags": "FailsafeFlags",
    "battery_status": "BatteryStatus",
    "vehicle_gps_position": "SensorGps",
    "home_position": "HomePosition",
    "vehicle_command_ack": "VehicleCommandAck",
    "vehicle_command": "VehicleCommand",
}
OUT_TOPICS: Final = tuple(t for t in TOPIC_MESSAGES if t != "vehicle_command")
_NAME = re.compile(
    r"^rt/(?:(?P<ns>.+)/)?fmu/(?P<dir>out|in)/(?P<topic>[a-z0-9_]+?)(?:_v(?P<v>\d+))?$"
)


_REPLY = re.compile(r"^rr/(?:.+/)?fmu/vehicle_commandReply$")


def is_command_reply(name: str) -> bool:
    """The reply topic of PX4's ``vehicle_command`` service (a VehicleCommandAck)."""
    return _REPLY.match(name) is not None


@dataclass(frozen=True, slots=True)
class TopicName:
    namespace: str | None
    direction: str  # "out" | "in"
    topic: str  # uORB name, e.g. "vehicle_status"
    version: int  # the _vN suffix, 0 without one


def parse_topic_name(name: str) -> TopicName | None:
    m = _NAME.match(name)
    if m is None:
        return None
    return TopicName(m["ns"], m["dir"], m["topic"], int(m["v"] or 0))


def dds_topic(topic: str, direction: str, version: int = 0, namespace: str | None = None) -> str:
    suffix = f"_v{version}" if version else ""
    ns = f"{namespace}/" if namespace else ""
    return f"rt/{ns}fmu/{direction}/{topic}{suffix}"


def dds_type(message: str) -> str:
    return f"px4_msgs::msg::dds_::{message}_"


def topic_names(topic: str, direction: str, namespace: str | None = None) -> list[str]:
    """Every DDS name ``topic`` has in v1.14..v1.17 (e.g. vehicle_status, vehicle_status_v1)."""
    msg = TOPIC_MESSAGES[topic]
    versions = sorted({LAYOUTS[r][msg][1] for r in RELEASES})
    return [dds_topic(topic, direction, v, namespace) for v in versions]


def candidates(message: str, version: int, size: int) -> list[str]:
    """Releases whose ``message`` has this MESSAGE_VERSION suffix and payload size."""
    return [
        r for r in RELEASES if LAYOUTS[r][message][0] == size and LAYOUTS[r][message][1] == version
    ]


def layout_for(message: str, version: int, size: int) -> tuple[Layout, tuple[str, ...]] | None:
    """The layout for a sample, and the releases it fits; None if none fits or they disagree."""
    rels = candidates(message, version, size)
    if not rels:
        return None
    first = LAYOUTS[rels[0]][message]
    for r in rels[1:]:
        if not _same_places(LAYOUTS[r][message][2], first[2]):
            return None  # same size, different field places: cannot tell which
    return first, tuple(rels)


def _same_places(a: dict[str, Field], b: dict[str, Field]) -> bool:
    """Every field at the same place; a renamed field (FailsafeFlags' primary_geofence_breached,
    1.14, is geofence_breached from 1.15) keeps its place and does not make them disagree."""
    if any(a[name] != b[name] for name in a.keys() & b.keys()):
        return False
    return sorted(a.values()) == sorted(b.values())


def decode_fields(layout: Layout, data: bytes) -> dict[str, float | int | bool]:
    """The fields of ``layout`` read from ``data`` (scalars; arrays give their first item)."""
    size, _version, fields = layout
    if len(data) < size:
        raise ValueError(f"sample of {len(data)} bytes, layout needs {size}")
    out: dict[str, float | int | bool] = {}
    for name, (off, code, _count) in fields.items():
        out[name] = struct.unpack_from("<" + code, data, off)[0]
    return out


def encode_fields(layout: Layout, values: dict[str, float | int | bool]) -> bytes:
    """A zeroed sample of ``layout`` with ``values`` written in (unknown names raise)."""
    size, _version, fields = layout
    buf = bytearray(size)
    for name, value in values.items():
        off, code, _count = fields[name]
        struct.pack_into("<" + code, buf, off, value)
    return bytes(buf)


def vehicle_command(
    release: str,
    *,
    command: int,
    params: tuple[float, ...],
    target_system: int,
    target_component: int,
    source_system: int,
    source_component: int,
    confirmation: int,
    timestamp_us: int,
) -> bytes:
    """A ``VehicleCommand`` sample for PX4 ``release`` (``from_external`` set, as PX4 needs)."""
    layout = LAYOUTS[release]["VehicleCommand"]
    values: dict[str, float | int | bool] = {
        "timestamp": timestamp_us,
        "command": command,
        "target_system": target_system,
        "target_component": target_component,
        "source_system": source_system,
        "source_component": source_component,
        "confirmation": confirmation,
        "from_external": True,
    }
    for i, p in enumerate(params[:7], start=1):
        values[f"param{i}"] = float(p) if not math.isnan(p) else math.nan
    return encode_fields(layout, values)
