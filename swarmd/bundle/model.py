"""The firmware bundle's in-memory model: what a verified bundle tells the daemon.

Everything SEDP would have carried at runtime, decided before flight (paper section 4.2):
every participant (name, index, role, GUID prefix, ports, announcement key) and every
endpoint (topic, type, QoS, entity id). The engine answers "which endpoints of peer P match
mine" from this model alone, with no SEDP on the air.

Identity is derived, never drawn: ``derive_guid_prefix`` and ``endpoint_entity_id`` are pure
functions of the mission, so the same mission always yields the same GUIDs.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Final

from swarmd.rtps.ports import metatraffic_unicast_port, user_unicast_port
from swarmd.rtps.types import VENDORID_SWARMD, EntityId, EntityKind, Guid, GuidPrefix

if TYPE_CHECKING:  # swarmd.bundle.ros2 imports this module's QoS types
    from swarmd.bundle.ros2 import Ros2Graph


class Role(StrEnum):
    COMMANDER = "commander"
    MEMBER = "member"


class Reliability(StrEnum):
    BEST_EFFORT = "best_effort"
    RELIABLE = "reliable"


class Durability(StrEnum):
    VOLATILE = "volatile"
    TRANSIENT_LOCAL = "transient_local"


class Liveliness(StrEnum):
    AUTOMATIC = "automatic"
    MANUAL_BY_PARTICIPANT = "manual_by_participant"
    MANUAL_BY_TOPIC = "manual_by_topic"


class EndpointKind(StrEnum):
    WRITER = "writer"
    READER = "reader"


@dataclass(frozen=True, slots=True)
class Qos:
    reliability: Reliability = Reliability.BEST_EFFORT
    durability: Durability = Durability.VOLATILE
    history_depth: int = 1
    liveliness: Liveliness = Liveliness.AUTOMATIC
    liveliness_lease_s: float | None = None  # None = infinite

    def compatible_with(self, reader: Qos) -> bool:
        """DDS request/offered rule for this (writer) QoS against a reader's (DDS 1.4 2.2.3)."""
        rel_ok = not (
            reader.reliability == Reliability.RELIABLE
            and self.reliability == Reliability.BEST_EFFORT
        )
        dur_ok = not (
            reader.durability == Durability.TRANSIENT_LOCAL
            and self.durability == Durability.VOLATILE
        )
        return rel_ok and dur_ok


@dataclass(frozen=True, slots=True)
class Topic:
    name: str
    type_name: str
    qos: Qos
    index: int  # position in the mission's topic list; keys the endpoint entity ids


@dataclass(frozen=True, slots=True)
class Endpoint:
    topic: str
    kind: EndpointKind
    entity_id: EntityId


@dataclass(frozen=True, slots=True)
class Participant:
    name: str
    index: int  # participant index: ports and the bit in the "heard" digest
    role: Role
    mavlink_sysid: int
    ipv4: str | None
    guid_prefix: GuidPrefix
    announce_public_key: bytes  # raw Ed25519 public key (32 bytes): verifies its SPDP
    endpoints: tuple[Endpoint, ...]
    # raw X25519 public key (32 bytes, bundle format 2): static Diffie-Hellman with it gives
    # every pair of nodes a shared key without a message on the air (swarmd.auth.keys)
    x25519_public_key: bytes

    def guid(self, endpoint: Endpoint) -> Guid:
        return Guid(self.guid_prefix, endpoint.entity_id)


@dataclass(frozen=True, slots=True)
class DiscoveryParams:
    t_min_s: float = 8.0  # paper section 4.1, Tmin
    t_max_s: float = 20.0  # paper section 4.1, Tmax
    lease_s: float = 20.0


@dataclass(frozen=True, slots=True)
class Match:
    """One of my endpoints paired with a peer's endpoint on the same topic."""

    topic: str
    local: Guid
    remote: Guid
    local_kind: EndpointKind


