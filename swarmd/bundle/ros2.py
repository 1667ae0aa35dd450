"""The swarm's ROS 2 graph as the bundle carries it (issue 19), and the identities it derives.

The mission's optional ``ros2:`` section declares the operator's own ROS 2 graph: topics
(ROS name, ROS type, QoS), services, and nodes (which drones run them, what each publishes,
subscribes, serves and calls). Each (drone, node) pair is one ROS 2 process, hence one DDS
participant (rmw_fastrtps creates one participant per rclpy context). Like swarmd's own
participants, its identity is derived, never drawn, so every drone and every generated Fast DDS
profile agree on it without a message on the air:

- GUID prefix = eProsima vendor id ``01.0f`` (these are stock Fast DDS participants) + the
  drone index (u16: the bytes Fast DDS calls "host id") + the node index (u16) +
  SHA-256(``"<swarm>/<domain>/ros2"``)[:6], so prefixes differ across drones, nodes and
  swarms. Fast DDS takes two participants whose first 8 octets are equal for one process
  and hands their data over in memory (its intra-process delivery), which two node
  processes on one drone cannot do: the node index in octets 4-5 keeps each node's
  "process" its own (docs/ros2.md, "Several nodes on one drone").
- Participant id = highest swarmd participant index + 1 + node index; ports are the standard
  RTPS mapping for it in the ROS 2 domain (RTPS 9.6.1.1). The ROS 2 participants can so share
  swarmd's domain without taking a port swarmd's own participant uses on any drone.
- Static EDP ``userDefinedID`` (Fast DDS's only key for static endpoint matching, unique in
  the whole static file): numbered from 1 over drones by index, nodes in mission order and
  each participant's endpoints in ``endpoints()`` order.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final

from swarmd.bundle.model import Bundle, Durability, Qos, Reliability
from swarmd.rtps.ports import max_participant_index, metatraffic_unicast_port, user_unicast_port

VENDOR_EPROSIMA: Final = b"\x01\x0f"
ROS2_TAG_BYTES: Final = 6
# Fast DDS keeps userDefinedID in an int16; 0 and negative ids mean "none" (never matched)
MAX_USER_ID: Final = 32767
MAX_ROS2_DRONE_INDEX: Final = 0xFFFF  # two prefix bytes
MAX_ROS2_NODE_INDEX: Final = 0xFFFF  # two prefix bytes
# DDS endpoints of one node (its topics, twice its services, ROS 2's own). What swarmd
# sends about a node must fit one UDP datagram (no DATA_FRAG here): the SPDP DATA(p) its
# relay announces for the node carries a static EDP property per endpoint, 60 octets
# each: 60,076 octets for 1,000 endpoints at user ids above 31,000, under Fast DDS's
# 65,500-octet message limit with room for what the node's own DATA(p) adds; its graph
# sample is 16,016 (tests/test_ros2_profile.py, review 18b; docs/ros2.md "Graph
# preloading").
MAX_NODE_ENDPOINTS: Final = 1000


class Ros2EndpointKind(StrEnum):
    WRITER = "writer"
    READER = "reader"


@dataclass(frozen=True, slots=True)
class Ros2Topic:
    name: str  # absolute ROS name, e.g. /chatter
    type_name: str  # ROS type, e.g. std_msgs/msg/String
    qos: Qos


@dataclass(frozen=True, slots=True)
class Ros2Service:
    name: str  # absolute ROS name, e.g. /trigger
    type_name: str  # e.g. std_srvs/srv/Trigger


@dataclass(frozen=True, slots=True)
class Ros2Node:
    name: str  # the ROS node name
    index: int  # position in the mission's ros2.nodes: keys prefix and ports
    drones: tuple[str, ...]  # swarm participant names, by index
    publishes: tuple[str, ...]
    subscribes: tuple[str, ...]
    serves: tuple[str, ...]
    calls: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Ros2Graph:
    domain_id: int  # ROS_DOMAIN_ID of the operator's nodes
    topics: tuple[Ros2Topic, ...]
    services: tuple[Ros2Service, ...]
    nodes: tuple[Ros2Node, ...]

    def topic(self, name: str) -> Ros2Topic:
        return next(t for t in self.topics if t.name == name)

    def service(self, name: str) -> Ros2Service:
        return next(s for s in self.services if s.name == name)


@dataclass(frozen=True, slots=True)
class Ros2Endpoint:
    """One DDS endpoint a ROS 2 node creates, as static EDP must know it."""

    profile_name: str  # what rmw_fastrtps looks the XML profile up by
    dds_topic: str  # the DDS topic name on the wire (rt/..., rq/..., rr/...)
    dds_type: str  # the DDS type name rmw registers
    kind: Ros2EndpointKind
    reliability: Reliability
    durability: Durability


@dataclass(frozen=True, slots=True)
class Ros2Participant:
    drone: str
    drone_index: int
    node: Ros2Node
    guid_prefix: bytes
    participant_id: int
    metatraffic_port: int
    user_port: int
    endpoints: tuple[Ros2Endpoint, ...]
    first_user_id: int  # endpoints[i] has userDefinedID first_user_id + i


def ros2_guid_prefix(swarm: str, domain_id: int, drone_index: int, node_index: int) -> bytes:
    """``01.0f | drone index u16 | node index u16 | SHA-256("<swarm>/<domain>/ros2")[:6]``.

    Octets 0-7 are what Fast DDS compares to decide "same process" (``GUID_t::
    is_on_same_process_as``): equal there, a writer delivers to a matched reader in memory
    and sends nothing, so the node index must sit inside them (two nodes of one drone are
    two processes); octets 0-3 stay the drone's ("same host", true of its nodes)."""
    tag = hashlib.sha256(f"{swarm}/{domain_id}/ros2".encode()).digest()[:ROS2_TAG_BYTES]
    return VENDOR_EPROSIMA + drone_index.to_bytes(2, "big") + node_index.to_bytes(2, "big") + tag


