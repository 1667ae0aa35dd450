"""The ROS 2 relay's side that faces its own drone's nodes (swarmd.ros2.relay): what a local
node's DATA(p) and DATA(p[UD]) tell it (heard, left, a restart under the same GUIDs, its
lease), the liveness word swarmd signs for them, the start answers, the sibling nodes that
hold a restarted node's old proxies, the unknown participants and undeclared endpoints
shown to operators. The "why" of each step is in swarmd.ros2.relay's module docstring.
"""

from __future__ import annotations

from typing import Final

from swarmd.bundle.ros2 import VENDOR_EPROSIMA
from swarmd.ros2.relay_announce import Announcer
from swarmd.ros2.relay_events import (
    LocalLivenessChanged,
    LocalParticipantHeard,
    UndeclaredEndpoint,
    UnknownParticipantHeard,
)
from swarmd.ros2.relay_spdp import FASTDDS_PROTOCOL_VERSION, STATIC_EDP_PROPERTY
from swarmd.ros2.relay_state import LocalNode, UnknownParticipant
from swarmd.rtps.spdp import SpdpAlive, SpdpParticipant, encode_spdp_dispose
from swarmd.rtps.types import GuidPrefix, VendorId

# unknown prefixes heard on loopback: a local process may invent any number of them
MAX_UNKNOWN_PARTICIPANTS: Final = 16
# A local process cycling more invented prefixes than the table holds makes every datagram
# a new participant (review 16): each was a warning line (``ros2_unknown_participant``),
# and journald's per-unit rate limit then drops the daemon's other lines. Reported about
# once a second (burst 10), each report saying how many it stands for, as discovery's
# foreign participants are (swarmd.discovery.foreign).
UNKNOWN_REPORTS_PER_S: Final = 1.0
UNKNOWN_REPORT_BURST: Final = 10.0
# undeclared endpoints shown per local participant: of its latest DATA(p), the first in its
# order (a node creating endpoints in a loop, or a local process speaking as it)
MAX_UNDECLARED_PER_PARTICIPANT: Final = 32
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


class LocalNodes(Announcer):
    """The relay's rows of its drone's nodes and what it does when one speaks."""

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
        256 (swarmd.ros2.relay, "A restart under the same GUIDs"). A relay that reads only
        the bitmap ignores the octets after it."""
        return self.alive_bitmap() + bytes(local.restarts for local in self._local.values())

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

    def _send_siblings_to(self, local: LocalNode) -> None:
        """The other alive nodes of this drone, to a starting ``local``: their own latest
        DATA(p), as they sent it. They are its initial peers and answer its first DATA(p)
        themselves, within milliseconds, which can land before the starting node listens
        (as the relay's answer can: START_ANSWERS); it would then take
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
        still hold the writer proxies of its earlier life (swarmd.ros2.relay, "A restart
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
        if not self._unknown_reports.take(now):
            self.counters["unknown_suppressed"] += 1
            self._unknown_suppressed += 1
            return
        suppressed, self._unknown_suppressed = self._unknown_suppressed, 0
        self._events.append(
            UnknownParticipantHeard(prefix, vendor, participant.entity_name, suppressed)
        )

    def _check_endpoints(self, local: LocalNode, participant: SpdpParticipant) -> None:
        """The node's undeclared endpoints are what its latest DATA(p) lists: Fast DDS's
        static EDP puts every endpoint a participant has in each DATA(p) it sends, so a new
        life (after its dispose, or numbering from 1 again) replaces them at its first
        DATA(p) and a node fixed and restarted no longer shows its old rows (review 18b;
        a node that left keeps its last ones on show). The first
        ``MAX_UNDECLARED_PER_PARTICIPANT`` in the DATA(p)'s own order are kept, the rest
        counted (shown as not shown, counter ``undeclared_dropped``). Kept across
        datagrams, a local process speaking as the node (``ros2.node_users`` unset) filled
        them with invented ones for good and hid the node's own; now its rows last until
        the node's next DATA(p). A row is reported (``UndeclaredEndpoint``) when it
        appears, not at every renewal that lists it again."""
        rows: list[tuple[str, int, str]] = []
        not_kept = 0
        for name, value in participant.properties:
            m = STATIC_EDP_PROPERTY.fullmatch(name)
            if m is None:
                continue
            kind, uid = m.group(1), int(m.group(2))
            if (kind, uid) in local.declared:
                continue
            key = (kind, uid, value[:32])
            if key in rows:
                continue
            if len(rows) >= MAX_UNDECLARED_PER_PARTICIPANT:
                not_kept += 1
                continue
            rows.append(key)
        self.counters["undeclared_dropped"] += not_kept
        before = local.undeclared or ()
        local.undeclared = tuple(rows)
        local.undeclared_not_kept = not_kept
        p = local.participant
        for kind, uid, entity in rows:
            if (kind, uid, entity) not in before:
                self._events.append(
                    UndeclaredEndpoint(p.drone, p.node.name, kind.lower(), uid, entity)
                )
