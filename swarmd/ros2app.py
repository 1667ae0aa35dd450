"""The ROS 2 relay's wiring (daemon tier): its [::1] socket, its ``Driver``, its log lines.

``swarmd.ros2.relay.Ros2Relay`` is the sans-IO core (docs/ros2.md); this module is its one
adapter, as ``swarmapp.py`` is the swarm core's. The daemon makes one ``Ros2App`` when
``ros2.relay`` is set, hands it discovery's authenticated peers (``peer_up`` on
``PeerDiscovered``, ``PeerRestarted`` and ``PeerLocatorsChanged``, ``peer_down`` on
``PeerLost``) and adds ``status`` to its own.

The socket is bound on ``[::1]`` only: the kernel drops a datagram for ``::1`` arriving on
the Wi-Fi interface, so nothing from the air reaches the relay (docs/security.md, "ROS 2
nodes and the relay").
"""

from __future__ import annotations

import asyncio
import secrets
import socket
from collections.abc import Callable
from typing import Any, Final

from swarmd.bundle.model import Bundle
from swarmd.bundle.ros2 import Ros2Graph, Ros2Participant, bundle_ros2_participants
from swarmd.changereports import LineBudget
from swarmd.config import DaemonConfig
from swarmd.driver import Driver
from swarmd.exitcodes import EX_OSERR, StartupError
from swarmd.ros2.graph import GRAPH_PREFIX_RANDOM_BYTES, LOOPBACK4, graph_participant_prefix
from swarmd.ros2.relay import (
    LOOPBACK,
    Ros2Relay,
)
from swarmd.ros2.relay_events import (
    LocalLivenessChanged,
    LocalParticipantHeard,
    RelayEvent,
    RemoteNodeLiveness,
    RemoteParticipantsRelayed,
    UndeclaredEndpoint,
    UnknownParticipantHeard,
)
from swarmd.senderuid import SenderUids, log_firewall_expected
from swarmd.udp import BatchedSocket, Datagram

# The relay's lines about what others make happen: a peer's node stopped, back or restarted
# (``ros2_remote_node_liveness``), a peer served at a new address (``ros2_relay_peer``), a
# local node's new life (``ros2_participant_heard``, ``ros2_node_liveness``) and its
# undeclared endpoints (``ros2_undeclared_endpoint``, review 18b). A captured
# member's signed DATA(p)s flip its word and move it at its verification budget (20 a second,
# 4 samples each), and a local process of any user (``ros2.node_users`` unset) cycles a
# declared node's lives as fast as it sends: one line each was a flood that journald's
# per-unit rate limit answers by dropping the daemon's other lines too (review 18; the
# daemon's own lines for the same changes: swarmd.daemon_events). At most this many a
# second per peer or node and kind, burst 10 (a drone's nodes starting together), the next
# line saying how many were held back; counted ``lines_suppressed``. What the relay does
# is not held: it still disposes and announces, and signs every life.
RELAY_LINES_PER_S: Final = 1.0
RELAY_LINE_BURST: Final = 10.0


def require_ros2_graph(
    config: DaemonConfig, bundle: Bundle
) -> tuple[Ros2Graph, tuple[Ros2Participant, ...]]:
    """The bundle's ROS 2 graph and participants; ``ConfigError`` (one line, at
    ``ros2.relay``) when it declares none to serve. ``swarmd check-config`` runs it too
    (Daemon.check_start)."""
    participants = bundle_ros2_participants(bundle)
    if not participants or bundle.ros2 is None:
        raise config.error(
            "ros2.relay",
            "the bundle declares no ROS 2 graph to serve",
            "add a 'ros2:' section to the mission (docs/ros2.md) or set ros2.relay: false",
        )
    return bundle.ros2, participants


