"""swarmd serves SPDP to its drone's stock ROS 2 nodes on loopback (issue 19, docs/ros2.md).

Theory of operation. A ROS 2 node started with a ``swarmctl ros2 profile --via-swarmd``
profile has its metatraffic (discovery) locator on IPv6 loopback (a UDPv6 transport allowed
on ``::1`` only: swarmd.ros2.profile) and one initial peer: this relay's socket,
[::1]:``relay_port``. Its SPDP therefore never leaves the drone. The
relay, in turn, sends each local ROS 2 participant (at [::1]:<its metatraffic port>,
from the bundle) a synthesized SPDP ``DATA(p)`` (DDSI-RTPS 2.5 8.5.3.2, 9.6.2.2) for every
ROS 2 participant the bundle places on a drone that swarmd's own, authenticated discovery has
found (``peer_discovered``):

- the bundle's GUID prefix and eProsima's vendor id (the remote node is stock Fast DDS);
- default unicast locator = the peer's address (from swarmd's discovery) + the bundle's user
  port: user data goes straight over the Wi-Fi, node to node;
- metatraffic unicast locator = this relay on loopback: whatever the local node sends to the
  remote participant's discovery side (its own SPDP renewals, WLP, ...) stays on the drone;
- builtin endpoints = SPDP writer and reader only (availableBuiltinEndpoints, DDSI-RTPS
  2.5 8.5.3.2): with no SEDP and no WLP endpoint announced, the local node starts neither
  for it (measured: the relays receive 0 WLP, docs/ros2.md);
- the remote node's static EDP endpoints as Fast DDS's ``EDPStatic`` announces them in the
  property list (``eProsimaEDPStatic_<Writer|Reader>_ALIVE_ID_<userId>`` = its entity id),
  built from the bundle: the profile gives every endpoint ``entityID`` = ``userDefinedID``,
  so the entity ids are known beforehand (checked against real SPDP, docs/ros2.md).

Renewed every ``lease_s / RENEWALS_PER_LEASE`` within the lease it announces, resent at once
to a local participant heard for the first time (a node start, or a restart: its sequence
numbers start again, or it sent a ``DATA(p[UD])`` before), and disposed
(``DATA(p[UD])``, 8.5.3.2) on ``peer_lost``. Sequence numbers carry swarmd's boot epoch in
their upper half: a node that matched the SPDP writer of a relayed participant drops samples
whose sequence number is not above the last one it took, so a restarted swarmd must count on
from above its earlier life.

A restart under the same GUIDs. The bundle fixes every node's GUID prefix and entity ids, so
a node that restarts has the writers of its earlier life, numbering their samples from 1
again, and a remote node's reader that still holds their writer proxies drops every sample
numbered at or below the last one it took (DDSI-RTPS 2.5 8.4.12, the reliable
StatefulReader: its writer proxy keeps the highest sequence number received): the new life
is silent until it outnumbers the old. The
proxies must go: the relay sends the local nodes the participant's ``DATA(p[UD])`` and, at
once after it, its ``DATA(p)`` again (Fast DDS removes the participant and its endpoint
proxies on the dispose, and matches the announcement afresh). It does so for

- a drone whose swarmd restarted (``peer_discovered(restarted=True)``: the engine's
  ``PeerRestarted``, a higher boot epoch in an authenticated DATA(p)): its nodes restarted
  with it, or will be matched again at no cost. Its relay restarted too, so its liveness
  word starts afresh: the new life's first word is the baseline, not restarts of its
  nodes (``relay_remote``, ``_new_life``);
- a node of another drone that restarted under a running swarmd: that drone's relay saw it
  (a smaller SPDP sequence number, or a ``DATA(p[UD])`` before) and counts the node's lives
  in the liveness word its swarmd signs (PID 0x8A06: the alive bitmap, then one octet per
  participant, its restarts modulo 256); a changed count for a node that stayed alive is
  the restart (``peer_liveness``). The count survives a lost DATA(p): any later one carries it.

On the node's own drone its sibling nodes, which find it directly, hold its old proxies too:
a node's new life without its ``DATA(p[UD])`` first is disposed at them, then its own new
DATA(p) passed on (``_send_dispose_to_siblings``); at once, or, for a node that was silent
past its lease (they dropped it by lease, which keeps its old numbers), once its own DATA(p)
has listed its endpoints to them and the list stayed the same ``SIBLING_REMATCH_S``.

Several nodes on one drone find each other directly: each one's profile lists the others'
[::1] discovery ports as initial peers. The relay only helps a starting one: with its start
answers it passes on the other alive nodes' own latest DATA(p) (the answers they send it
themselves can arrive before it listens, as the relay's can).

Trust. Nothing the relay sends comes from the air: only from the signed bundle and
``peer_discovered`` (an authenticated peer), and, to a starting node of this drone, the
DATA(p) its sibling nodes on loopback sent (what they send that node's port anyway). What
local nodes send it is otherwise read to show operators what runs (heard, matched to the
bundle, unknown) and which endpoints a node has that the bundle does not hold, and to keep
this drone's liveness word (alive, restarts) and its siblings' view of a restarted node;
none of it goes to another drone but that word, in swarmd's signed DATA(p). Which local
process sent a datagram is the kernel's word (its socket's owner uid, swarmd.senderuid):
with ``node_uids`` (``ros2.node_users``) only those users' datagrams are read. Bad datagrams
are counted and dropped; ``receive_datagram`` raises nothing.

Driving sources: datagrams from the relay socket (``receive_datagram``), the timer
(``handle_timer``), and the daemon's discovery events (``peer_discovered``/``peer_lost``/
``peer_liveness``). Its events are in ``swarmd.ros2.relay_events``. The class is split by
concern (at 782 lines): what it announces (``relay_announce.Announcer``, which also declares
the state they share), what its drone's nodes send it (``relay_local.LocalNodes``: lives,
liveness word, start answers, siblings, unknown participants), and discovery's events
(``relay_remote.RemoteDrones``); this module keeps the driving protocol and the status.
"""

