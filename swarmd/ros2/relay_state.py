"""The SPDP relay's rows (swarmd.ros2.relay): what it keeps per local node of its drone,
per unknown participant heard on loopback, and per remote drone swarmd found. Plain data;
the relay core moves them."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.bundle.ros2 import Ros2Participant
from swarmd.rtps.types import GuidPrefix


@dataclass(slots=True)
class LocalNode:
    participant: Ros2Participant
    declared: frozenset[tuple[str, int]]  # ("Writer"|"Reader", userId)
    heard_at: float | None = None
    left: bool = False  # its last word was a DATA(p[UD])
    last_sn: int = 0
    datagrams: int = 0
    answers_left: int = 0  # datagrams of this life still answered with everything relayed
    # alive as swarmd tells the other drones: heard within its lease, or (never heard) within
    # one relay lease of the relay's start; None: no expiry (left, expired, or not started)
    alive: bool = True
    alive_until: float | None = None
    restarts: int = 0  # lives after the first this relay saw, modulo 256 (PID 0x8A06)
    # (kind, uid, entity id) of its latest DATA(p) (relay_local ``_check_endpoints``): nodes
    # without ids all say 65535, their entity ids differ; and how many more it listed
    undeclared: tuple[tuple[str, int, str], ...] = ()
    undeclared_not_kept: int = 0
    # its latest DATA(p) datagram as it sent it (to everyone, its own header): passed on to
    # a sibling node of this drone that starts, with the relay's start answers
    last_spdp: bytes | None = None
    # the static EDP property names of its latest DATA(p) (the endpoints it has created)
    static_edp: frozenset[str] = frozenset()
    # a new life after its lease ran out: when its siblings get its dispose (the endpoint
    # list quiet for SIBLING_REMATCH_S), and the latest that may be (SIBLING_REMATCH_MAX_S
    # after the life's first DATA(p)); None: none pending ("Ros2Relay._heard")
    sibling_dispose_at: float | None = None
    sibling_dispose_by: float = 0.0


@dataclass(slots=True)
class UnknownParticipant:
    guid_prefix: GuidPrefix
    vendor: str
    name: str | None
    heard_at: float
    datagrams: int


@dataclass(slots=True)
class RemoteDrone:
    drone: str
    address: str
    since: float
