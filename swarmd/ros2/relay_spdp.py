"""What the SPDP relay puts in the DATA(p) it synthesizes and how it reads what local nodes
send it (swarmd.ros2.relay's module docstring): Fast DDS's static EDP property list built
from the bundle, and WLP recognised. Pure functions of the bundle and of bytes (sans-IO).
"""

from __future__ import annotations

import re
from typing import Final

from swarmd.bundle.ros2 import GRAPH_TOPIC, Ros2EndpointKind, Ros2Participant
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.message import Data, Heartbeat, decode_message
from swarmd.rtps.types import ENTITYID_P2P_MESSAGE_WRITER, ProtocolVersion

FASTDDS_PROTOCOL_VERSION: Final = ProtocolVersion(2, 3)
ENTITY_KIND_WRITER_NO_KEY: Final = 0x03  # DDSI-RTPS 9.3.1.2
ENTITY_KIND_READER_NO_KEY: Final = 0x04
MAX_ENTITY_KEY: Final = 0xFFFFFF
# Fast DDS's EDPStatic property names (its SPDP lists each alive static endpoint)
STATIC_EDP_PROPERTY: Final = re.compile(r"eProsimaEDPStatic_(Writer|Reader)_ALIVE_ID_(-?\d{1,6})")


def static_edp_entity_id(user_id: int, kind: Ros2EndpointKind) -> str:
    """The property value Fast DDS's EDPStatic gives an endpoint whose profile sets
    ``entityID`` = ``user_id``: the 4 entity id octets in decimal, dot-separated."""
    key = user_id & MAX_ENTITY_KEY
    kind_octet = (
        ENTITY_KIND_WRITER_NO_KEY if kind == Ros2EndpointKind.WRITER else ENTITY_KIND_READER_NO_KEY
    )
    return f"{key >> 16 & 0xFF}.{key >> 8 & 0xFF}.{key & 0xFF}.{kind_octet}"


def is_wlp(datagram: bytes) -> bool:
    try:
        message = decode_message(datagram)
    except DecodeError:
        return False
    return any(
        isinstance(sm, Data | Heartbeat) and sm.writer_id == ENTITYID_P2P_MESSAGE_WRITER
        for sm in message.submessages
    )


def _property_kind(kind: Ros2EndpointKind) -> str:
    return "Writer" if kind == Ros2EndpointKind.WRITER else "Reader"


def static_edp_properties(p: Ros2Participant) -> tuple[tuple[str, str], ...]:
    """The static EDP part of ``p``'s SPDP property list, from the bundle, without its
    ``ros_discovery_info`` writer and reader: rmw's graph topic then matches only between
    the nodes of one drone, so no node sends its graph updates (every entity it creates,
    reliable and transient-local, to every node of the swarm: the busiest second of the
    relay route on the testbed, docs/ros2.md "Graph traffic") over the Wi-Fi. Topics,
    publisher counts and service readiness still come from static EDP; the other drones' node
    names come from swarmd's graph participant (swarmd.ros2.graph)."""
    out: list[tuple[str, str]] = []
    for i, e in enumerate(p.endpoints):
        if e.dds_topic == GRAPH_TOPIC:
            continue
        uid = p.first_user_id + i
        out.append(
            (
                f"eProsimaEDPStatic_{_property_kind(e.kind)}_ALIVE_ID_{uid}",
                static_edp_entity_id(uid, e.kind),
            )
        )
    return tuple(out)