class Ros2App:
    """The relay core, its socket and its driver, for one daemon."""

    def __init__(
        self,
        config: DaemonConfig,
        bundle: Bundle,
        *,
        epoch: int,
        log: Any,
        count: Callable[[str], None],
        on_liveness: Callable[[bytes], None] | None = None,
        sender_uids: SenderUids | None = None,
    ) -> None:
        """``on_liveness``: called with the relay's new alive bitmap when one of this
        drone's nodes comes or goes (the daemon puts it in its signed DATA(p))."""
        """Raises ``ConfigError`` (one line, at ``ros2.relay``) for a bundle with no ROS 2
        graph."""
        graph, participants = require_ros2_graph(config, bundle)
        self.config = config
        self.log = log
        self.count = count
        self.on_liveness = on_liveness
        self.relay = Ros2Relay(
            participants,
            config.node,
            domain_id=graph.domain_id,
            lease_s=config.ros2.lease_s,
            relay_port=config.ros2.relay_port,
            epoch=epoch,
            # the graph writer's GUID is a secret of this drone (swarmd.ros2.graph, "Trust")
            graph_prefix=graph_participant_prefix(secrets.token_bytes(GRAPH_PREFIX_RANDOM_BYTES)),
            node_uids=config.ros2.node_users,
        )
        # who sent a datagram (its socket's uid): looked up only when the relay tells users
        # apart (``ros2.node_users``, whose sources are kept: swarmd.senderuid); ``sender_uids``
        # is injected by tests
        node_users = config.ros2.node_users
        self.sender_uids = (
            (sender_uids or SenderUids(keep_uids=node_users, log=log))
            if node_users is not None
            else None
        )
        self.transport: BatchedSocket | None = None
        self.transport4: BatchedSocket | None = None
        self.driver: Driver[bytes, Datagram, RelayEvent] | None = None
        # keyed by (line, bundle drone or node name): bounded by the bundle
        self.lines: LineBudget[tuple[str, str]] = LineBudget(RELAY_LINES_PER_S, RELAY_LINE_BURST)

    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        """Bind [::1]:ros2.relay_port and start driving the core; ``StartupError`` (one
        line) when the port or IPv6 is not there."""
        port = self.config.ros2.relay_port
        try:
            sock = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        except OSError as exc:
            raise StartupError(
                f"{self.config.file}: ros2.relay: no IPv6 socket ({exc.strerror}); fix: enable "
                "IPv6 (the relay and the nodes' discovery use ::1; docs/ros2.md)",
                EX_OSERR,
            ) from None
        try:
            sock.setblocking(False)
            sock.bind((LOOPBACK, port))
        except OSError as exc:
            sock.close()
            raise StartupError(
                f"{self.config.file}: ros2.relay_port: cannot bind [{LOOPBACK}]:{port} "
                f"({exc.strerror}); fix: choose a free port here and in 'swarmctl ros2 profile "
                "--via-swarmd --relay-port' (or enable IPv6 on lo)",
                EX_OSERR,
            ) from None
        transport = BatchedSocket(sock, "ros2_relay", self._received, self.count, loop)
        self.transport = transport
        # the graph samples go to the nodes' unique-flow readers, UDPv4 on 127.0.0.1
        # (swarmd.ros2.graph): a send-only socket bound there, any port; the kernel delivers
        # 127.0.0.0/8 from lo only
        sock4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock4.setblocking(False)
            sock4.bind((LOOPBACK4, 0))
        except OSError as exc:
            sock4.close()
            transport.close()
            raise StartupError(
                f"{self.config.file}: ros2.relay: cannot bind {LOOPBACK4} ({exc.strerror}); "
                "fix: bring up lo with 127.0.0.1 (docs/ros2.md)",
                EX_OSERR,
            ) from None
        transport4 = BatchedSocket(sock4, "ros2_graph", self._ignored, self.count, loop)
        self.transport4 = transport4

        def transmit(out: tuple[bytes, tuple[str, int]]) -> None:
            (transport4 if out[1][0] == LOOPBACK4 else transport).sendto(out[0], out[1])

        self.driver = Driver(
            self.relay,
            transmit=transmit,
            on_event=self._on_event,
            name="ros2_relay",
            log=self.log,
            loop=loop,
            on_core_error=lambda: self.count("ros2_relay_exceptions"),
        )
        relay = self.relay
        if relay.node_uids is None:
            # docs/security.md, "ROS 2 nodes and the relay": any local process can speak as
            # a declared node
            self.log.info(
                "ros2_local_users_not_told_apart",
                fix="set ros2.node_users to the users the ROS 2 nodes run as (docs/ros2.md)",
            )
        else:
            log_firewall_expected(self.log, "ros2.relay_port")
        self.driver.call(relay.started)

    def close(self) -> None:
        """Stop the timer and the socket. No dispose is sent: the local nodes keep their
        peers for the lease, so a restarted swarmd takes over before anything expires."""
        if self.driver is not None:
            self.driver.close()
        if self.transport is not None:
            self.transport.close()
            self.transport = None
        if self.transport4 is not None:
            self.transport4.close()
            self.transport4 = None

    # ---- discovery's authenticated peers -------------------------------------------------

    def peer_up(self, name: str, address: str | None, *, restarted: bool = False) -> None:
        """An authenticated peer is up (or moved) at ``address``; ``restarted``: its swarmd
        restarted (``PeerRestarted``), its nodes are disposed and announced again."""
        relay, driver = self.relay, self.driver
        if driver is not None:
            driver.call(lambda now: relay.peer_discovered(name, address, now, restarted=restarted))

    def peer_liveness(self, name: str, alive: bytes) -> None:
        """An authenticated peer's relay says which of its nodes are alive."""
        relay, driver = self.relay, self.driver
        if driver is not None:
            driver.call(lambda now: relay.peer_liveness(name, alive, now))

    def peer_down(self, name: str) -> None:
        relay, driver = self.relay, self.driver
        if driver is not None:
            driver.call(lambda now: relay.peer_lost(name, now))

    def status(self, now: float) -> dict[str, Any]:
        """The core's rows, and beside its ``rx_foreign_user`` the lookup's
        ``sender_port_shared``: a node user's port another uid holds too, its datagrams
        dropped (swarmd.senderuid; as ``px4.backend.sender_port_shared``). 0 without
        ``ros2.node_users``: the key is there for a JSON reader either way."""
        out = self.relay.status(now)
        shared = self.sender_uids.counters["port_shared"] if self.sender_uids is not None else 0
        out["counters"]["sender_port_shared"] = shared
        out["counters"]["lines_suppressed"] = self.lines.suppressed
        return out

    # ---- internals -----------------------------------------------------------------------

    def _ignored(self, batch: list[Datagram], via: str) -> None:
        """The send-only socket reads nothing (a local process writing to it is counted)."""
        del via
        for _ in batch:
            self.count("ros2_graph_rx_ignored")

    def _received(self, batch: list[Datagram], via: str) -> None:
        if self.driver is None:
            return
        uids, relay = self.sender_uids, self.relay
        if uids is None:
            self.driver.datagrams_received(batch)
            return

        def receive(data: bytes, source: Any, now: float) -> None:
            # the kernel's word on the sender; the relay decides (Ros2Relay.node_uids)
            relay.receive_datagram(data, source, now, uids.uid_of(source))

        self.driver.datagrams_received(batch, receive)

    def _budgeted(self, event: str, about: str, *, warning: bool = False, **fields: Any) -> None:
        """Log info (or warning) line ``event`` about peer or node ``about`` unless its
        budget holds it back (``RELAY_LINES_PER_S``); it says how many of them were held
        back since the last (``suppressed``)."""
        now = self.driver.now() if self.driver is not None else 0.0
        held = self.lines.take((event, about), now)
        if held is not None:
            (self.log.warning if warning else self.log.info)(event, **fields, suppressed=held)

    def _on_event(self, event: RelayEvent) -> None:
        match event:
            case LocalParticipantHeard(node=node, guid_prefix=prefix, restarted=restarted):
                self._budgeted(
                    "ros2_participant_heard",
                    node,
                    node=node,
                    guid_prefix=str(prefix),
                    restarted=restarted,
                )
            case UnknownParticipantHeard(guid_prefix=prefix, vendor=vendor, name=name):
                # rate-limited in the relay: ``suppressed`` more were not reported one by one
                self.log.warning(
                    "ros2_unknown_participant",
                    guid_prefix=str(prefix),
                    vendor=vendor,
                    name=name,
                    suppressed=event.suppressed,
                    fix="start the node with the profile 'swarmctl ros2 profile --via-swarmd' "
                    "wrote for this drone",
                )
            case UndeclaredEndpoint(node=node, kind=kind, user_id=uid, entity_id=entity):
                # a row appears with each list that names it (review 18b: the rows are the
                # node's latest DATA(p)'s), and a local process can send new lists at will
                self._budgeted(
                    "ros2_undeclared_endpoint",
                    node,
                    warning=True,
                    node=node,
                    kind=kind,
                    user_id=uid,
                    entity_id=entity,
                    fix="declare the endpoint in the mission's ros2 section and re-flash",
                )
            case LocalLivenessChanged(alive=alive, node=node, up=up):
                self._budgeted("ros2_node_liveness", node, node=node, up=up, alive=alive.hex())
                if self.on_liveness is not None:
                    self.on_liveness(alive)  # every change: the word swarmd signs is not held
            case RemoteNodeLiveness(drone=drone, node=node, up=up, restarted=restarted):
                self._budgeted(
                    "ros2_remote_node_liveness",
                    drone,
                    peer=drone,
                    node=node,
                    up=up,
                    restarted=restarted,
                )
            case RemoteParticipantsRelayed(drone=drone, participants=n, up=up, restarted=again):
                self._budgeted(
                    "ros2_relay_peer", drone, peer=drone, participants=n, up=up, restarted=again
                )
            case _:
                self.log.info("ros2_relay_event", event_type=type(event).__name__)