from __future__ import annotations

import ipaddress
from collections import deque
from typing import Any, Final

from swarmd.bundle.ros2 import Ros2EndpointKind, Ros2Participant
from swarmd.lives import LifeDamping
from swarmd.ros2.graph import GraphParticipant
from swarmd.ros2.relay_events import RelayEvent
from swarmd.ros2.relay_local import (
    MAX_NODE_LEASE_S,
    MAX_UNDECLARED_PER_PARTICIPANT,
    MAX_UNKNOWN_PARTICIPANTS,
    MIN_NODE_LEASE_S,
    SIBLING_LEASE_SLACK_FRACTION,
    SIBLING_LEASE_SLACK_S,
    SIBLING_REMATCH_MAX_S,
    SIBLING_REMATCH_S,
    START_ANSWERS,
    UNKNOWN_REPORT_BURST,
    UNKNOWN_REPORTS_PER_S,
    LocalNodes,
)
from swarmd.ros2.relay_remote import LIVENESS_MIN_INTERVAL_S, RemoteDrones
from swarmd.ros2.relay_spdp import is_wlp
from swarmd.ros2.relay_state import LocalNode, RemoteDrone, UnknownParticipant
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpAlive, decode_spdp
from swarmd.rtps.types import GuidPrefix
from swarmd.tokenbucket import TokenBucket

__all__ = [  # the bounds live with the concern they bound; tests and docs name them here
    "DEFAULT_RELAY_PORT",
    "LIVENESS_MIN_INTERVAL_S",
    "LOOPBACK",
    "MAX_EVENTS",
    "MAX_NODE_LEASE_S",
    "MAX_UNDECLARED_PER_PARTICIPANT",
    "MAX_UNKNOWN_PARTICIPANTS",
    "MIN_NODE_LEASE_S",
    "RENEWALS_PER_LEASE",
    "SIBLING_LEASE_SLACK_FRACTION",
    "SIBLING_LEASE_SLACK_S",
    "SIBLING_REMATCH_MAX_S",
    "SIBLING_REMATCH_S",
    "START_ANSWERS",
    "UNKNOWN_REPORTS_PER_S",
    "UNKNOWN_REPORT_BURST",
    "Ros2Relay",
]

