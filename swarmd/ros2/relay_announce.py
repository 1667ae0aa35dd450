"""What the ROS 2 relay (swarmd.ros2.relay) announces to its drone's nodes on loopback: the
synthesized DATA(p) of each remote drone's ROS 2 participants (the bundle's prefix and
endpoints, the peer's address from swarmd's discovery, the relay as metatraffic locator),
their disposes, swarmd's graph participant, and the renewals within the lease. Sequence
numbers carry the relay's boot epoch in their upper half (swarmd.ros2.relay's module
docstring). ``Announcer`` declares the relay's state the other concerns share; ``Ros2Relay``
sets it. Sans-IO: datagrams are queued, the owner sends them.
"""

from __future__ import annotations

from collections import deque

from swarmd.bundle.ros2 import VENDOR_EPROSIMA, Ros2Participant
from swarmd.lives import LifeDamping
from swarmd.ros2.graph import GraphParticipant
from swarmd.ros2.relay_events import RelayEvent
from swarmd.ros2.relay_spdp import FASTDDS_PROTOCOL_VERSION, static_edp_properties
from swarmd.ros2.relay_state import LocalNode, RemoteDrone, UnknownParticipant
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import BES_SPDP_ONLY, SpdpParticipant, encode_spdp, encode_spdp_dispose
from swarmd.rtps.types import Duration, GuidPrefix, VendorId
from swarmd.tokenbucket import TokenBucket


class Announcer:
    """The relay's shared state (set by ``Ros2Relay.__init__``) and its announcements."""

    drone: str
    node_uids: frozenset[int] | None
    domain_id: int
    lease_s: float
    period_s: float
    relay_port: int
    loopback: str
    graph: GraphParticipant | None
    counters: dict[str, int]
    _relay_locator: Locator
    _sn: int
    _local: dict[GuidPrefix, LocalNode]
    _remote_by_drone: dict[str, list[Ros2Participant]]
    _remote_prefixes: frozenset[GuidPrefix]
    _present: dict[str, RemoteDrone]
    _remote_alive: dict[str, tuple[bool, ...]]
    _remote_restarts: dict[str, tuple[int, ...] | None]
    _liveness_acted: dict[str, float]
    _liveness_held: dict[str, bytes]
    _liveness_lives: LifeDamping
    _drone_index: dict[str, int]
    _unknown: dict[GuidPrefix, UnknownParticipant]
    _unknown_reports: TokenBucket
    _unknown_suppressed: int
    _out: list[tuple[bytes, tuple[str, int]]]
    _events: deque[RelayEvent]
    _next_renewal: float | None

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

    def _renew_all(self, now: float) -> None:
        if self._present:
            self._send_graph_spdp(None)
        for drone, present in self._present.items():
            for p in self._alive_remote(drone):
                self._send_alive(p, present.address, now)
        self._next_renewal = now + self.period_s if self._present else None
