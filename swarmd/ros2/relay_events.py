"""The ROS 2 relay's events (swarmd.ros2.relay): frozen, past tense, one base."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.rtps.types import GuidPrefix


@dataclass(frozen=True, slots=True)
class RelayEvent:
    """Base of the relay's events."""


@dataclass(frozen=True, slots=True)
class LocalParticipantHeard(RelayEvent):
    """A local ROS 2 participant of the bundle announced itself (``restarted``: after an
    earlier life this relay saw)."""

    drone: str
    node: str
    guid_prefix: GuidPrefix
    restarted: bool


@dataclass(frozen=True, slots=True)
class UnknownParticipantHeard(RelayEvent):
    """A participant the bundle does not place on this drone announced itself on loopback;
    it is shown, never relayed. ``vendor`` as two hex octets. ``suppressed``: how many new
    ones since the last report were not reported one by one (a flood: relay_local)."""

    guid_prefix: GuidPrefix
    vendor: str
    name: str | None
    suppressed: int = 0


@dataclass(frozen=True, slots=True)
class UndeclaredEndpoint(RelayEvent):
    """A local node announced a static endpoint the bundle does not hold for it (Fast DDS's
    EDPStatic property): it matches nothing, silently, in Fast DDS; reported here by node."""

    drone: str
    node: str
    kind: str  # "writer" | "reader"
    user_id: int  # the profile's userDefinedID (65535 or negative: none was given)
    entity_id: str


@dataclass(frozen=True, slots=True)
class LocalLivenessChanged(RelayEvent):
    """Which of this drone's ROS 2 participants are alive changed (a node heard, left, or
    its lease expired unheard), or one of them restarted. ``alive``: the liveness word
    swarmd carries in its signed SPDP (PID 0x8A06, ``Ros2Relay.liveness``): the bitmap over
    this drone's participants in bundle order, LSB of byte 0 = the first, then each one's
    restart count; ``node``/``up``: the participant that changed."""

    alive: bytes
    node: str
    up: bool


@dataclass(frozen=True, slots=True)
class RemoteNodeLiveness(RelayEvent):
    """An authenticated peer's relay says its node ``node`` stopped (``up`` False: the
    relay disposed it at the local nodes) or is back (announced again); ``restarted``: it
    came back under a running swarmd without having been seen stopped (disposed and
    announced again at once)."""

    drone: str
    node: str
    up: bool
    restarted: bool = False


@dataclass(frozen=True, slots=True)
class RemoteParticipantsRelayed(RelayEvent):
    """The relay started (``up``) or stopped serving a drone's ROS 2 participants;
    ``restarted``: the drone's swarmd restarted, its participants were disposed and
    announced again."""

    drone: str
    participants: int
    up: bool
    restarted: bool = False