# IPv6 loopback: the nodes' discovery port is bound there only (swarmd.ros2.profile); the
# kernel drops a datagram for ::1 that arrives on any other interface (RFC 4291 2.5.3)
LOOPBACK: Final = "::1"
# outside every RTPS port mapping (7400 + 250 * domain + ...): no participant can take it
DEFAULT_RELAY_PORT: Final = 7399
RENEWALS_PER_LEASE: Final = 4
MAX_EVENTS: Final = 256  # queued events if the owner stops draining


class Ros2Relay(LocalNodes, RemoteDrones):
    """The SPDP relay core of one drone (see the module docstring); sans-IO.

    Datagrams out are ``(bytes, (host, port))``, always to ``loopback``."""

    def __init__(
        self,
        participants: tuple[Ros2Participant, ...],
        drone: str,
        *,
        domain_id: int,
        lease_s: float,
        relay_port: int = DEFAULT_RELAY_PORT,
        epoch: int = 0,
        loopback: str = LOOPBACK,
        graph_prefix: GuidPrefix | None = None,
        node_uids: frozenset[int] | None = None,
    ) -> None:
        """``graph_prefix``: the GUID prefix of swarmd's graph participant (drawn at random
        by the caller, swarmd.ros2.graph); None serves no node names. ``node_uids``: the
        local users allowed to be this drone's ROS 2 nodes (``ros2.node_users``): a
        datagram whose sender's uid (``receive_datagram``'s ``sender_uid``) is not one of
        them is dropped before it is read; None: every local sender is taken (the nodes'
        and any other local process's words look the same)."""
        if lease_s <= 0:
            raise ValueError("ros2 relay lease must be positive")
        self.drone = drone
        self.node_uids = node_uids
        self.domain_id = domain_id
        self.lease_s = lease_s
        self.period_s = lease_s / RENEWALS_PER_LEASE
        self.relay_port = relay_port
        self.loopback = loopback
        self._relay_locator = (
            Locator.udpv6(loopback, relay_port)
            if ipaddress.ip_address(loopback).version == 6
            else Locator.udpv4(loopback, relay_port)
        )
        # SN = epoch (31 bits) | counter: above every SN of an earlier life of this relay
        self._sn = (epoch & 0x7FFF_FFFF) << 32
        self._local: dict[GuidPrefix, LocalNode] = {}
        self._remote_by_drone: dict[str, list[Ros2Participant]] = {}
        for p in participants:
            if p.drone == drone:
                declared = frozenset(
                    (
                        "Writer" if e.kind == Ros2EndpointKind.WRITER else "Reader",
                        p.first_user_id + i,
                    )
                    for i, e in enumerate(p.endpoints)
                )
                self._local[GuidPrefix(p.guid_prefix)] = LocalNode(p, declared)
            else:
                self._remote_by_drone.setdefault(p.drone, []).append(p)
        self._remote_prefixes = frozenset(
            GuidPrefix(p.guid_prefix) for ps in self._remote_by_drone.values() for p in ps
        )
        self._present: dict[str, RemoteDrone] = {}
        # per drone, its relay's last authenticated word on its participants (absent: all
        # alive, as a peer without a relay or before its first word)
        self._remote_alive: dict[str, tuple[bool, ...]] = {}
        # per drone, the restart counts of its last word (absent or None: it sent none)
        self._remote_restarts: dict[str, tuple[int, ...] | None] = {}
        # per drone, when its word last moved a node here, and the word held since (changes
        # within LIVENESS_MIN_INTERVAL_S: relay_remote); bundle drones only
        self._liveness_acted: dict[str, float] = {}
        self._liveness_held: dict[str, bytes] = {}
        # the lives their words brought, damped per drone (relay_remote, swarmd.lives)
        self._liveness_lives = LifeDamping()
        self._drone_index = {d: i for i, d in enumerate(self._remote_by_drone)}
        self._unknown: dict[GuidPrefix, UnknownParticipant] = {}
        # their reports, at a bounded rate (a local flood of invented prefixes: relay_local)
        self._unknown_reports = TokenBucket(UNKNOWN_REPORTS_PER_S, UNKNOWN_REPORT_BURST, 0.0)
        self._unknown_suppressed = 0
        self._out: list[tuple[bytes, tuple[str, int]]] = []
        self._events: deque[RelayEvent] = deque(maxlen=MAX_EVENTS)
        self._next_renewal: float | None = None
        self.graph: GraphParticipant | None = None
        if graph_prefix is not None:
            graph = GraphParticipant(
                participants,
                drone,
                prefix=graph_prefix,
                relay_locator=self._relay_locator,
                domain_id=domain_id,
                lease_s=lease_s,
                epoch=epoch,
            )
            self.graph = graph if graph.enabled else None
        self.counters: dict[str, int] = {
            "rx": 0,
            "rx_malformed": 0,
            "rx_foreign_user": 0,
            "rx_not_spdp": 0,
            "rx_wlp": 0,
            "rx_dispose": 0,
            "rx_remote_prefix": 0,
            "rx_unknown": 0,
            "unknown_evicted": 0,
            "unknown_suppressed": 0,
            "undeclared_dropped": 0,
            "tx_spdp": 0,
            "tx_dispose": 0,
            "tx_start_answers": 0,
            "tx_sibling_spdp": 0,
            "tx_sibling_dispose": 0,
            "sibling_dispose_deferred": 0,
            "liveness_unknown_drone": 0,
            "remote_liveness_held": 0,
            "remote_liveness_damped": 0,
            "remote_restarts": 0,
        }

    # ---- the driving protocol ----------------------------------------------------------------

    def receive_datagram(
        self, data: bytes, source: Any, now: float, sender_uid: int | None = None
    ) -> None:
        """An SPDP datagram a local ROS 2 participant sent the relay. Never raises.

        ``sender_uid``: the local user whose socket sent it (the adapter reads it from the
        kernel's socket table: swarmd.senderuid), None when unknown (the socket is gone,
        or two users hold its port). With ``node_uids`` set, anything else than a node
        user's datagram is counted (``rx_foreign_user``) and dropped unread: a local
        process of another user cannot speak as a declared node (its prefix is no
        secret), nor reach the graph writer (docs/security.md, "ROS 2 nodes and the relay")."""
        self.counters["rx"] += 1
        if self.node_uids is not None and sender_uid not in self.node_uids:
            self.counters["rx_foreign_user"] += 1
            return
        try:
            header, samples = decode_spdp(data)
        except DecodeError:
            self.counters["rx_malformed"] += 1
            return
        if not samples:
            if self.graph is not None and self.graph.receive_datagram(data, now):
                return  # an ACKNACK to swarmd's graph writer
            # what else a node sends its peers' discovery side: WLP (DDSI-RTPS 8.4.13) if
            # a relayed participant announced a WLP reader (it does not), else anything
            self.counters["rx_wlp" if is_wlp(data) else "rx_not_spdp"] += 1
            return
        for sample in samples:
            if isinstance(sample, SpdpAlive):
                own = (
                    len(samples) == 1
                    and sample.destination is None
                    and header.guid_prefix == sample.participant.guid_prefix
                )
                self._heard(sample, now, data if own else None)
            else:
                self._left(sample.guid_prefix)

    def started(self, now: float) -> None:
        """The relay's socket is up: a node not heard within one relay lease from now is
        taken as stopped (its peers on other drones are told through swarmd)."""
        for local in self._local.values():
            if local.heard_at is None and local.alive:
                local.alive_until = now + self.lease_s

    def handle_timer(self, now: float) -> None:
        for local in self._local.values():
            # first: a dispose due before the node's lease ran out is still owed
            if local.sibling_dispose_at is not None and now >= local.sibling_dispose_at:
                local.sibling_dispose_at = None
                self._send_dispose_to_siblings(local, local.last_spdp)
            if local.alive and local.alive_until is not None and now >= local.alive_until:
                self._set_local_alive(local, False)
        self.release_liveness(now)
        if self._next_renewal is not None and now >= self._next_renewal:
            self._renew_all(now)
        if self.graph is not None:
            self.graph.handle_timer(now)

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        out, self._out = self._out, []
        if self.graph is not None:
            out += self.graph.datagrams_to_send()
        return out

    def get_timer(self) -> float | None:
        deadlines = [u.alive_until for u in self._local.values() if u.alive_until is not None]
        deadlines += [
            u.sibling_dispose_at for u in self._local.values() if u.sibling_dispose_at is not None
        ]
        if self._next_renewal is not None:
            deadlines.append(self._next_renewal)
        held_due = self.liveness_due()
        if held_due is not None:
            deadlines.append(held_due)
        graph_due = self.graph.get_timer() if self.graph is not None else None
        if graph_due is not None:
            deadlines.append(graph_due)
        return min(deadlines, default=None)

    def next_event(self) -> RelayEvent | None:
        return self._events.popleft() if self._events else None

    # ---- discovery's events (authenticated peers): RemoteDrones (swarmd.ros2.relay_remote);
    # ---- what the local nodes send: LocalNodes (swarmd.ros2.relay_local);
    # ---- the announcements: Announcer (swarmd.ros2.relay_announce)

    # ---- queries -----------------------------------------------------------------------------

    def status(self, now: float) -> dict[str, Any]:
        """Rows for ``swarmctl status`` (docs/operations.md, ``ros2``)."""
        local_rows = []
        for prefix, local in self._local.items():
            p = local.participant
            local_rows.append(
                {
                    "node": p.node.name,
                    "guid_prefix": str(prefix),
                    "metatraffic": f"{self.loopback}:{p.metatraffic_port}",
                    "state": "not heard"
                    if local.heard_at is None
                    else "left"
                    if local.left
                    else "heard"
                    if local.alive
                    else "lease expired",
                    "alive": local.alive,
                    "restarts": local.restarts,
                    "last_heard_s": None
                    if local.heard_at is None
                    else round(now - local.heard_at, 3),
                    "undeclared_endpoints": [
                        {"kind": kind.lower(), "user_id": uid, "entity_id": entity}
                        for kind, uid, entity in local.undeclared
                    ],
                    "undeclared_not_shown": local.undeclared_not_kept,
                }
            )
        remote_rows = []
        for drone, ps in self._remote_by_drone.items():
            present = self._present.get(drone)
            alive = self._remote_alive.get(drone, (True,) * len(ps))
            for p, up in zip(ps, alive, strict=True):
                remote_rows.append(
                    {
                        "drone": drone,
                        "node": p.node.name,
                        "guid_prefix": str(GuidPrefix(p.guid_prefix)),
                        "state": "waiting for drone"
                        if present is None
                        else "relayed"
                        if up
                        else "node stopped",
                        "user_locator": None
                        if present is None
                        else f"{present.address}:{p.user_port}",
                    }
                )
        return {
            "relay": f"{self.loopback}:{self.relay_port}",
            "lease_s": self.lease_s,
            "alive_bitmap": self.alive_bitmap().hex(),
            "local": local_rows,
            "remote": remote_rows,
            "unknown": [
                {
                    "guid_prefix": str(u.guid_prefix),
                    "vendor": u.vendor,
                    "name": u.name,
                    "last_heard_s": round(now - u.heard_at, 3),
                    "datagrams": u.datagrams,
                }
                for u in self._unknown.values()
            ],
            "counters": dict(self.counters)
            | (self.graph.counters if self.graph is not None else {}),
            "graph": self.graph.status() if self.graph is not None else None,
        }
