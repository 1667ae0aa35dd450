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
  with it, or will be matched again at no cost;
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
``peer_liveness``). Its events are in ``swarmd.ros2.relay_events``.
"""

from __future__ import annotations

import ipaddress
from collections import deque
from typing import Any, Final

from swarmd.bundle.ros2 import (
    VENDOR_EPROSIMA,
    Ros2EndpointKind,
    Ros2Participant,
)
from swarmd.ros2.graph import GraphParticipant
from swarmd.ros2.relay_events import (
    LocalLivenessChanged,
    LocalParticipantHeard,
    RelayEvent,
    RemoteNodeLiveness,
    RemoteParticipantsRelayed,
    UndeclaredEndpoint,
    UnknownParticipantHeard,
)
from swarmd.ros2.relay_spdp import (
    FASTDDS_PROTOCOL_VERSION,
    STATIC_EDP_PROPERTY,
    is_wlp,
    static_edp_properties,
)
from swarmd.ros2.relay_state import LocalNode, RemoteDrone, UnknownParticipant
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import (
    BES_SPDP_ONLY,
    SpdpAlive,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.types import (
    Duration,
    GuidPrefix,
    VendorId,
)

# IPv6 loopback: the nodes' discovery port is bound there only (swarmd.ros2.profile); the
# kernel drops a datagram for ::1 that arrives on any other interface (RFC 4291 2.5.3)
LOOPBACK: Final = "::1"
# outside every RTPS port mapping (7400 + 250 * domain + ...): no participant can take it
DEFAULT_RELAY_PORT: Final = 7399
RENEWALS_PER_LEASE: Final = 4
# unknown prefixes heard on loopback: a local process may invent any number of them
MAX_UNKNOWN_PARTICIPANTS: Final = 16
# undeclared endpoints kept per local participant (a node creating endpoints in a loop)
MAX_UNDECLARED_PER_PARTICIPANT: Final = 32
MAX_EVENTS: Final = 256  # queued events if the owner stops draining
# A starting Fast DDS participant sends its first DATA(p) before it listens: its
# RTPSParticipantImpl::enable() runs BuiltinProtocols::enable() (the first announcement)
# and only then registers its receivers, and a datagram read in between is dropped
# (ReceiverResource::OnDataReceived with no receiver; Fast DDS 3.2). The relay's answer on
# loopback can land in that window (docs/ros2.md, "A late publisher"). Every later
# datagram of the node is sent once it listens, so the relay answers the first
# START_ANSWERS datagrams of each node life, not only the first.
START_ANSWERS: Final = 2
# a local node's lease as the relay keeps it (its SPDP's PID_PARTICIPANT_LEASE_DURATION),
# clamped: a node announcing 0 or years must neither flap nor be alive forever
MIN_NODE_LEASE_S: Final = 1.0
MAX_NODE_LEASE_S: Final = 300.0
# A node back after its own lease ("_heard", docs/ros2.md "A node back after its own lease"):
# its siblings get its dispose once its own DATA(p) has listed its endpoints to them (they
# create them as it starts; the dispose removes only matched writers' numbers) and that list
# has stayed the same this long; at the latest SIBLING_REMATCH_MAX_S after its first DATA(p)
SIBLING_REMATCH_S: Final = 0.5
SIBLING_REMATCH_MAX_S: Final = 3.0
# a node restarting within a quarter of its lease (at most 1 s) of its end may already be
# dropped by its siblings' lease check (their timers are not the relay's): it is handled as
# lapsed, which costs nothing more (the dispose comes later, that is all). A fraction: a
# node claiming the shortest lease must not make every restart one of these
SIBLING_LEASE_SLACK_FRACTION: Final = 0.25
SIBLING_LEASE_SLACK_S: Final = 1.0


def _is_static_edp(name: str) -> bool:
    return STATIC_EDP_PROPERTY.fullmatch(name) is not None


def _lease_slack_s(lease_s: float) -> float:
    return min(SIBLING_LEASE_SLACK_S, SIBLING_LEASE_SLACK_FRACTION * lease_s)


class Ros2Relay:
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
        self._unknown: dict[GuidPrefix, UnknownParticipant] = {}
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
            "undeclared_dropped": 0,
            "tx_spdp": 0,
            "tx_dispose": 0,
            "tx_start_answers": 0,
            "tx_sibling_spdp": 0,
            "tx_sibling_dispose": 0,
            "sibling_dispose_deferred": 0,
            "liveness_unknown_drone": 0,
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
        graph_due = self.graph.get_timer() if self.graph is not None else None
        if graph_due is not None:
            deadlines.append(graph_due)
        return min(deadlines, default=None)

    def alive_bitmap(self) -> bytes:
        """This drone's participants alive (bundle order, LSB of byte 0 = the first)."""
        bits = bytearray((len(self._local) + 7) // 8)
        for i, local in enumerate(self._local.values()):
            if local.alive:
                bits[i // 8] |= 1 << (i % 8)
        return bytes(bits)

    def liveness(self) -> bytes:
        """What swarmd's signed DATA(p) carries for this drone's nodes (PID 0x8A06): the
        alive bitmap, then one octet per participant in bundle order, its restarts modulo
        256 (module docstring, "A restart under the same GUIDs"). A relay that reads only
        the bitmap ignores the octets after it."""
        return self.alive_bitmap() + bytes(local.restarts for local in self._local.values())

    def next_event(self) -> RelayEvent | None:
        return self._events.popleft() if self._events else None

    # ---- discovery's events (authenticated peers) --------------------------------------------

    def peer_discovered(
        self, drone: str, address: str | None, now: float, *, restarted: bool = False
    ) -> None:
        """swarmd's discovery has ``drone`` at ``address``: relay its ROS 2 participants to
        every local one now, and from then on within their lease. ``restarted``: its swarmd
        restarted (the engine's ``PeerRestarted``: a higher epoch in an authenticated
        DATA(p), never anything else): its participants, announced before, are disposed at
        the local nodes and announced again at once, so their readers drop the writer
        proxies of the earlier life (module docstring, "A restart under the same GUIDs")."""
        remote = self._remote_by_drone.get(drone)
        if not remote or address is None:
            return
        known = self._present.get(drone)
        if known is not None and known.address == address and not restarted:
            return
        self._present[drone] = RemoteDrone(drone, address, now)
        again = restarted and known is not None
        self._events.append(RemoteParticipantsRelayed(drone, len(remote), up=True, restarted=again))
        self._send_graph_spdp(None)
        for p in self._alive_remote(drone):
            if again:
                self._send_dispose(p)
            self._send_alive(p, address, now)
            if self.graph is not None:
                self.graph.publish(GuidPrefix(p.guid_prefix), now)
        if self._next_renewal is None:
            self._next_renewal = now + self.period_s

    def peer_lost(self, drone: str, now: float) -> None:
        """swarmd lost ``drone``: dispose its ROS 2 participants at every local node, so
        their writers stop sending to it at once rather than after the lease."""
        if self._present.pop(drone, None) is None:
            return
        remote = self._remote_by_drone.get(drone, [])
        self._events.append(RemoteParticipantsRelayed(drone, len(remote), up=False))
        for p in remote:
            self._send_dispose(p)
        if not self._present:
            self._next_renewal = None

    def peer_liveness(self, drone: str, alive: bytes, now: float) -> None:
        """``drone``'s relay says which of its ROS 2 participants are alive (PID 0x8A06 of
        its swarmd's DATA(p), which the discovery engine accepted: authenticated). A node
        that stopped is disposed (DATA(p[UD])) at every local node, one that is back is
        announced again at once; both only while swarmd has the drone. Bits past the
        drone's participants are ignored, missing ones are "not alive"."""
        remote = self._remote_by_drone.get(drone)
        if not remote:
            self.counters["liveness_unknown_drone"] += 1
            return
        new = tuple(
            i // 8 < len(alive) and bool(alive[i // 8] >> (i % 8) & 1) for i in range(len(remote))
        )
        # the restart counts after the bitmap (a relay that sends none: no restart is seen)
        counted = len(alive) >= (len(remote) + 7) // 8 + len(remote)
        restarts = tuple(alive[(len(remote) + 7) // 8 :][: len(remote)]) if counted else None
        old = self._remote_alive.get(drone, (True,) * len(remote))
        old_restarts = self._remote_restarts.get(drone)
        self._remote_alive[drone] = new
        self._remote_restarts[drone] = restarts
        present = self._present.get(drone)
        for i, (p, was, up) in enumerate(zip(remote, old, new, strict=True)):
            # a new life of a node that was and is alive: its proxies must go (DATA(p[UD]))
            restarted = (
                was
                and up
                and restarts is not None
                and old_restarts is not None
                and restarts[i] != old_restarts[i]
            )
            if was == up and not restarted:
                continue
            self._events.append(RemoteNodeLiveness(drone, p.node.name, up, restarted))
            if restarted:
                self.counters["remote_restarts"] += 1
            if present is None:
                continue  # announced (or not) when swarmd finds the drone
            if up:
                if restarted:
                    self._send_dispose(p)
                self._send_graph_spdp(None)
                self._send_alive(p, present.address, now)
                if self.graph is not None:
                    self.graph.publish(GuidPrefix(p.guid_prefix), now)
            else:
                self._send_dispose(p)

    # ---- queries -----------------------------------------------------------------------------

    def synthesized(self, p: Ros2Participant, address: str) -> SpdpParticipant:
        """The DATA(p) content the relay announces for remote participant ``p``."""
        return SpdpParticipant(
            GuidPrefix(p.guid_prefix),
            protocol_version=FASTDDS_PROTOCOL_VERSION,
            vendor_id=VendorId(VENDOR_EPROSIMA),
            domain_id=self.domain_id,
            metatraffic_unicast_locators=(self._relay_locator,),
            default_unicast_locators=(Locator.udpv4(address, p.user_port),),
            lease_duration=Duration.from_seconds(self.lease_s),
            builtin_endpoints=BES_SPDP_ONLY,
            entity_name="/",  # rclpy names its participant after the enclave
            properties=static_edp_properties(p),
        )

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
                        for kind, uid, entity in sorted(local.undeclared or ())
                    ],
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

    # ---- internals ---------------------------------------------------------------------------

    def _next_sn(self) -> int:
        self._sn += 1
        return self._sn

    def _send_alive(self, p: Ros2Participant, address: str, now: float) -> None:
        del now  # INFO_TS left invalid: Fast DDS does not need a source timestamp for SPDP
        datagram = encode_spdp(
            self.synthesized(p, address), sequence_number=self._next_sn(), timestamp=None
        )
        for local in self._local.values():
            self._out.append((datagram, (self.loopback, local.participant.metatraffic_port)))
            self.counters["tx_spdp"] += 1

    def _send_graph_spdp(self, local: LocalNode | None) -> None:
        """swarmd's graph participant's DATA(p) to ``local`` (None: every local node)."""
        if self.graph is None:
            return
        datagram = encode_spdp(self.graph.spdp(), sequence_number=self._next_sn(), timestamp=None)
        targets = self._local.values() if local is None else (local,)
        for target in targets:
            self._out.append((datagram, (self.loopback, target.participant.metatraffic_port)))
            self.counters["tx_spdp"] += 1

    def _send_all_to(self, local: LocalNode) -> None:
        port = local.participant.metatraffic_port
        if self._present:
            self._send_graph_spdp(local)
        for drone, present in self._present.items():
            for p in self._alive_remote(drone):
                datagram = encode_spdp(
                    self.synthesized(p, present.address),
                    sequence_number=self._next_sn(),
                    timestamp=None,
                )
                self._out.append((datagram, (self.loopback, port)))
                self.counters["tx_spdp"] += 1

    def _send_siblings_to(self, local: LocalNode) -> None:
        """The other alive nodes of this drone, to a starting ``local``: their own latest
        DATA(p), as they sent it. They are its initial peers and answer its first DATA(p)
        themselves, within milliseconds, which can land before the starting node listens
        (as the relay's answer can: module docstring, START_ANSWERS); it would then take
        them only from their next periodic DATA(p), seconds later (docs/ros2.md, "Several
        nodes on one drone"). Nothing from the air: a loopback node's words, which it sends
        that node's port anyway."""
        port = local.participant.metatraffic_port
        for sibling in self._local.values():
            if sibling is local or not sibling.alive or sibling.left:
                continue
            if sibling.last_spdp is not None:
                self._out.append((sibling.last_spdp, (self.loopback, port)))
                self.counters["tx_sibling_spdp"] += 1

    def _send_dispose_to_siblings(self, local: LocalNode, datagram: bytes | None) -> None:
        """``local`` started again without having sent its ``DATA(p[UD])`` (SIGKILL, a
        crash): the other alive nodes of this drone, which find it directly on [::1],
        still hold the writer proxies of its earlier life (module docstring, "A restart
        under the same GUIDs"), and their SPDP readers drop its new DATA(p) too (numbered
        from 1 again). They get its DATA(p[UD]), numbered above everything (the relay's
        epoch), then ``datagram``, its own latest DATA(p) as it sent it: Fast DDS forgets a
        writer's numbers when its participant is disposed (not when its lease runs out)."""
        siblings = self._siblings_of(local)
        if not siblings:
            return
        dispose = encode_spdp_dispose(
            GuidPrefix(local.participant.guid_prefix),
            sequence_number=self._next_sn(),
            timestamp=None,
            vendor_id=VendorId(VENDOR_EPROSIMA),
            protocol_version=FASTDDS_PROTOCOL_VERSION,
        )
        for sibling in siblings:
            port = sibling.participant.metatraffic_port
            self._out.append((dispose, (self.loopback, port)))
            self.counters["tx_sibling_dispose"] += 1
            if datagram is not None:
                self._out.append((datagram, (self.loopback, port)))
                self.counters["tx_sibling_spdp"] += 1

    def _siblings_of(self, local: LocalNode) -> list[LocalNode]:
        return [s for s in self._local.values() if s is not local and s.alive and not s.left]

    def _alive_remote(self, drone: str) -> list[Ros2Participant]:
        remote = self._remote_by_drone.get(drone, [])
        alive = self._remote_alive.get(drone)
        if alive is None:
            return remote
        return [p for p, up in zip(remote, alive, strict=True) if up]

    def _send_dispose(self, p: Ros2Participant) -> None:
        if self.graph is not None:
            self.graph.withdraw(GuidPrefix(p.guid_prefix))
        datagram = encode_spdp_dispose(
            GuidPrefix(p.guid_prefix),
            sequence_number=self._next_sn(),
            timestamp=None,
            vendor_id=VendorId(VENDOR_EPROSIMA),
            protocol_version=FASTDDS_PROTOCOL_VERSION,
        )
        for local in self._local.values():
            self._out.append((datagram, (self.loopback, local.participant.metatraffic_port)))
            self.counters["tx_dispose"] += 1

    def _set_local_alive(self, local: LocalNode, alive: bool, restarted: bool = False) -> None:
        if not alive:
            local.alive_until = None
            local.last_spdp = None
            local.sibling_dispose_at = None
        if local.alive == alive and not restarted:
            return
        local.alive = alive
        p = local.participant
        self._events.append(LocalLivenessChanged(self.liveness(), p.node.name, alive))

    def _renew_all(self, now: float) -> None:
        if self._present:
            self._send_graph_spdp(None)
        for drone, present in self._present.items():
            for p in self._alive_remote(drone):
                self._send_alive(p, present.address, now)
        self._next_renewal = now + self.period_s if self._present else None

    def _heard(self, sample: SpdpAlive, now: float, datagram: bytes | None = None) -> None:
        """``datagram``: the whole datagram when it is this one DATA(p), to everyone, under
        the participant's own header (kept to pass on to a starting sibling)."""
        participant = sample.participant
        prefix = participant.guid_prefix
        local = self._local.get(prefix)
        if local is None:
            if prefix in self._remote_prefixes:
                # a remote drone's participant cannot speak on this drone's loopback
                self.counters["rx_remote_prefix"] += 1
            else:
                self._heard_unknown(participant, now)
            return
        # a smaller sequence number than before: the node restarted (Fast DDS starts at 1)
        restarted = local.heard_at is not None and (
            local.left or sample.sequence_number < local.last_sn
        )
        first = local.heard_at is None or restarted
        # a new life without its DATA(p[UD]) (killed): its siblings still hold its proxies
        unannounced_restart = restarted and not local.left
        # ... or, silent past its lease (by the relay's book, with slack), dropped it by lease
        lapsed = unannounced_restart and (
            local.alive_until is None
            or local.heard_at is None
            or now >= local.alive_until - _lease_slack_s(local.alive_until - local.heard_at)
        )
        if restarted:
            # a new life under the same GUIDs: counted in the signed liveness word, so the
            # other drones' relays drop its old proxies even if its bit never went down
            local.restarts = (local.restarts + 1) & 0xFF
        local.left = False
        local.heard_at = now
        lease = min(
            max(participant.lease_duration.total_seconds(), MIN_NODE_LEASE_S), MAX_NODE_LEASE_S
        )
        local.alive_until = now + lease
        self._set_local_alive(local, True, restarted)
        local.last_sn = sample.sequence_number
        local.datagrams += 1
        if datagram is not None:
            local.last_spdp = datagram
        self._check_endpoints(local, participant)
        static_edp = frozenset(n for n, _v in participant.properties if _is_static_edp(n))
        if static_edp != local.static_edp and local.sibling_dispose_at is not None:
            local.sibling_dispose_at = min(now + SIBLING_REMATCH_S, local.sibling_dispose_by)
        local.static_edp = static_edp
        if first:
            p = local.participant
            self._events.append(LocalParticipantHeard(p.drone, p.node.name, prefix, restarted))
            local.answers_left = START_ANSWERS
            if self.graph is not None:
                self.graph.local_restarted(prefix, now)
            local.sibling_dispose_at = None
            if lapsed and self._siblings_of(local):
                # its siblings dropped it by lease, which keeps its writers' last numbers
                # (Fast DDS 3.2 BaseReader::remove_persistence_guid erases the record only
                # when not removed by lease), and a dispose of a participant they do not
                # know removes nothing: they re-create it from its own DATA(p) (the lease
                # drop erased its SPDP writer's record, so they take them) and match its
                # writers from the kept record; the dispose, once that list is quiet,
                # removes them not by lease. Nothing of its is sent before: numbered above
                # its own, it would make their SPDP reader drop the DATA(p)s that list its
                # endpoints (StatelessReader::change_received records a matched SPDP writer's
                # number), and the dispose would find no writer to remove
                local.sibling_dispose_at = now + SIBLING_REMATCH_S
                local.sibling_dispose_by = now + SIBLING_REMATCH_MAX_S
                self.counters["sibling_dispose_deferred"] += 1
            elif unannounced_restart:
                self._send_dispose_to_siblings(local, datagram)
        if local.answers_left > 0:
            local.answers_left -= 1
            self.counters["tx_start_answers"] += 1
            self._send_all_to(local)
            self._send_siblings_to(local)

    def _left(self, prefix: GuidPrefix) -> None:
        """A local node's DATA(p[UD]) (it is shutting down): shown as left; its next
        announcement is a restart and gets every relayed participant at once."""
        self.counters["rx_dispose"] += 1
        local = self._local.get(prefix)
        if local is not None:
            local.left = True
            local.last_spdp = None
            self._set_local_alive(local, False)

    def _heard_unknown(self, participant: SpdpParticipant, now: float) -> None:
        self.counters["rx_unknown"] += 1
        prefix = participant.guid_prefix
        row = self._unknown.get(prefix)
        if row is not None:
            row.heard_at = now
            row.datagrams += 1
            return
        if len(self._unknown) >= MAX_UNKNOWN_PARTICIPANTS:
            oldest = min(self._unknown.values(), key=lambda u: u.heard_at)
            del self._unknown[oldest.guid_prefix]
            self.counters["unknown_evicted"] += 1
        vendor = participant.vendor_id.value.hex()
        self._unknown[prefix] = UnknownParticipant(prefix, vendor, participant.entity_name, now, 1)
        self._events.append(UnknownParticipantHeard(prefix, vendor, participant.entity_name))

    def _check_endpoints(self, local: LocalNode, participant: SpdpParticipant) -> None:
        for name, value in participant.properties:
            m = STATIC_EDP_PROPERTY.fullmatch(name)
            if m is None:
                continue
            kind, uid = m.group(1), int(m.group(2))
            if (kind, uid) in local.declared:
                continue
            undeclared = local.undeclared if local.undeclared is not None else set()
            local.undeclared = undeclared
            key = (kind, uid, value[:32])
            if key in undeclared:
                continue
            if len(undeclared) >= MAX_UNDECLARED_PER_PARTICIPANT:
                self.counters["undeclared_dropped"] += 1
                continue
            undeclared.add(key)
            p = local.participant
            self._events.append(UndeclaredEndpoint(p.drone, p.node.name, kind.lower(), uid, key[2]))
