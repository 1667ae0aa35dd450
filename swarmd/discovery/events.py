"""What the discovery engine tells its driver: frozen, slotted, past-tense events.

Every event derives from ``Event``, so a driver can ``match`` on them and close with
``assert_never`` to have mypy check it handles each kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

from swarmd.bundle.model import Match
from swarmd.discovery.phases import Phase
from swarmd.rtps.locator import Locator
from swarmd.rtps.types import GuidPrefix


class DropReason(StrEnum):
    """Why a datagram (or one SPDP sample in it) moved nothing: the one list of drop reasons.

    The engine counts them in a ``collections.Counter`` (a reason added here can never raise
    out of ``receive_datagram``) and reports every member, zero or not, in
    ``counters()["dropped"]`` in this order. The last three also name why a participant is
    foreign (``ForeignParticipantSeen.reason``).
    """

    DECODE_ERROR = "decode_error"  # not RTPS, or a malformed submessage (rtps.DecodeError)
    WRONG_DOMAIN = "wrong_domain"  # another domain id or a domain tag
    OWN = "own"  # our own multicast, looped back by the kernel
    NOT_SPDP = "not_spdp"  # RTPS, but no SPDP DATA(p) in it
    NOT_FOR_ME = "not_for_me"  # a directed DATA(p) for another participant
    NOT_IN_BUNDLE = "not_in_bundle"  # a GUID prefix the bundle does not list
    DIGEST_MISMATCH = "digest_mismatch"  # a swarmd node flashed with another bundle
    VENDOR_MISMATCH = "vendor_mismatch"  # a bundle GUID prefix sent by a stack not swarmd
    STOPPED = "stopped"  # received after shutdown()
    # authentication (swarmd.auth.spdp, docs/security.md): a datagram under a bundle GUID
    # prefix moves nothing unless its authenticator holds; cheapest checks first
    AUTH_MISSING = "auth_missing"  # no authenticator at the end of the datagram
    AUTH_REPLAYED = "auth_replayed"  # freshness not newer than the sender's replay window
    AUTH_BAD_TAG = "auth_bad_tag"  # my receiver tag did not hold: not made by the sender
    AUTH_BUDGET_SENDER = "auth_budget_sender"  # this sender/address spent its verifications
    AUTH_BUDGET_GLOBAL = "auth_budget_global"  # unverified addresses spent the shared budget
    AUTH_BAD_SIGNATURE = "auth_bad_signature"  # not signed with the prefix's bundle key
    AUTH_REPEATED_FORGERY = "auth_repeated_forgery"  # these octets already failed Ed25519 here
    # an authenticated DATA(p) announcing a loopback (from the air), multicast, unspecified or
    # broadcast unicast locator (issue 10, attack 7): refused whole, nothing moves
    BAD_LOCATOR = "bad_locator"
    # a datagram under a prefix outside the bundle while the foreign budget is spent (a
    # flood of forged participants, attack 9): counted, not even decoded
    FOREIGN_BUDGET = "foreign_budget"


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
    # the locators of the DATA(p) it was discovered by, as sent (DDSI-RTPS 8.5.3.1): its
    # metatraffic unicast locators (SPDP replies) and default unicast locators (user data)
    metatraffic_unicast_locators: tuple[Locator, ...]
    default_unicast_locators: tuple[Locator, ...]
    # the peer's boot epoch from its authenticated DATA(p) (swarmd.auth.freshness); None when
    # the engine runs without authentication (simulator, codec tests). The data plane binds
    # its unicast MACs to it: a peer's new life (higher epoch) never accepts old datagrams.
    epoch: int | None = None


@dataclass(frozen=True, slots=True)
class PeerRestarted(Event):
    """A discovered peer's authenticated DATA(p) carries a higher boot epoch: it restarted
    (and forgot us) within its lease, so no ``PeerLost`` came first.

    Whatever the data plane keeps per peer (reader positions, acknowledged sets, replay
    windows, MAC state bound to the old epoch) belongs to its earlier life: reset it.
    Emitted only with authentication (the epoch is signed); the peer stays discovered."""

    name: str
    guid_prefix: GuidPrefix
    epoch: int
    previous_epoch: int


@dataclass(frozen=True, slots=True)
class PeerLocatorsChanged(Event):
    """A discovered peer's authenticated DATA(p) announces other unicast locators (it moved,
    or its address changed): where to send it user data and SPDP replies from now on."""

    name: str
    guid_prefix: GuidPrefix
    metatraffic_unicast_locators: tuple[Locator, ...]
    default_unicast_locators: tuple[Locator, ...]


@dataclass(frozen=True, slots=True)
class PeerRos2Liveness(Event):
    """A discovered peer's relay says which of its drone's ROS 2 participants are alive
    (PID 0x8A06, docs/ros2.md "Node liveness"): reported when it differs from its previous
    DATA(p)'s, and a new life's first one always, after that life's ``PeerRestarted`` (a
    word of a life whose restart is held waits with it). Only ever from a DATA(p) the
    engine accepted: authenticated in the daemon,
    so a forged or replayed change never gets here. ``alive``: a bitmap over that drone's
    ROS 2 participants in bundle order, LSB of byte 0 = the first."""

    name: str
    guid_prefix: GuidPrefix
    alive: bytes


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
    reason: DropReason = DropReason.NOT_IN_BUNDLE
    # new foreign participants not reported one by one since the previous report: a flood of
    # invented prefixes yields about one event a second (``MAX_FOREIGN_REPORTS_PER_S``),
    # each carrying how many it stands for, never one per datagram
    suppressed: int = 0


@dataclass(frozen=True, slots=True)
class PhaseChanged(Event):
    old: Phase
    new: Phase
    reason: str


@dataclass(frozen=True, slots=True)
class PacketDropped(Event):
    """A datagram (or one SPDP sample in it) was ignored; ``reason`` names the counter."""

    reason: DropReason
    source: tuple[str, int]