@dataclass(frozen=True, slots=True)
class Bundle:
    swarm: str
    domain_id: int
    discovery: DiscoveryParams
    topics: tuple[Topic, ...]
    participants: tuple[Participant, ...]  # sorted by index
    content_sha256: bytes  # hash of the canonical content (what peers compare)
    signing_public_key: bytes  # raw Ed25519 public key of the swarm signing key
    dev: bool = False  # an --unsigned-dev bundle: its node keys are publicly derivable
    ros2: Ros2Graph | None = None  # the operator's ROS 2 graph (issue 19, docs/ros2.md)
    # the anti-rollback serial (1..SERIAL_MAX, in the signed body): drones refuse a serial
    # below the highest they accepted (swarmd.bundle.floor); None: built before serials
    serial: int | None = None

    @property
    def size(self) -> int:
        return len(self.participants)

    def participant(self, name: str) -> Participant:
        for p in self.participants:
            if p.name == name:
                return p
        raise KeyError(f"no participant named {name!r} in bundle of swarm {self.swarm!r}")

    def member(self, node: str) -> Participant:
        """This node's own participant: the one check that a node belongs to the bundle.

        Raises ``NotAParticipant`` (a ``ValueError``) with the one message every caller
        shows: the daemon's config check, the discovery engine, the swarm layer."""
        for p in self.participants:
            if p.name == node:
                return p
        raise NotAParticipant(self, node)

    def by_prefix(self, prefix: GuidPrefix) -> Participant | None:
        index = _prefix_index(self, prefix)
        return self.participants_by_index().get(index) if index is not None else None

    def participants_by_index(self) -> dict[int, Participant]:
        return {p.index: p for p in self.participants}

    def topic(self, name: str) -> Topic:
        for t in self.topics:
            if t.name == name:
                return t
        raise KeyError(f"no topic named {name!r}")

    def metatraffic_port(self, p: Participant) -> int:
        return metatraffic_unicast_port(self.domain_id, p.index)

    def user_port(self, p: Participant) -> int:
        return user_unicast_port(self.domain_id, p.index)

    def matches(self, local: Participant, peer: Participant) -> list[Match]:
        """Endpoint pairs between ``local`` and ``peer``: same topic, opposite kinds, QoS
        compatible. This is what SEDP would have established, answered from the bundle."""
        out: list[Match] = []
        for le in local.endpoints:
            for re in peer.endpoints:
                if le.topic != re.topic or le.kind == re.kind:
                    continue
                topic = self.topic(le.topic)
                # both sides of a bundle topic carry the topic's QoS, so they are compatible
                # by construction; the check stays for bundles whose endpoints override QoS
                if not topic.qos.compatible_with(topic.qos):
                    continue
                out.append(Match(le.topic, local.guid(le), peer.guid(re), le.kind))
        return out


SWARM_TAG_BYTES: Final = 6
# a u32, like every counter on the wire: 4 billion re-signings outlast any swarm
SERIAL_MAX: Final = 0xFFFF_FFFF


def is_serial(value: object) -> bool:
    """Whether ``value`` is a serial a bundle may carry: a whole number 1..``SERIAL_MAX``
    (0 is what a bundle without one counts as, so none is built or accepted with 0)."""
    return isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= SERIAL_MAX


def derive_guid_prefix(swarm: str, domain_id: int, index: int) -> GuidPrefix:
    """``"SW" | sha256(swarm/domain)[:6] | index (u32 BE)``.

    Bytes 0-1 carry swarmd's vendor id as spec 9.3.1.5 suggests; the swarm tag keeps two
    swarms on one channel apart; the index makes the prefix unique within the swarm.
    """
    tag = hashlib.sha256(f"{swarm}/{domain_id}".encode()).digest()[:SWARM_TAG_BYTES]
    return GuidPrefix(VENDORID_SWARMD.value + tag + index.to_bytes(4, "big"))


class NotAParticipant(ValueError):
    """A node name the bundle does not list; ``problem`` and ``fix`` for a config error."""

    def __init__(self, bundle: Bundle, node: str) -> None:
        shown = ", ".join(p.name for p in bundle.participants[:8])
        more = ", ..." if len(bundle.participants) > 8 else ""
        self.problem = f"{node!r} is not a participant of swarm {bundle.swarm!r}"
        self.fix = f"use one of {shown}{more}"
        super().__init__(f"node {self.problem}; fix: {self.fix}")


def _prefix_index(bundle: Bundle, prefix: GuidPrefix) -> int | None:
    expected = derive_guid_prefix(bundle.swarm, bundle.domain_id, 0).value[:8]
    if prefix.value[:8] != expected:
        return None
    return int.from_bytes(prefix.value[8:], "big")


def endpoint_entity_id(topic_index: int, kind: EndpointKind) -> EntityId:
    """Entity key = topic index + 1 (24 bits); kind byte = keyless writer/reader (spec 9.3.1.2)."""
    entity_kind = (
        EntityKind.WRITER_NO_KEY if kind == EndpointKind.WRITER else EntityKind.READER_NO_KEY
    )
    return EntityId.user(topic_index + 1, entity_kind)