def ros2_participant_id(top_swarm_index: int, node_index: int) -> int:
    return top_swarm_index + 1 + node_index


def ros2_top_participant_id(domain_id: int) -> int:
    return max_participant_index(domain_id)


def dds_type_name(ros_type: str, suffix: str = "") -> str:
    """``pkg/msg/Name`` -> ``pkg::msg::dds_::Name_`` (rosidl_typesupport_fastrtps's naming)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}{suffix}_"


def _dds_name(ros_name: str) -> str:
    return ros_name.removeprefix("/")


# rmw's graph cache topic (rmw_dds_common: every participant's ParticipantEntitiesInfo)
GRAPH_TOPIC: Final = "ros_discovery_info"

# ROS 2's own endpoints of every rclpy node (rmw_fastrtps_shared_cpp, rcl): the participant's
# graph cache topic, parameter events and rosout. Parameter and type-description services are
# not listed: nodes on a static graph turn them off (docs/ros2.md).
_BUILTIN: Final = (
    Ros2Endpoint(
        GRAPH_TOPIC,
        GRAPH_TOPIC,
        "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_",
        Ros2EndpointKind.WRITER,
        Reliability.RELIABLE,
        Durability.TRANSIENT_LOCAL,
    ),
    Ros2Endpoint(
        GRAPH_TOPIC,
        GRAPH_TOPIC,
        "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_",
        Ros2EndpointKind.READER,
        Reliability.RELIABLE,
        Durability.TRANSIENT_LOCAL,
    ),
    Ros2Endpoint(
        "/parameter_events",
        "rt/parameter_events",
        "rcl_interfaces::msg::dds_::ParameterEvent_",
        Ros2EndpointKind.WRITER,
        Reliability.RELIABLE,
        Durability.VOLATILE,
    ),
    Ros2Endpoint(
        "/rosout",
        "rt/rosout",
        "rcl_interfaces::msg::dds_::Log_",
        Ros2EndpointKind.WRITER,
        Reliability.RELIABLE,
        Durability.TRANSIENT_LOCAL,
    ),
)


def node_endpoints(graph: Ros2Graph, node: Ros2Node) -> tuple[Ros2Endpoint, ...]:
    """Every DDS endpoint ``node`` creates, in a fixed order: ROS 2's own, then publications,
    subscriptions, served services (request reader, reply writer) and clients."""
    out: list[Ros2Endpoint] = list(_BUILTIN)
    for names, kind in (
        (node.publishes, Ros2EndpointKind.WRITER),
        (node.subscribes, Ros2EndpointKind.READER),
    ):
        for name in names:
            t = graph.topic(name)
            out.append(
                Ros2Endpoint(
                    name,
                    "rt/" + _dds_name(name),
                    dds_type_name(t.type_name),
                    kind,
                    t.qos.reliability,
                    t.qos.durability,
                )
            )
    for names, request_kind in (
        (node.serves, Ros2EndpointKind.READER),
        (node.calls, Ros2EndpointKind.WRITER),
    ):
        reply_kind = (
            Ros2EndpointKind.WRITER
            if request_kind == Ros2EndpointKind.READER
            else Ros2EndpointKind.READER
        )
        for name in names:
            s = graph.service(name)
            for prefix, suffix, kind in (
                ("rq/", "Request", request_kind),
                ("rr/", "Reply", reply_kind),
            ):
                dds_topic = prefix + _dds_name(name) + suffix
                type_suffix = "_Request" if suffix == "Request" else "_Response"
                out.append(
                    Ros2Endpoint(
                        dds_topic,
                        dds_topic,
                        dds_type_name(s.type_name, type_suffix),
                        kind,
                        # rclpy's services default: reliable, volatile (rmw_qos_profile_services)
                        Reliability.RELIABLE,
                        Durability.VOLATILE,
                    )
                )
    return tuple(out)


def ros2_participants(
    swarm: str,
    drone_indices: dict[str, int],
    graph: Ros2Graph,
) -> tuple[Ros2Participant, ...]:
    """Every ROS 2 participant of the swarm, by drone index then node index, with its
    derived prefix, ports and static EDP ids. ``drone_indices`` maps every swarm participant
    name to its index. Raises ``ValueError`` when ports or user ids run out (the mission
    checker turns that into a one-line error)."""
    top_swarm_index = max(drone_indices.values())
    by_drone = sorted(drone_indices.items(), key=lambda item: item[1])
    next_user_id = 1
    out: list[Ros2Participant] = []
    top_id = ros2_top_participant_id(graph.domain_id)
    for drone, drone_index in by_drone:
        if drone_index > MAX_ROS2_DRONE_INDEX:
            raise ValueError(f"drone index {drone_index} exceeds {MAX_ROS2_DRONE_INDEX}")
        if len(graph.nodes) - 1 > MAX_ROS2_NODE_INDEX:
            raise ValueError(f"{len(graph.nodes)} ROS 2 nodes exceed {MAX_ROS2_NODE_INDEX + 1}")
        for node in graph.nodes:
            if drone not in node.drones:
                continue
            pid = ros2_participant_id(top_swarm_index, node.index)
            if pid > top_id:
                raise ValueError(
                    f"node {node.name!r} needs RTPS participant id {pid}, above {top_id} in "
                    f"ROS 2 domain {graph.domain_id}"
                )
            endpoints = node_endpoints(graph, node)
            if len(endpoints) > MAX_NODE_ENDPOINTS:
                raise ValueError(
                    f"node {node.name!r} has {len(endpoints)} DDS endpoints, over "
                    f"{MAX_NODE_ENDPOINTS}: its discovery announcement would not fit one UDP "
                    "datagram"
                )
            out.append(
                Ros2Participant(
                    drone=drone,
                    drone_index=drone_index,
                    node=node,
                    guid_prefix=ros2_guid_prefix(swarm, graph.domain_id, drone_index, node.index),
                    participant_id=pid,
                    metatraffic_port=metatraffic_unicast_port(graph.domain_id, pid),
                    user_port=user_unicast_port(graph.domain_id, pid),
                    endpoints=endpoints,
                    first_user_id=next_user_id,
                )
            )
            next_user_id += len(endpoints)
    if next_user_id - 1 > MAX_USER_ID:
        raise ValueError(
            f"the graph has {next_user_id - 1} ROS 2 endpoints over all drones; Fast DDS static "
            f"discovery numbers them with 16-bit ids, at most {MAX_USER_ID}"
        )
    return tuple(out)


def bundle_ros2_participants(bundle: Bundle) -> tuple[Ros2Participant, ...]:
    """The bundle's ROS 2 participants (none when its mission declares no ``ros2:``)."""
    if bundle.ros2 is None:
        return ()
    return ros2_participants(
        bundle.swarm, {p.name: p.index for p in bundle.participants}, bundle.ros2
    )


