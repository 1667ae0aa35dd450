"""What the XRCE session engines report (frozen, past tense, one base type: style.md rule 10)."""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

Address = Hashable  # whatever the driver uses for a peer: ("127.0.0.1", 40000), "serial", ...


@dataclass(frozen=True, slots=True)
class XrceEvent:
    """Base of every event."""


@dataclass(frozen=True, slots=True)
class SessionCreated(XrceEvent):
    source: Address
    client_key: bytes
    session_id: int
    mtu: int


@dataclass(frozen=True, slots=True)
class SessionEnded(XrceEvent):
    source: Address
    client_key: bytes
    reason: str  # "deleted" | "timeout" | "replaced" | "agent_lost" | "refused:<status>"


@dataclass(frozen=True, slots=True)
class ClientRefused(XrceEvent):
    """A CREATE_CLIENT the agent refused (the agent is bound to another vehicle or session)."""

    source: Address
    client_key: bytes
    reason: str  # "wrong_key" | "vehicle_alive" | "too_many_sessions" | "bad_cookie" | ...


@dataclass(frozen=True, slots=True)
class EntityCreated(XrceEvent):
    source: Address
    object_id: int
    kind: int
    name: str | None  # topic name (topics, writers, readers), service name (repliers)
    type_name: str | None
    status: int


@dataclass(frozen=True, slots=True)
class SampleReceived(XrceEvent):
    """A sample a writer published (agent side) or a reader was sent (client side)."""

    source: Address
    topic_name: str
    type_name: str
    data: bytes


@dataclass(frozen=True, slots=True)
class PacketDropped(XrceEvent):
    source: Address
    reason: str
