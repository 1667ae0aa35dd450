"""Fast DDS XML profiles and environment files for the swarm's stock ROS 2 nodes (issue 19).

The paper's "Static discovery" bar (Fig. 8) for operators' own rclpy/rclcpp nodes, generated
from the signed bundle so that no ROS 2 discovery is left to chance on the air:

- PDP: unicast only. UDPv4 is the one transport (no shared memory, no builtin transports),
  the participant's own metatraffic and user unicast locators are fixed (drone address + the
  bundle's ports), and ``initialPeersList`` names every other ROS 2 participant of the swarm
  with its explicit port (without a port Fast DDS probes a range of ports per peer). With no
  multicast locator and a non-empty peer list Fast DDS sends no multicast SPDP.
- EDP: ``STATIC``. Every endpoint of every declared node is listed in one static endpoint
  file with its ``userId``; each node's XML gives each of its endpoints that id through a
  ``data_writer``/``data_reader`` profile named after the ROS topic, which rmw_fastrtps looks
  up by that name. No SEDP datagram is then sent (measured: reference/ros2-fastdds-facts.md).
- The GUID prefix is the bundle's, so every drone knows every ROS 2 participant beforehand.
- Environment: ``RMW_IMPLEMENTATION=rmw_fastrtps_cpp``, ``FASTDDS_DEFAULT_PROFILES_FILE``,
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT`` (any other value makes rmw_fastrtps add
  its own peers or multicast on top of the XML), ``ROS_DOMAIN_ID``, no ``ROS_STATIC_PEERS``.

Pure text generation: no I/O, no ROS 2 package needed (this runs on the ground laptop).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from swarmd.bundle.model import Durability, Reliability
from swarmd.bundle.ros2 import GRAPH_TOPIC, Ros2EndpointKind, Ros2Graph, Ros2Participant
from swarmd.ros2.graph import UNIQUE_FLOW_SPAN, graph_reader_port, graph_writer_user_id

# SPDP lease and announcement period of the ROS 2 participants: Fast DDS's defaults (20 s
# lease, 3 s announcements) would be as chatty as stock; the bundle's own lease is reused
DEFAULT_LEASE_S: Final = 20
STATIC_EDP_FILE: Final = "static-edp.xml"
# the relay route's discovery address: IPv6 loopback, on a UDPv6 transport allowed on ::1
# only. Fast DDS binds a UDPv4 locator's port on 0.0.0.0 (or on every allowed interface),
# so a 127.0.0.1 metatraffic locator would still be reachable from the Wi-Fi at the drone's
# address; the UDPv4 transport cannot bind an IPv6 locator at all, and the UDPv6 one binds
# [::1] only (measured with ss -uanp: docs/ros2.md).
LOOPBACK6: Final = "::1"

_RELIABILITY: Final = {
    Reliability.RELIABLE: "RELIABLE_RELIABILITY_QOS",
    Reliability.BEST_EFFORT: "BEST_EFFORT_RELIABILITY_QOS",
}
_DURABILITY: Final = {
    Durability.VOLATILE: "VOLATILE_DURABILITY_QOS",
    Durability.TRANSIENT_LOCAL: "TRANSIENT_LOCAL_DURABILITY_QOS",
}


def escape(text: str) -> str:
    """XML character data (xml.sax.saxutils would pull in urllib and with it ``socket``)."""
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def quoteattr(text: str) -> str:
    return '"' + escape(text).replace('"', "&quot;") + '"'


class ProfileError(ValueError):
    """The bundle cannot give a profile (a drone without an address); ``problem``/``fix``."""

    def __init__(self, problem: str, fix: str) -> None:
        self.problem = problem
        self.fix = fix
        super().__init__(f"{problem}; fix: {fix}")


@dataclass(frozen=True, slots=True)
class ProfileFile:
    path: str  # relative: <drone>/<node>.xml, <drone>/<node>.env, <drone>/static-edp.xml
    text: str


def _prefix_text(prefix: bytes) -> str:
    return ".".join(f"{b:02x}" for b in prefix)


def _locator(address: str, port: int) -> str:
    kind = "udpv6" if ":" in address else "udpv4"
    return (
        f"<locator><{kind}><address>"
        + escape(address)
        + f"</address><port>{port}</port></{kind}></locator>"
    )


def static_edp_xml(
    participants: tuple[Ros2Participant, ...],
    addresses: Mapping[str, str],
    graph_writer: bool = False,
) -> str:
    """One static endpoint file for the whole swarm: every endpoint with its userId, topic,
    type, QoS and the user unicast locator of its participant. One ``<participant>`` named
    ``/`` (the name rclpy gives its participants, the default enclave): Fast DDS 3.2 matches
    on ``userId`` alone, and the single name also suits a build that checks it.

    ``graph_writer`` (the relay route): also swarmd's graph writer (swarmd.ros2.graph), the
    id after the bundle's last, with no locator: Fast DDS then sends to the locator its
    participant announces, the relay on [::1]. And each ``ros_discovery_info`` reader's
    locator is its unique-flow port (``graph_reader_port``, which the relay-route profile
    fixes with ``portBase``) instead of the user port, where Fast DDS never hands a sample
    to it: the nodes of one drone then see each other in their graphs (the other drones'
    graph endpoints are not announced on this route, so nothing goes over the air)."""
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        "<!-- generated by swarmctl ros2 profile from the swarm's bundle; do not edit -->",
        "<staticdiscovery>",
        "  <participant>",
        "    <name>/</name>",
    ]
    for p in participants:
        address = addresses[p.drone]
        lines.append(f"    <!-- {escape(p.drone)}/{escape(p.node.name)} -->")
        for i, e in enumerate(p.endpoints):
            tag = "writer" if e.kind == Ros2EndpointKind.WRITER else "reader"
            port = p.user_port
            if graph_writer and e.dds_topic == GRAPH_TOPIC and e.kind == Ros2EndpointKind.READER:
                port = graph_reader_port(p, participants)
            lines += [
                f"    <{tag}>",
                f"      <userId>{p.first_user_id + i}</userId>",
                f"      <topicName>{escape(e.dds_topic)}</topicName>",
                f"      <topicDataType>{escape(e.dds_type)}</topicDataType>",
                "      <topicKind>NO_KEY</topicKind>",
                f"      <reliabilityQos>{_RELIABILITY[e.reliability]}</reliabilityQos>",
                f"      <durabilityQos>{_DURABILITY[e.durability]}</durabilityQos>",
                f'      <unicastLocator address={quoteattr(address)} port="{port}"/>',
                f"    </{tag}>",
            ]
    graph_id = graph_writer_user_id(participants) if graph_writer else 0
    if graph_id:
        graph = next(e for p in participants for e in p.endpoints if e.dds_topic == GRAPH_TOPIC)
        lines += [
            "    <!-- swarmd's graph participant (the other drones' node names) -->",
            "    <writer>",
            f"      <userId>{graph_id}</userId>",
            f"      <topicName>{escape(graph.dds_topic)}</topicName>",
            f"      <topicDataType>{escape(graph.dds_type)}</topicDataType>",
            "      <topicKind>NO_KEY</topicKind>",
            f"      <reliabilityQos>{_RELIABILITY[Reliability.RELIABLE]}</reliabilityQos>",
            f"      <durabilityQos>{_DURABILITY[Durability.TRANSIENT_LOCAL]}</durabilityQos>",
            "    </writer>",
        ]
    lines += ["  </participant>", "</staticdiscovery>", ""]
    return "\n".join(lines)


def participant_xml(
    p: Ros2Participant,
    peers: tuple[Ros2Participant, ...],
    addresses: Mapping[str, str],
    static_edp_path: str,
    lease_s: int,
    relay_port: int | None = None,
) -> str:
    """The default participant profile of one ROS 2 process, plus one endpoint profile per
    endpoint it creates, carrying the endpoint's static EDP userId and, as its entity id,
    the same number (so the entity ids are known from the bundle: swarmd's relay announces
    them, swarmd.ros2.relay).

    ``relay_port`` set (``--via-swarmd``): the participant's metatraffic locator is on IPv6
    loopback (a UDPv6 transport allowed on ``::1`` only) and its initial peers are swarmd's
    relay plus the other ROS 2 participants of the same drone there: its discovery never
    leaves the drone, and nothing from the air reaches its discovery port; swarmd announces
    the other drones' participants to it (swarmd.ros2.relay). User data stays UDPv4 on the
    drone's address."""
    address = addresses[p.drone]
    announce_s = max(1, lease_s // 4)
    if relay_port is None:
        meta_address = address
        peer_lines = [
            "          " + _locator(addresses[q.drone], q.metatraffic_port)
            for q in peers
            if q.guid_prefix != p.guid_prefix
        ]
    else:
        meta_address = LOOPBACK6
        peer_lines = ["          " + _locator(LOOPBACK6, relay_port)] + [
            "          " + _locator(LOOPBACK6, q.metatraffic_port)
            for q in peers
            if q.drone == p.drone and q.guid_prefix != p.guid_prefix
        ]
    transports = ["swarm_udpv4"] if relay_port is None else ["swarm_udpv4", "swarm_lo6"]
    lo6 = [
        "      <transport_descriptor>",
        "        <transport_id>swarm_lo6</transport_id>",
        "        <type>UDPv6</type>",
        f"        <interfaceWhiteList><address>{LOOPBACK6}</address></interfaceWhiteList>",
        "      </transport_descriptor>",
    ]
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f"<!-- ROS 2 participant of {escape(p.drone)}/{escape(p.node.name)}: generated by "
        "swarmctl ros2 profile from the swarm's bundle; do not edit -->",
        '<dds xmlns="http://www.eprosima.com">',
        "  <profiles>",
        "    <transport_descriptors>",
        "      <transport_descriptor>",
        "        <transport_id>swarm_udpv4</transport_id>",
        "        <type>UDPv4</type>",
        "      </transport_descriptor>",
        *(lo6 if relay_port is not None else []),
        "    </transport_descriptors>",
        '    <participant profile_name="swarmd_ros2" is_default_profile="true">',
        "      <rtps>",
        *(
            []
            if relay_port is None
            else [
                # the graph reader's unique-flow port (swarmd.ros2.graph); every other port
                # of the participant is explicit above and below
                "        <port><portBase>"
                f"{graph_reader_port(p, peers) + UNIQUE_FLOW_SPAN}</portBase></port>"
            ]
        ),
        f"        <prefix>{_prefix_text(p.guid_prefix)}</prefix>",
        "        <useBuiltinTransports>false</useBuiltinTransports>",
        "        <userTransports>"
        + "".join(f"<transport_id>{t}</transport_id>" for t in transports)
        + "</userTransports>",
        "        <defaultUnicastLocatorList>",
        "          " + _locator(address, p.user_port),
        "        </defaultUnicastLocatorList>",
        "        <builtin>",
        "          <discovery_config>",
        "            <discoveryProtocol>SIMPLE</discoveryProtocol>",
        "            <EDP>STATIC</EDP>",
        f"            <static_edp_xml_config>file://{escape(static_edp_path)}</static_edp_xml_config>",
        f"            <leaseDuration><sec>{lease_s}</sec></leaseDuration>",
        f"            <leaseAnnouncement><sec>{announce_s}</sec></leaseAnnouncement>",
        "          </discovery_config>",
        "          <metatrafficUnicastLocatorList>",
        "            " + _locator(meta_address, p.metatraffic_port),
        "          </metatrafficUnicastLocatorList>",
        "          <initialPeersList>",
        *peer_lines,
        "          </initialPeersList>",
        "        </builtin>",
        "      </rtps>",
        "    </participant>",
    ]
    for i, e in enumerate(p.endpoints):
        tag = "data_writer" if e.kind == Ros2EndpointKind.WRITER else "data_reader"
        lines.append(
            f"    <{tag} profile_name={quoteattr(e.profile_name)}>"
            f"<userDefinedID>{p.first_user_id + i}</userDefinedID>"
            f"<entityID>{p.first_user_id + i}</entityID></{tag}>"
        )
    lines += ["  </profiles>", "</dds>", ""]
    return "\n".join(lines)


