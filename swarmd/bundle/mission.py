"""The mission file: the operator's YAML description of one swarm, checked field by field.

The schema is documented in ``firmware_bundle/README.md``. Checking walks PyYAML's composed
node tree rather than the plain loaded dict, because only the nodes keep their line marks:
every rejection names the file, the line, the field path and the fix, and comes before any
output is written (issue 3, "Bad input").

Parsing is a pure function of the text (``parse_mission(text, file)``), so the builder's
determinism (same mission, same bytes) can be tested on generated missions without files.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final, NoReturn, TypeVar

import yaml

from swarmd.bundle.errors import MissionError
from swarmd.bundle.model import (
    DiscoveryParams,
    Durability,
    Liveliness,
    Qos,
    Reliability,
    Role,
)
from swarmd.bundle.ros2 import (
    MAX_NODE_ENDPOINTS,
    Ros2Graph,
    Ros2Node,
    Ros2Service,
    Ros2Topic,
    node_endpoints,
    ros2_participants,
)
from swarmd.rtps.ports import (
    DOMAIN_GAIN,
    MAX_DOMAIN_ID,
    MAX_PORT,
    OFFSET_D3,
    PARTICIPANT_GAIN,
    PORT_BASE,
    max_participant_index,
)
from swarmd.yamldoc import composed, read_text, unknown_field

# Names that become file names (keys/nodes/<name>.key) and DDS entity names: keep them to a
# portable, shell-safe alphabet.
NAME_RE: Final = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
# An IDL scoped name (IDL 4.2 7.2.3 identifiers joined by ``::``), which is what DDS type names
# are; IDL forbids a leading underscore in an unescaped identifier.
TYPE_NAME_RE: Final = re.compile(r"[A-Za-z][A-Za-z0-9_]*(::[A-Za-z][A-Za-z0-9_]*)*")
# DDS topic names: letters, digits, '_' and the '/' that ROS 2 and PX4 topic names use
# ("rt/fmu/in/..."); no leading digit, no empty path segment.
TOPIC_NAME_RE: Final = re.compile(r"[A-Za-z_/][A-Za-z0-9_/]*")
MAX_NAME_CHARS: Final = 255
MAX_HISTORY_DEPTH: Final = 100_000
# entity keys are 24 bits and key 0 is reserved (endpoint_entity_id uses topic index + 1)
MAX_TOPICS: Final = (1 << 24) - 2
MAVLINK_SYSID_MIN: Final = 1  # 0 is MAVLink's broadcast id
MAVLINK_SYSID_MAX: Final = 254  # 255 is the ground station by convention
SELECTOR_ALL: Final = "all"
RESERVED_NAMES: Final = frozenset({Role.COMMANDER.value, Role.MEMBER.value, SELECTOR_ALL})

_TOP_FIELDS: Final = ("swarm", "domain_id", "discovery", "participants", "topics", "ros2")
_ROS2_FIELDS: Final = ("domain_id", "topics", "services", "nodes")
_ROS2_TOPIC_FIELDS: Final = ("name", "type", "reliability", "durability", "history_depth")
_ROS2_SERVICE_FIELDS: Final = ("name", "type")
_ROS2_NODE_FIELDS: Final = ("name", "drones", "publishes", "subscribes", "serves", "calls")
# ROS 2 names (REP 144 / rcl's validation): absolute, segments of letters, digits and '_'
ROS2_NAME_RE: Final = re.compile(r"(/[A-Za-z][A-Za-z0-9_]*)+")
ROS2_NODE_NAME_RE: Final = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
ROS2_MSG_TYPE_RE: Final = re.compile(r"[a-z][a-z0-9_]*/msg/[A-Z][A-Za-z0-9]*")
ROS2_SRV_TYPE_RE: Final = re.compile(r"[a-z][a-z0-9_]*/srv/[A-Z][A-Za-z0-9]*")
# topics every rclpy node creates itself; the profile generator lists them already
ROS2_BUILTIN_TOPICS: Final = frozenset({"/rosout", "/parameter_events"})
# rclpy's default publisher/subscription depth (rmw_qos_profile_default: KEEP_LAST 10)
ROS2_DEFAULT_DEPTH: Final = 10
_DISCOVERY_FIELDS: Final = ("t_min_s", "t_max_s", "lease_s")
_PARTICIPANT_FIELDS: Final = ("name", "index", "role", "mavlink_sysid", "ipv4")
_TOPIC_FIELDS: Final = (
    "name",
    "type",
    "reliability",
    "durability",
    "history_depth",
    "liveliness",
    "liveliness_lease_s",
    "writers",
    "readers",
)

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class MissionParticipant:
    name: str
    index: int
    role: Role
    mavlink_sysid: int
    ipv4: str | None


@dataclass(frozen=True, slots=True)
class MissionTopic:
    name: str
    type_name: str
    qos: Qos
    index: int
    writers: tuple[str, ...]  # participant names, mission order
    readers: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Mission:
    """A checked mission: every invariant the bundle relies on already holds."""

    swarm: str
    domain_id: int
    discovery: DiscoveryParams
    participants: tuple[MissionParticipant, ...]  # sorted by index
    topics: tuple[MissionTopic, ...]  # mission order; the order keys the entity ids
    source: str
    ros2: Ros2Graph | None = None  # the operator's own ROS 2 graph (docs/ros2.md)


def load_mission(path: str | Path) -> Mission:
    """Read and check a mission file; raises ``MissionError`` (one line) on any problem."""
    text = read_text(path, MissionError, missing_fix="give the path of a mission YAML file")
    return parse_mission(text, str(path))


def parse_mission(text: str, file: str = "<mission>") -> Mission:
    """Check a mission given as YAML text; ``file`` only labels the error messages."""
    with composed(text, file, MissionError, empty_fix="write a mission (see README)") as (
        root,
        loader,
    ):
        return _Checker(file, loader).mission(root)


class _Checker:
    """Walks the node tree once; the first problem raises ``MissionError``."""

    def __init__(self, file: str, loader: yaml.SafeLoader) -> None:
        self.file = file
        self.loader = loader

    # -- failure -------------------------------------------------------------------------

    def fail(self, node: yaml.Node, field: str, problem: str, fix: str) -> NoReturn:
        raise MissionError(self.file, node.start_mark.line + 1, field, problem, fix)

    # -- node shapes ---------------------------------------------------------------------

    def mapping(
        self, node: yaml.Node, field: str, allowed: tuple[str, ...]
    ) -> dict[str, tuple[yaml.Node, yaml.Node]]:
        """Key name -> (key node, value node); rejects non-mappings, duplicate and unknown keys."""
        if not isinstance(node, yaml.MappingNode):
            self.fail(node, field, "expected a mapping (key: value lines)", "write it as a mapping")
        out: dict[str, tuple[yaml.Node, yaml.Node]] = {}
        for key_node, value_node in node.value:
            key = self.loader.construct_object(key_node, deep=True)
            path = f"{field}.{key}" if field != "<top>" else str(key)
            if not isinstance(key, str):
                self.fail(key_node, path, "keys must be strings", f"use one of {allowed}")
            if key not in allowed:
                self.fail(key_node, path, *unknown_field(key, allowed))
            if key in out:
                self.fail(
                    key_node,
                    path,
                    "duplicate key (YAML would silently keep the last one)",
                    "keep one",
                )
            out[key] = (key_node, value_node)
        return out

    def sequence(self, node: yaml.Node, field: str) -> list[yaml.Node]:
        if not isinstance(node, yaml.SequenceNode):
            self.fail(node, field, "expected a list", "write it as a YAML list ('- item' lines)")
        items: list[yaml.Node] = node.value
        return items

    def scalar(self, node: yaml.Node, field: str) -> object:
        if not isinstance(node, yaml.ScalarNode):
            self.fail(node, field, "expected a single value", "write a plain value, not a list/map")
        try:
            return self.loader.construct_object(node, deep=True)
        except yaml.YAMLError as exc:
            self.fail(node, field, f"unreadable value ({exc})", "write a plain value")

    def string(self, node: yaml.Node, field: str, what: str) -> str:
        value = self.scalar(node, field)
        if not isinstance(value, str) or not value:
            self.fail(node, field, f"expected {what}, got {value!r}", f"write {what}")
        return value

    def integer(self, node: yaml.Node, field: str, low: int, high: int, fix: str) -> int:
        value = self.scalar(node, field)
        # bool is an int in Python, but "index: yes" is a mistake, not 1
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(node, field, f"expected an integer, got {value!r}", fix)
        if not low <= value <= high:
            self.fail(node, field, f"{value} is outside {low}..{high}", fix)
        return value

    def seconds(self, node: yaml.Node, field: str, *, nullable: bool = False) -> float | None:
        value = self.scalar(node, field)
        if value is None and nullable:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(node, field, f"expected a duration in seconds, got {value!r}", "write e.g. 8")
        ms = round(value * 1000)
        # the bundle stores integer milliseconds, so a finer value would change silently
        if not 0 < ms <= 86_400_000 or abs(value * 1000 - ms) > 1e-6:
            self.fail(
                node,
                field,
                f"{value} s is not a positive whole number of milliseconds up to one day",
                "give a positive duration with at most 3 decimals",
            )
        return ms / 1000

    def enum(self, node: yaml.Node, field: str, kind: Callable[[str], T], names: list[str]) -> T:
        value = self.scalar(node, field)
        if not isinstance(value, str) or value not in names:
            self.fail(node, field, f"unknown value {value!r}", f"use one of: {', '.join(names)}")
        return kind(value)

    def required(
        self, fields: dict[str, tuple[yaml.Node, yaml.Node]], owner: yaml.Node, path: str, key: str
    ) -> yaml.Node:
        if key not in fields:
            where = f"{path}.{key}" if path != "<top>" else key
            self.fail(owner, where, "missing required field", f"add '{key}:'")
        return fields[key][1]

    # -- the mission ---------------------------------------------------------------------

    def mission(self, root: yaml.Node) -> Mission:
        top = self.mapping(root, "<top>", _TOP_FIELDS)
        swarm_node = self.required(top, root, "<top>", "swarm")
        swarm = self.string(swarm_node, "swarm", "a swarm name")
        if not NAME_RE.fullmatch(swarm):
            self.fail(
                swarm_node,
                "swarm",
                f"invalid swarm name {swarm!r}",
                "use 1-64 letters, digits, '_', '.', '-', starting with a letter or digit",
            )
        domain_id = self.integer(
            self.required(top, root, "<top>", "domain_id"),
            "domain_id",
            0,
            MAX_DOMAIN_ID,
            f"use a DDS domain id in 0..{MAX_DOMAIN_ID} (the RTPS port mapping's limit)",
        )
        discovery = self.discovery(top["discovery"][1]) if "discovery" in top else DiscoveryParams()
        participants = self.participants(
            self.required(top, root, "<top>", "participants"), domain_id
        )
        topics = self.topics(self.required(top, root, "<top>", "topics"), participants)
        ros2 = self.ros2(top["ros2"][1], swarm, domain_id, participants) if "ros2" in top else None
        return Mission(
            swarm=swarm,
            domain_id=domain_id,
            discovery=discovery,
            participants=tuple(sorted(participants, key=lambda p: p.index)),
            topics=tuple(topics),
            source=self.file,
            ros2=ros2,
        )

    def discovery(self, node: yaml.Node) -> DiscoveryParams:
        fields = self.mapping(node, "discovery", _DISCOVERY_FIELDS)
        defaults = DiscoveryParams()
        values: dict[str, float] = {}
        for key in _DISCOVERY_FIELDS:
            if key in fields:
                seconds = self.seconds(fields[key][1], f"discovery.{key}")
                assert seconds is not None  # noqa: S101 - seconds() returns None only if nullable
                values[key] = seconds
        params = DiscoveryParams(
            t_min_s=values.get("t_min_s", defaults.t_min_s),
            t_max_s=values.get("t_max_s", defaults.t_max_s),
            lease_s=values.get("lease_s", defaults.lease_s),
        )
        if params.t_max_s < params.t_min_s:
            bad = fields.get("t_max_s", fields.get("t_min_s"))
            self.fail(
                bad[1] if bad is not None else node,
                "discovery.t_max_s",
                f"Tmax {params.t_max_s} s is below Tmin {params.t_min_s} s",
                "make t_max_s >= t_min_s (paper section 4.1 draws the timer in [Tmin, Tmax])",
            )
        return params

    def participants(self, node: yaml.Node, domain_id: int) -> list[MissionParticipant]:
        items = self.sequence(node, "participants")
        if not items:
            self.fail(node, "participants", "no participants", "list at least one participant")
        out: list[MissionParticipant] = []
        seen_name: dict[str, int] = {}
        seen_index: dict[int, str] = {}
        seen_sysid: dict[int, str] = {}
        seen_ip: dict[str, str] = {}
        top_index = max_participant_index(domain_id)
        for i, item in enumerate(items):
            path = f"participants[{i}]"
            f = self.mapping(item, path, _PARTICIPANT_FIELDS)
            name_node = self.required(f, item, path, "name")
            name = self.string(name_node, f"{path}.name", "a participant name")
            if not NAME_RE.fullmatch(name):
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"invalid participant name {name!r}",
                    "use 1-64 letters, digits, '_', '.', '-', starting with a letter or digit",
                )
            if name in RESERVED_NAMES:
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"{name!r} is reserved for writers/readers selectors",
                    "pick another name",
                )
            if name in seen_name:
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"duplicate participant name {name!r} (also participants[{seen_name[name]}])",
                    "give every participant a unique name",
                )
            seen_name[name] = i
            index_node = self.required(f, item, path, "index")
            index = self._participant_index(index_node, f"{path}.index", domain_id, top_index)
            if index in seen_index:
                self.fail(
                    index_node,
                    f"{path}.index",
                    f"duplicate participant index {index} (also {seen_index[index]!r})",
                    "give every participant a unique index",
                )
            seen_index[index] = name
            role = self.enum(
                self.required(f, item, path, "role"), f"{path}.role", Role, [r.value for r in Role]
            )
            sysid_node = self.required(f, item, path, "mavlink_sysid")
            sysid = self.integer(
                sysid_node,
                f"{path}.mavlink_sysid",
                MAVLINK_SYSID_MIN,
                MAVLINK_SYSID_MAX,
                "use the vehicle's MAV_SYS_ID, 1..254 (0 is broadcast, 255 the ground station)",
            )
            # MAVLink has 254 vehicle ids: a bigger swarm must reuse them (one ground station
            # cannot watch it all anyway); below that a duplicate is a typo that would make a
            # ground station merge two vehicles
            if sysid in seen_sysid and len(items) <= MAVLINK_SYSID_MAX:
                self.fail(
                    sysid_node,
                    f"{path}.mavlink_sysid",
                    f"duplicate MAVLink system id {sysid} (also {seen_sysid[sysid]!r})",
                    "give every vehicle its own MAV_SYS_ID",
                )
            seen_sysid[sysid] = name
            ipv4 = None
            if "ipv4" in f and self.scalar(f["ipv4"][1], f"{path}.ipv4") is not None:
                ipv4 = self._ipv4(f["ipv4"][1], f"{path}.ipv4")
                if ipv4 in seen_ip:
                    self.fail(
                        f["ipv4"][1],
                        f"{path}.ipv4",
                        f"duplicate address {ipv4} (also {seen_ip[ipv4]!r})",
                        "give every drone its own address or leave ipv4 out",
                    )
                seen_ip[ipv4] = name
            out.append(MissionParticipant(name, index, role, sysid, ipv4))
        return out

    def _participant_index(self, node: yaml.Node, field: str, domain_id: int, top: int) -> int:
        value = self.scalar(node, field)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            self.fail(node, field, f"expected an index >= 0, got {value!r}", "write e.g. 3")
        if value > top:
            port = PORT_BASE + DOMAIN_GAIN * domain_id + OFFSET_D3 + PARTICIPANT_GAIN * value
            self.fail(
                node,
                field,
                f"index {value} overflows the port range of domain {domain_id} "
                f"(its user unicast port would be {port} > {MAX_PORT})",
                f"use an index <= {top} in domain {domain_id}, or a lower domain_id",
            )
        return value

    def _ipv4(self, node: yaml.Node, field: str) -> str:
        value = self.scalar(node, field)
        try:
            address = ipaddress.IPv4Address(str(value))
        except ValueError:
            self.fail(node, field, f"{value!r} is not an IPv4 address", "write e.g. 10.42.0.11")
        if (
            address.is_multicast
            or address.is_unspecified
            or address == ipaddress.IPv4Address("255.255.255.255")
        ):
            self.fail(node, field, f"{address} is not a unicast address", "use the drone's address")
        return str(address)

    def topics(self, node: yaml.Node, participants: list[MissionParticipant]) -> list[MissionTopic]:
        items = self.sequence(node, "topics")
        if not items:
            self.fail(node, "topics", "no topics", "list at least one topic")
        if len(items) > MAX_TOPICS:
            self.fail(node, "topics", f"{len(items)} topics", f"use at most {MAX_TOPICS}")
        out: list[MissionTopic] = []
        seen: dict[str, int] = {}
        for i, item in enumerate(items):
            path = f"topics[{i}]"
            f = self.mapping(item, path, _TOPIC_FIELDS)
            name_node = self.required(f, item, path, "name")
            name = self.string(name_node, f"{path}.name", "a topic name")
            if (
                not TOPIC_NAME_RE.fullmatch(name)
                or "//" in name
                or name.endswith("/")
                or len(name) > MAX_NAME_CHARS
            ):
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"{name!r} is not a valid DDS topic name",
                    "use letters, digits, '_' and single '/' separators, no leading digit, "
                    f"at most {MAX_NAME_CHARS} characters (e.g. swarm/ready)",
                )
            if name in seen:
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"duplicate topic {name!r} (also topics[{seen[name]}])",
                    "list each topic once; one entry can name several writers and readers",
                )
            seen[name] = i
            type_node = self.required(f, item, path, "type")
            type_name = self.string(type_node, f"{path}.type", "a DDS type name")
            if not TYPE_NAME_RE.fullmatch(type_name) or len(type_name) > MAX_NAME_CHARS:
                self.fail(
                    type_node,
                    f"{path}.type",
                    f"{type_name!r} is not a valid DDS type name",
                    "use an IDL scoped name: identifiers of letters, digits and '_' (starting "
                    "with a letter) joined by '::', e.g. swarmd::Readiness",
                )
            qos = self.qos(f, path)
            writers = self.selectors(f, item, path, "writers", participants)
            readers = self.selectors(f, item, path, "readers", participants)
            out.append(MissionTopic(name, type_name, qos, i, writers, readers))
        return out

    def qos(self, f: dict[str, tuple[yaml.Node, yaml.Node]], path: str) -> Qos:
        default = Qos()
        reliability = default.reliability
        if "reliability" in f:
            names = [r.value for r in Reliability]
            reliability = self.enum(f["reliability"][1], f"{path}.reliability", Reliability, names)
        durability = default.durability
        if "durability" in f:
            names = [d.value for d in Durability]
            durability = self.enum(f["durability"][1], f"{path}.durability", Durability, names)
        depth = default.history_depth
        if "history_depth" in f:
            depth = self.integer(
                f["history_depth"][1],
                f"{path}.history_depth",
                1,
                MAX_HISTORY_DEPTH,
                f"use a KEEP_LAST depth in 1..{MAX_HISTORY_DEPTH}",
            )
        liveliness = default.liveliness
        if "liveliness" in f:
            names = [v.value for v in Liveliness]
            liveliness = self.enum(f["liveliness"][1], f"{path}.liveliness", Liveliness, names)
        lease = default.liveliness_lease_s
        if "liveliness_lease_s" in f:
            lease = self.seconds(
                f["liveliness_lease_s"][1], f"{path}.liveliness_lease_s", nullable=True
            )
        return Qos(reliability, durability, depth, liveliness, lease)

    def selectors(
        self,
        f: dict[str, tuple[yaml.Node, yaml.Node]],
        owner: yaml.Node,
        path: str,
        key: str,
        participants: list[MissionParticipant],
    ) -> tuple[str, ...]:
        field = f"{path}.{key}"
        node = self.required(f, owner, path, key)
        entries: list[tuple[yaml.Node, object]]
        if isinstance(node, yaml.SequenceNode):
            entries = [(n, self.scalar(n, field)) for n in node.value]
        else:
            entries = [(node, self.scalar(node, field))]
        by_name = {p.name: p for p in participants}
        chosen: set[str] = set()
        for entry_node, value in entries:
            if value == SELECTOR_ALL:
                chosen.update(by_name)
            elif value in (Role.COMMANDER.value, Role.MEMBER.value):
                chosen.update(p.name for p in participants if p.role.value == value)
            elif isinstance(value, str) and value in by_name:
                chosen.add(value)
            else:
                self.fail(
                    entry_node,
                    field,
                    f"{value!r} is neither a role nor a participant name",
                    "use 'commander', 'member', 'all' or a participant's name",
                )
        if not chosen:
            verb = "written" if key == "writers" else "read"
            self.fail(
                node,
                field,
                f"the topic is {verb} by nobody (the selectors match no participant)",
                f"name at least one participant or a role that some participant has in '{key}'",
            )
        return tuple(p.name for p in participants if p.name in chosen)

    # -- the ROS 2 graph (issue 19, docs/ros2.md) ------------------------------------------

    def ros2(
        self, node: yaml.Node, swarm: str, domain_id: int, participants: list[MissionParticipant]
    ) -> Ros2Graph:
        f = self.mapping(node, "ros2", _ROS2_FIELDS)
        ros_domain = domain_id
        if "domain_id" in f:
            ros_domain = self.integer(
                f["domain_id"][1],
                "ros2.domain_id",
                0,
                MAX_DOMAIN_ID,
                f"use the nodes' ROS_DOMAIN_ID, 0..{MAX_DOMAIN_ID}",
            )
        topics: list[Ros2Topic] = []
        for i, item in enumerate(self.sequence(self.required(f, node, "ros2", "topics"), "ros2")):
            path = f"ros2.topics[{i}]"
            tf = self.mapping(item, path, _ROS2_TOPIC_FIELDS)
            name = self._ros2_name(self.required(tf, item, path, "name"), f"{path}.name")
            if name in ROS2_BUILTIN_TOPICS or any(t.name == name for t in topics):
                self.fail(
                    tf["name"][1],
                    f"{path}.name",
                    f"topic {name!r} is declared twice or is one of ROS 2's own",
                    "declare each topic once; /rosout and /parameter_events are always listed",
                )
            type_name = self._ros2_type(
                self.required(tf, item, path, "type"), f"{path}.type", ROS2_MSG_TYPE_RE
            )
            qos = self.qos(tf, path)
            if "reliability" not in tf:  # ROS 2's default is reliable, DDS's best effort
                qos = Qos(Reliability.RELIABLE, qos.durability, qos.history_depth)
            if "history_depth" not in tf:
                qos = Qos(qos.reliability, qos.durability, ROS2_DEFAULT_DEPTH)
            topics.append(Ros2Topic(name, type_name, qos))
        services: list[Ros2Service] = []
        if "services" in f:
            for i, item in enumerate(self.sequence(f["services"][1], "ros2.services")):
                path = f"ros2.services[{i}]"
                sf = self.mapping(item, path, _ROS2_SERVICE_FIELDS)
                name = self._ros2_name(self.required(sf, item, path, "name"), f"{path}.name")
                if any(s.name == name for s in services):
                    self.fail(
                        sf["name"][1], f"{path}.name", f"duplicate service {name!r}", "keep one"
                    )
                type_name = self._ros2_type(
                    self.required(sf, item, path, "type"), f"{path}.type", ROS2_SRV_TYPE_RE
                )
                services.append(Ros2Service(name, type_name))
        nodes: list[Ros2Node] = []
        items = self.sequence(self.required(f, node, "ros2", "nodes"), "ros2.nodes")
        if not items:
            self.fail(node, "ros2.nodes", "no nodes", "declare at least one ROS 2 node")
        for i, item in enumerate(items):
            path = f"ros2.nodes[{i}]"
            nf = self.mapping(item, path, _ROS2_NODE_FIELDS)
            name_node = self.required(nf, item, path, "name")
            name = self.string(name_node, f"{path}.name", "a ROS 2 node name")
            if not ROS2_NODE_NAME_RE.fullmatch(name) or any(n.name == name for n in nodes):
                self.fail(
                    name_node,
                    f"{path}.name",
                    f"invalid or duplicate node name {name!r}",
                    "use a unique name of letters, digits and '_', starting with a letter",
                )
            drones = self.selectors(nf, item, path, "drones", participants)
            known_topics = [t.name for t in topics]
            known_services = [s.name for s in services]
            refs = [
                self._ros2_refs(nf, path, key, known)
                for key, known in (
                    ("publishes", known_topics),
                    ("subscribes", known_topics),
                    ("serves", known_services),
                    ("calls", known_services),
                )
            ]
            ros2_node = Ros2Node(name, i, drones, refs[0], refs[1], refs[2], refs[3])
            declared = Ros2Graph(ros_domain, tuple(topics), tuple(services), ())
            count = len(node_endpoints(declared, ros2_node))
            if count > MAX_NODE_ENDPOINTS:
                self.fail(
                    item,
                    path,
                    f"node {name!r} has {count} DDS endpoints (topics, two per service, "
                    f"ROS 2's own), over {MAX_NODE_ENDPOINTS}: its discovery announcement would "
                    "not fit one UDP datagram",
                    "split it into several nodes",
                )
            nodes.append(ros2_node)
        graph = Ros2Graph(ros_domain, tuple(topics), tuple(services), tuple(nodes))
        try:
            ros2_participants(swarm, {p.name: p.index for p in participants}, graph)
        except ValueError as exc:
            self.fail(
                node, "ros2.nodes", str(exc), "declare fewer nodes or endpoints, or lower indices"
            )
        return graph

    def _ros2_name(self, node: yaml.Node, field: str) -> str:
        name = self.string(node, field, "a ROS 2 name")
        if not ROS2_NAME_RE.fullmatch(name) or len(name) > MAX_NAME_CHARS:
            self.fail(
                node,
                field,
                f"{name!r} is not an absolute ROS 2 name",
                "write e.g. /chatter or /drone/status: '/'-separated segments of letters, "
                "digits and '_', each starting with a letter",
            )
        return name

    def _ros2_type(self, node: yaml.Node, field: str, pattern: re.Pattern[str]) -> str:
        value = self.string(node, field, "a ROS 2 type")
        if not pattern.fullmatch(value):
            example = "std_srvs/srv/Trigger" if "srv" in pattern.pattern else "std_msgs/msg/String"
            self.fail(node, field, f"{value!r} is not a ROS 2 type name", f"write e.g. {example}")
        return value

    def _ros2_refs(
        self, f: dict[str, tuple[yaml.Node, yaml.Node]], path: str, key: str, known: list[str]
    ) -> tuple[str, ...]:
        if key not in f:
            return ()
        field = f"{path}.{key}"
        out: list[str] = []
        for item in self.sequence(f[key][1], field):
            value = self.scalar(item, field)
            if not isinstance(value, str) or value not in known:
                what = "topic" if key in ("publishes", "subscribes") else "service"
                self.fail(
                    item,
                    field,
                    f"{value!r} is not a declared ROS 2 {what}",
                    f"declare it under ros2.{what}s first, or use one of: "
                    f"{', '.join(known) or '(none declared)'}",
                )
            if value not in out:
                out.append(value)
        return tuple(out)