def graph_value(graph: Ros2Graph, participants: tuple[Ros2Participant, ...]) -> dict[str, Any]:
    """The bundle body's ``ros2`` value: the declaration, plus every ROS 2 participant's
    derived prefix and ports for tools that do not run this code (the loader checks them)."""
    return {
        "domain_id": graph.domain_id,
        "topics": [
            {
                "name": t.name,
                "type_name": t.type_name,
                "reliability": t.qos.reliability.value,
                "durability": t.qos.durability.value,
                "history_depth": t.qos.history_depth,
            }
            for t in graph.topics
        ],
        "services": [{"name": s.name, "type_name": s.type_name} for s in graph.services],
        "nodes": [
            {
                "name": n.name,
                "index": n.index,
                "drones": list(n.drones),
                "publishes": list(n.publishes),
                "subscribes": list(n.subscribes),
                "serves": list(n.serves),
                "calls": list(n.calls),
            }
            for n in graph.nodes
        ],
        "participants": [
            {
                "drone": p.drone,
                "node": p.node.name,
                "guid_prefix": p.guid_prefix.hex(),
                "metatraffic_unicast_port": p.metatraffic_port,
                "user_unicast_port": p.user_port,
            }
            for p in participants
        ],
    }


def graph_from_value(value: Any, swarm: str, drone_indices: dict[str, int]) -> Ros2Graph:
    """Decode the body's ``ros2`` value; ``ValueError`` (or ``KeyError``/``TypeError``) when
    it is malformed or its derived identities differ from ``ros2_participants``."""
    if not isinstance(value, dict):
        raise ValueError("ros2: not an object")
    topics = tuple(
        Ros2Topic(
            _str(t["name"]),
            _str(t["type_name"]),
            Qos(
                Reliability(t["reliability"]),
                Durability(t["durability"]),
                _int(t["history_depth"]),
            ),
        )
        for t in value["topics"]
    )
    services = tuple(Ros2Service(_str(s["name"]), _str(s["type_name"])) for s in value["services"])
    topic_names = {t.name for t in topics}
    service_names = {s.name for s in services}
    nodes: list[Ros2Node] = []
    for i, n in enumerate(value["nodes"]):
        node = Ros2Node(
            _str(n["name"]),
            _int(n["index"]),
            tuple(_str(d) for d in n["drones"]),
            tuple(_str(x) for x in n["publishes"]),
            tuple(_str(x) for x in n["subscribes"]),
            tuple(_str(x) for x in n["serves"]),
            tuple(_str(x) for x in n["calls"]),
        )
        if node.index != i or not set(node.drones) <= drone_indices.keys():
            raise ValueError(f"ros2.nodes[{i}]: index out of order or unknown drone")
        if not set(node.publishes + node.subscribes) <= topic_names or not (
            set(node.serves + node.calls) <= service_names
        ):
            raise ValueError(f"ros2.nodes[{i}]: names an undeclared topic or service")
        nodes.append(node)
    graph = Ros2Graph(_int(value["domain_id"]), topics, services, tuple(nodes))
    derived = graph_value(graph, ros2_participants(swarm, drone_indices, graph))["participants"]
    if value["participants"] != derived:
        raise ValueError("ros2.participants: prefixes or ports are not the derived ones")
    return graph


def _str(value: Any) -> str:
    if not isinstance(value, str):
        raise TypeError(f"expected a string, got {type(value).__name__}")
    return value


def _int(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"expected an integer, got {type(value).__name__}")
    return value
