"""What the discovery engine tells its driver: frozen, slotted, past-tense events.

Every event derives from ``Event``, so a driver can ``match`` on them and close with
``assert_never`` to have mypy check it handles each kind.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.bundle.model import Match
from swarmd.discovery.phases import Phase
from swarmd.rtps.types import GuidPrefix


@dataclass(frozen=True, slots=True)
class Event:
    """Base of every discovery event."""


@dataclass(frozen=True, slots=True)
class PeerDiscovered(Event):
    """A bundle participant was heard; its endpoints are matched from the bundle (no SEDP)."""

    name: str
    guid_prefix: GuidPrefix
    matches: tuple[Match, ...]
    via: str  # "multicast" | "directed"


@dataclass(frozen=True, slots=True)
class PeerLost(Event):
    """A discovered bundle participant went away."""

    name: str
    guid_prefix: GuidPrefix
    reason: str  # "lease" | "disposed"


@dataclass(frozen=True, slots=True)
class ForeignParticipantSeen(Event):
    """An SPDP participant that is not (or not verifiably) in our bundle: listed, never matched.

    ``reason``: "not_in_bundle" (stock DDS node, stranger), "digest_mismatch" (a swarmd node
    flashed with another bundle) or "vendor_mismatch" (a bundle GUID prefix sent by a stack
    that is not swarmd).
    """

    guid_prefix: GuidPrefix
    vendor: str
    name: str | None
    reason: str = "not_in_bundle"


@dataclass(frozen=True, slots=True)
class PhaseChanged(Event):
    old: Phase
    new: Phase
    reason: str


@dataclass(frozen=True, slots=True)
class PacketDropped(Event):
    """A datagram (or one SPDP sample in it) was ignored; ``reason`` names the counter."""

    reason: str
    source: tuple[str, int]