def environment(graph: Ros2Graph, profile_path: str) -> str:
    """The environment a node process is started with (``env $(cat F) ros2 run ...`` or a
    systemd ``EnvironmentFile=``)."""
    return "\n".join(
        [
            "# generated by swarmctl ros2 profile; source it before starting the node",
            "RMW_IMPLEMENTATION=rmw_fastrtps_cpp",
            f"ROS_DOMAIN_ID={graph.domain_id}",
            # SYSTEM_DEFAULT: rmw_fastrtps leaves the XML's locators and peers alone
            "ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT",
            "ROS_STATIC_PEERS=",
            f"FASTDDS_DEFAULT_PROFILES_FILE={profile_path}",
            # the XML's QoS must not override what the node asks for: only the ids are taken
            "RMW_FASTRTPS_USE_QOS_FROM_XML=0",
            "",
        ]
    )


def drone_profiles(
    graph: Ros2Graph,
    participants: tuple[Ros2Participant, ...],
    addresses: Mapping[str, str],
    drone: str,
    install_dir: str,
    lease_s: int = DEFAULT_LEASE_S,
    relay_port: int | None = None,
) -> list[ProfileFile]:
    """The files one drone needs: ``<node>.xml`` and ``<node>.env`` per node it runs, and the
    static endpoint file. ``install_dir`` is where they will live on the drone (the XML refers
    to the static file by absolute path)."""
    for q in participants:
        if q.drone not in addresses:
            raise ProfileError(
                f"drone {q.drone!r} runs ROS 2 node {q.node.name!r} but has no address",
                f"add 'ipv4:' to participant {q.drone!r} in the mission, or pass "
                f"--address {q.drone}=A.B.C.D",
            )
    base = install_dir.rstrip("/")
    static_path = f"{base}/{STATIC_EDP_FILE}"
    static_text = static_edp_xml(participants, addresses, graph_writer=relay_port is not None)
    out = [ProfileFile(f"{drone}/{STATIC_EDP_FILE}", static_text)]
    for p in participants:
        if p.drone != drone:
            continue
        xml_name = f"{p.node.name}.xml"
        out.append(
            ProfileFile(
                f"{drone}/{xml_name}",
                participant_xml(p, participants, addresses, static_path, lease_s, relay_port),
            )
        )
        out.append(
            ProfileFile(f"{drone}/{p.node.name}.env", environment(graph, f"{base}/{xml_name}"))
        )
    return out
