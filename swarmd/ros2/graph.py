"""Graph preloading: swarmd serves its drone's ROS 2 nodes the other drones' node names on
loopback, from the signed bundle (issue 19, docs/ros2.md "Graph preloading").

Theory of operation. rmw_fastrtps keeps a node's view of the ROS 2 graph (``ros2 node
list``, ``get_node_names``) from the topic ``ros_discovery_info``: every participant
publishes its ``ParticipantEntitiesInfo`` (its GID; per node its name, namespace and its
endpoints' GIDs) and rmw_dds_common's graph cache files each sample under the participant
GID *inside the message*, whoever wrote it; an entry goes when that participant is removed
from discovery (``GraphCache::update_participant_entities``/``remove_participant``). On the
relay route the other drones' graph endpoints are not announced, so none of that crosses
the air (docs/ros2.md, "Graph traffic stays on the drone"), and this module puts the names
back without it:

- swarmd is one more *local* participant of each node, the graph participant: its SPDP
  (sent by the relay with the others, on [::1]) has a GUID prefix drawn at random when
  swarmd starts, metatraffic and default unicast locators = the relay on [::1], and one
  static EDP writer on ``ros_discovery_info`` (``eProsimaEDPStatic_Writer_ALIVE_ID_<id>``,
  the id after the bundle's last; the relay-route ``static-edp.xml`` lists it without a
  locator, so Fast DDS takes the participant's: the node's ACKNACKs come to the relay);
- that writer (DDSI-RTPS 2.5 8.4.7, reliable stateful, reader proxies from the bundle)
  publishes one sample per remote ROS 2 participant the relay announces, the bundle's node
  with its endpoints' GIDs, and disposes nothing: the relay's ``DATA(p[UD])`` of that
  participant makes rmw drop its entry; a participant announced again gets a new sample;
- a node's graph reader asks for unique network flows (rmw_fastrtps
  ``init_rmw_context_impl.cpp``), so Fast DDS gives it a port of its own, the first free one
  from ``portBase - 400`` (``RTPSParticipantImpl.cpp`` ``get_unique_flows_parameters``); its
  user port does not reach it (measured: a DATA there was never taken). The relay-route
  profile sets ``portBase`` so that this port is ``graph_reader_port`` (6999, 6998, ... by
  the node's place on its drone), which is where the samples go, on 127.0.0.1.

Samples go out when the reader shows it has matched the writer: its first (preemptive)
ACKNACK, or a NACK after a HEARTBEAT; HEARTBEATs repeat with a backoff until the reader
acknowledges the last sample. A sample sent before the node matched the writer is dropped
by Fast DDS, so nothing depends on the first DATA arriving.

Trust. The samples are a function of the bundle and of which drones swarmd's authenticated
discovery has. The writer's GUID is the capability: its prefix is random per swarmd start
and only ever sent on loopback, so an outsider cannot forge a sample the node's reader
takes (a DATA from an unmatched writer is dropped), though the reader's port is open to the
air as every unique-flow port of stock ROS 2 is. An ACKNACK only makes the writer resend its
samples to a bundle-known loopback port, at most once per ``MIN_RESEND_S`` per reader; a
sample the reader has never been sent goes at its first NACK, so the DATA the limit lets
through is bounded by the relay's announcements, and a drone found 0.1 s after another does
not wait a heartbeat (up to 0.5 s) for its name (docs/benchmarks.md, "ROS 2 on swarmd's
slow pairs, split").
Sans-IO: driven by ``receive_datagram``, ``handle_timer`` and the relay's calls;
``receive_datagram`` raises nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

from swarmd.bundle.ros2 import (
    GRAPH_TOPIC,
    MAX_USER_ID,
    VENDOR_EPROSIMA,
    Ros2EndpointKind,
    Ros2Participant,
)
from swarmd.rtps.buffer import Reader
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator
from swarmd.rtps.message import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    SequenceNumberSet,
    Submessage,
    decode_message,
    encode_header,
    encode_submessage,
)
from swarmd.rtps.spdp import BES_SPDP_ONLY, SpdpParticipant
from swarmd.rtps.types import (
    ENTITYID_PARTICIPANT,
    Duration,
    EntityId,
    GuidPrefix,
    ProtocolVersion,
    VendorId,
)

FASTDDS_PROTOCOL_VERSION: Final = ProtocolVersion(2, 3)
FIRST_HEARTBEAT_S: Final = 0.5  # unacknowledged: heartbeat again after this, doubling
MIN_RESEND_S: Final = 0.2  # ACKNACKs answered with DATA at most this often per reader
# Fast DDS 3.2 looks for a unique-flow port in [portBase - 400, portBase)
UNIQUE_FLOW_SPAN: Final = 400
# the first node of a drone gets its graph reader here, the next one below: under Fast
# DDS's stock unique-flow range (7000-7399) and far below the ephemeral ports
GRAPH_READER_PORT_TOP: Final = 6999
LOOPBACK4: Final = "127.0.0.1"  # where the node's unique-flow (UDPv4) reader listens too
GRAPH_PREFIX_RANDOM_BYTES: Final = 10  # after eProsima's vendor id
GID_SIZE: Final = 16  # rmw_dds_common/msg/Gid: char[16] (Kilted: GUID prefix + entity id)
MAX_NAME: Final = 256  # string<=256 node_namespace / node_name
# a decoded sample's sequences (nodes, GIDs): bounds the work a forged payload can cause
MAX_SEQUENCE: Final = 4096
# The most octets of one datagram to a node's graph reader: Fast DDS's default
# maxMessageSize (s_maximumMessageSize, TransportInterface.hpp; the size of its receive
# buffer), under UDP's 65,507 over IPv4. The answer to a reader's first ACKNACK carries
# every remote participant's sample, 16 octets per endpoint, and a valid bundle holds up to
# 32,767 endpoints (swarmd.bundle.ros2 MAX_USER_ID): over 500 KB. Sent as one message it
# passed this limit at 39 remote nodes of 103 endpoints (65,900 octets; review 18b,
# docs/ros2.md "Graph preloading"); now the submessages are split over as many messages as
# needed, each complete (DDSI-RTPS 2.5 8.3: any number of submessages per message, any
# number of messages). One sample always fits: a node has at most MAX_NODE_ENDPOINTS
# (1,000), a sample of 16,016 octets.
MAX_DATAGRAM: Final = 65_500
CDR_BE: Final = b"\x00\x00"
CDR_LE: Final = b"\x00\x01"


# ---- CDR codec (XCDR1, OMG DDS-XTypes 7.4.1; rosidl's ParticipantEntitiesInfo) -------------


@dataclass(frozen=True, slots=True)
class NodeEntitiesInfo:
    namespace: str
    name: str
    reader_gids: tuple[bytes, ...]
    writer_gids: tuple[bytes, ...]


@dataclass(frozen=True, slots=True)
class ParticipantEntitiesInfo:
    gid: bytes
    nodes: tuple[NodeEntitiesInfo, ...]


class _Cdr:
    """XCDR1 writer: alignment is relative to the payload after the encapsulation header."""

    def __init__(self) -> None:
        self.out = bytearray()

    def align(self, n: int) -> None:
        self.out += bytes(-len(self.out) % n)

    def u32(self, value: int) -> None:
        self.align(4)
        self.out += value.to_bytes(4, "little")

    def string(self, text: str) -> None:
        raw = text.encode()
        if len(text) > MAX_NAME or b"\x00" in raw:
            raise ValueError(f"ROS name {text!r}: not a string<={MAX_NAME}")
        self.u32(len(raw) + 1)
        self.out += raw + b"\x00"

    def gids(self, gids: tuple[bytes, ...]) -> None:
        self.u32(len(gids))
        for gid in gids:
            if len(gid) != GID_SIZE:
                raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(gid)}")
            self.out += gid


def encode_entities_info(info: ParticipantEntitiesInfo) -> bytes:
    """The serialized payload (encapsulation CDR_LE + body), as rmw_fastrtps writes it."""
    w = _Cdr()
    if len(info.gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, not {len(info.gid)}")
    w.out += info.gid
    w.u32(len(info.nodes))
    for node in info.nodes:
        w.string(node.namespace)
        w.string(node.name)
        w.gids(node.reader_gids)
        w.gids(node.writer_gids)
    return CDR_LE + b"\x00\x00" + bytes(w.out)


def _pull_aligned_u32(r: Reader, base: int, what: str) -> int:
    r.pull_bytes(-(r.pos - base) % 4, "CDR padding")
    return r.pull_u32(what)


def _pull_string(r: Reader, base: int, what: str) -> str:
    length = _pull_aligned_u32(r, base, what)
    if not 1 <= length <= MAX_NAME + 1:
        raise DecodeError(f"{what}: length {length} outside 1..{MAX_NAME + 1}")
    raw = r.pull_bytes(length, what)
    if raw[-1] != 0 or 0 in raw[:-1]:
        raise DecodeError(f"{what}: not a NUL-terminated string")
    try:
        return raw[:-1].decode()
    except UnicodeDecodeError:
        raise DecodeError(f"{what}: not UTF-8") from None


def _pull_count(r: Reader, base: int, what: str, item_size: int) -> int:
    count = _pull_aligned_u32(r, base, what)
    # every item takes at least item_size bytes: a count the payload cannot hold is forged
    if count > MAX_SEQUENCE or count * item_size > r.remaining():
        raise DecodeError(f"{what}: {count} items do not fit")
    return count


def decode_entities_info(payload: bytes) -> ParticipantEntitiesInfo:
    """Parse a serialized ``ParticipantEntitiesInfo`` (CDR_BE or CDR_LE); ``DecodeError``
    for anything else, never another exception. Padding bytes are not checked (rmw leaves
    them uninitialised: a real sample has 0x7f there)."""
    if len(payload) < 4 or payload[:2] not in (CDR_BE, CDR_LE):
        raise DecodeError("not a CDR (XCDR1) encapsulation")
    r = Reader(payload, 4, little=payload[:2] == CDR_LE)
    base = 4
    gid = r.pull_bytes(GID_SIZE, "participant gid")
    nodes: list[NodeEntitiesInfo] = []
    for _ in range(_pull_count(r, base, "node count", 10)):
        namespace = _pull_string(r, base, "node namespace")
        name = _pull_string(r, base, "node name")
        readers = tuple(
            r.pull_bytes(GID_SIZE, "reader gid")
            for _ in range(_pull_count(r, base, "reader count", GID_SIZE))
        )
        writers = tuple(
            r.pull_bytes(GID_SIZE, "writer gid")
            for _ in range(_pull_count(r, base, "writer count", GID_SIZE))
        )
        nodes.append(NodeEntitiesInfo(namespace, name, readers, writers))
    if r.remaining() > 3:  # at most the final alignment padding may follow
        raise DecodeError(f"{r.remaining()} bytes after the sample")
    return ParticipantEntitiesInfo(gid, tuple(nodes))


# ---- what the bundle says a participant's graph sample is ----------------------------------


def endpoint_entity_id(user_id: int, kind: Ros2EndpointKind) -> EntityId:
    """The entity id the profile gives an endpoint (``entityID`` = ``userDefinedID``; kind
    writer/reader with no key, DDSI-RTPS 9.3.1.2)."""
    kind_octet = 0x03 if kind == Ros2EndpointKind.WRITER else 0x04
    return EntityId((user_id & 0xFFFFFF).to_bytes(3, "big") + bytes([kind_octet]))


def graph_endpoint_id(p: Ros2Participant, kind: Ros2EndpointKind) -> EntityId:
    """``p``'s ``ros_discovery_info`` writer or reader entity id."""
    for i, e in enumerate(p.endpoints):
        if e.dds_topic == GRAPH_TOPIC and e.kind == kind:
            return endpoint_entity_id(p.first_user_id + i, kind)
    raise ValueError(f"participant {p.node.name!r} has no {GRAPH_TOPIC} {kind}")


def entities_info(p: Ros2Participant) -> ParticipantEntitiesInfo:
    """``p``'s graph sample from the bundle: one node (namespace ``/``, the bundle's name)
    with every declared endpoint but the graph topic's own (rmw lists a node's entities,
    not its context's graph reader and writer)."""
    readers: list[bytes] = []
    writers: list[bytes] = []
    for i, e in enumerate(p.endpoints):
        if e.dds_topic == GRAPH_TOPIC:
            continue
        gid = p.guid_prefix + endpoint_entity_id(p.first_user_id + i, e.kind).value
        (writers if e.kind == Ros2EndpointKind.WRITER else readers).append(gid)
    node = NodeEntitiesInfo("/", p.node.name, tuple(readers), tuple(writers))
    return ParticipantEntitiesInfo(p.guid_prefix + ENTITYID_PARTICIPANT.value, (node,))


def graph_reader_port(p: Ros2Participant, participants: tuple[Ros2Participant, ...]) -> int:
    """The UDP port of ``p``'s ``ros_discovery_info`` reader on the relay route: the profile
    sets ``portBase`` = this + ``UNIQUE_FLOW_SPAN`` (module docstring)."""
    place = [q.guid_prefix for q in participants if q.drone == p.drone].index(p.guid_prefix)
    return GRAPH_READER_PORT_TOP - place


def graph_writer_user_id(participants: tuple[Ros2Participant, ...]) -> int:
    """The static EDP id of swarmd's graph writer: the one after the bundle's last; 0 when
    the bundle has used every id Fast DDS can hold (no graph preloading then)."""
    top = max((p.first_user_id + len(p.endpoints) for p in participants), default=1)
    return top if top <= MAX_USER_ID else 0


def graph_participant_prefix(random_bytes: bytes) -> GuidPrefix:
    """The graph participant's GUID prefix: eProsima's vendor id (Fast DDS reads static EDP
    properties from it) + ``GRAPH_PREFIX_RANDOM_BYTES`` drawn by the caller (secrets)."""
    if len(random_bytes) != GRAPH_PREFIX_RANDOM_BYTES:
        raise ValueError(f"the graph prefix takes {GRAPH_PREFIX_RANDOM_BYTES} random bytes")
    return GuidPrefix(VENDOR_EPROSIMA + random_bytes)


# ---- the writer --------------------------------------------------------------------------


@dataclass(slots=True)
class _Proxy:
    """One local node's graph reader: DDSI-RTPS 8.4.7.5 ReaderProxy."""

    participant: Ros2Participant
    reader_id: EntityId
    port: int
    acked_below: int = 0  # every SN below this is acknowledged (ACKNACK base)
    sent_below: int = 1  # every SN below this was sent (DATA or GAP) to this reader once
    next_heartbeat: float | None = None
    heartbeat_s: float = FIRST_HEARTBEAT_S
    last_data: float | None = None


@dataclass(slots=True)
class _History:
    """The writer's samples: one per remote participant the relay announces."""

    by_prefix: dict[GuidPrefix, int] = field(default_factory=dict)  # -> its SN
    payloads: dict[int, bytes] = field(default_factory=dict)  # SN -> serialized sample


class GraphParticipant:
    """swarmd's graph participant on one drone (module docstring). Datagrams out:
    ``(bytes, (host, port))``, always to 127.0.0.1."""

    def __init__(
        self,
        participants: tuple[Ros2Participant, ...],
        drone: str,
        *,
        prefix: GuidPrefix,
        relay_locator: Locator,
        domain_id: int,
        lease_s: float,
        epoch: int = 0,
    ) -> None:
        self.prefix = prefix
        self.user_id = graph_writer_user_id(participants)
        self.writer_id = endpoint_entity_id(self.user_id, Ros2EndpointKind.WRITER)
        self.relay_locator = relay_locator
        self.domain_id = domain_id
        self.lease_s = lease_s
        self.period_s = lease_s / 4
        # Sequence numbers and heartbeat counts start at 1 in each life: the prefix is new
        # each life, so no reader has seen this writer before. Not swarmd's epoch in the
        # upper half as the relay's SPDP has: Fast DDS's reliable reader walks the numbers
        # below a writer's first one (measured: a first sample at epoch << 32 + 1 hung the
        # node, its graph reader's socket never read again)
        del epoch
        self._sn = 0
        self._count = 0
        self._payloads = {
            GuidPrefix(p.guid_prefix): encode_entities_info(entities_info(p))
            for p in participants
            if p.drone != drone
        }
        self._proxies: dict[GuidPrefix, _Proxy] = {
            GuidPrefix(p.guid_prefix): _Proxy(
                p,
                graph_endpoint_id(p, Ros2EndpointKind.READER),
                graph_reader_port(p, participants),
            )
            for p in participants
            if p.drone == drone
        }
        self._history = _History()
        self._out: list[tuple[bytes, tuple[str, int]]] = []
        self.counters: dict[str, int] = {
            "graph_rx_acknack": 0,
            "graph_rx_ignored": 0,
            "graph_rx_inconsistent": 0,
            "graph_tx_data": 0,
            "graph_tx_gap": 0,
            "graph_tx_heartbeat": 0,
            "graph_resend_limited": 0,
            "graph_tx_split": 0,
        }

    @property
    def enabled(self) -> bool:
        return self.user_id > 0

    def spdp(self) -> SpdpParticipant:
        """The graph participant's DATA(p) content (the relay sends it with its own)."""
        return SpdpParticipant(
            self.prefix,
            protocol_version=FASTDDS_PROTOCOL_VERSION,
            vendor_id=VendorId(VENDOR_EPROSIMA),
            domain_id=self.domain_id,
            metatraffic_unicast_locators=(self.relay_locator,),
            default_unicast_locators=(self.relay_locator,),
            lease_duration=Duration.from_seconds(self.lease_s),
            builtin_endpoints=BES_SPDP_ONLY,
            entity_name="/",
            properties=(
                (
                    f"eProsimaEDPStatic_Writer_ALIVE_ID_{self.user_id}",
                    ".".join(str(b) for b in self.writer_id.value),
                ),
            ),
        )

    # ---- driven by the relay -------------------------------------------------------------------

    def publish(self, remote: GuidPrefix, now: float) -> None:
        """The relay announced remote participant ``remote`` (again): a new sample for it."""
        payload = self._payloads.get(remote)
        if payload is None or not self.enabled:
            return
        old = self._history.by_prefix.pop(remote, None)
        if old is not None:
            del self._history.payloads[old]
        self._sn += 1
        self._history.by_prefix[remote] = self._sn
        self._history.payloads[self._sn] = payload
        for proxy in self._proxies.values():
            self._offer(proxy, now)

    def withdraw(self, remote: GuidPrefix) -> None:
        """The relay disposed ``remote`` (rmw drops its entry with the participant): its
        sample is no longer offered; a reader that asks for it gets a GAP."""
        sn = self._history.by_prefix.pop(remote, None)
        if sn is not None:
            del self._history.payloads[sn]

    def local_restarted(self, local: GuidPrefix, now: float) -> None:
        """A local node (re)started: its reader has nothing yet."""
        proxy = self._proxies.get(local)
        if proxy is not None:
            proxy.acked_below = 0
            proxy.sent_below = 1
            proxy.last_data = None
            self._offer(proxy, now)

    def receive_datagram(self, data: bytes, now: float) -> bool:
        """A datagram a local node sent the relay's port: True when it was for this writer
        (an ACKNACK), False to let the relay count it. Never raises."""
        try:
            message = decode_message(data)
        except DecodeError:
            return False
        dst: GuidPrefix | None = None
        mine = False
        for sm in message.submessages:
            if isinstance(sm, InfoDst):
                dst = sm.guid_prefix
            elif isinstance(sm, AckNack) and sm.writer_id == self.writer_id:
                if dst is not None and dst != self.prefix:
                    continue
                mine = True
                proxy = self._proxies.get(message.header.guid_prefix)
                if proxy is None or sm.reader_id != proxy.reader_id:
                    self.counters["graph_rx_ignored"] += 1
                    continue
                self.counters["graph_rx_acknack"] += 1
                self._acknack(proxy, sm.reader_sn_state, now)
        return mine

    def handle_timer(self, now: float) -> None:
        for proxy in self._proxies.values():
            if proxy.next_heartbeat is None or now < proxy.next_heartbeat:
                continue
            if proxy.acked_below > self._sn:
                proxy.next_heartbeat = None
                continue
            self._send(proxy, [self._heartbeat(proxy)])
            proxy.heartbeat_s = min(proxy.heartbeat_s * 2, self.period_s)
            proxy.next_heartbeat = now + proxy.heartbeat_s

    def get_timer(self) -> float | None:
        due = [p.next_heartbeat for p in self._proxies.values() if p.next_heartbeat is not None]
        return min(due, default=None)

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        out, self._out = self._out, []
        return out

    def status(self) -> dict[str, object]:
        return {
            "writer_user_id": self.user_id,
            "samples": len(self._history.payloads),
            "readers_up_to_date": sum(p.acked_below > self._sn for p in self._proxies.values()),
            "readers": len(self._proxies),
        }

    # ---- internals ---------------------------------------------------------------------------

    def _offer(self, proxy: _Proxy, now: float) -> None:
        """HEARTBEAT now and again with a backoff until acknowledged: a reader that has
        matched the writer answers it with a NACK, and the data follows (``_acknack``)."""
        proxy.heartbeat_s = FIRST_HEARTBEAT_S
        proxy.next_heartbeat = now + FIRST_HEARTBEAT_S
        self._send(proxy, [self._heartbeat(proxy)])

    def _heartbeat(self, proxy: _Proxy) -> Heartbeat:
        self._count += 1
        self.counters["graph_tx_heartbeat"] += 1
        first = min(self._history.payloads, default=self._sn + 1)
        # DDSI-RTPS 8.3.7.5: first = last + 1 says "nothing available"
        return Heartbeat(proxy.reader_id, self.writer_id, first, self._sn, self._count)

    def _acknack(self, proxy: _Proxy, state: SequenceNumberSet, now: float) -> None:
        if state.base > self._sn + 1:
            # it says numbers never published were received: inconsistent, ignored whole as
            # Fast DDS's writer does (StatefulWriter::process_acknack). Taken, it made the
            # reader look up to date for good: no more heartbeats, so a lost DATA was not
            # offered again (a buggy node, or a local process speaking as one; review 18)
            self.counters["graph_rx_inconsistent"] += 1
            return
        proxy.acked_below = max(proxy.acked_below, state.base)
        if state.base > self._sn:
            proxy.next_heartbeat = None  # up to date
            return
        if proxy.next_heartbeat is None:
            proxy.heartbeat_s = FIRST_HEARTBEAT_S
            proxy.next_heartbeat = now + FIRST_HEARTBEAT_S
        # a preemptive ACKNACK (empty set: Fast DDS sends one when it matches the writer)
        # asks for everything from its base, a NACK for its members (DDSI-RTPS 8.4.15.3);
        # below the first sample nothing is available (the HEARTBEAT says so)
        available = sorted(self._history.payloads)
        lo = max(state.base, available[0] if available else self._sn + 1)
        requested = set(state.members())
        # never past the last number published: a GAP there would make the reader drop the
        # next drones' samples (DDSI-RTPS 8.3.7.4; a buggy or forged NACK, review 17)
        hi = self._sn if state.num_bits == 0 else min(max(requested, default=0), self._sn)
        # the limit holds resends only: a sample published since this reader was last sent
        # anything goes at once (each at most once outside the limit, so a NACK flood still
        # draws one DATA per MIN_RESEND_S). Before, a drone found within 0.2 s of the last
        # DATA waited for the next heartbeat, up to FIRST_HEARTBEAT_S later
        fresh = max(lo, proxy.sent_below) <= min(hi, self._sn)
        limited = proxy.last_data is not None and now - proxy.last_data < MIN_RESEND_S
        if limited and not fresh:
            self.counters["graph_resend_limited"] += 1
            return
        submessages: list[Submessage] = []
        start = lo
        for sn in (s for s in available if lo <= s <= hi):
            if start < sn:  # withdrawn samples in between: irrelevant (GAP, 8.3.7.4)
                submessages.append(self._gap(proxy, start, sn))
            if state.num_bits == 0 or sn in requested:
                payload = self._history.payloads[sn]
                submessages.append(
                    Data(proxy.reader_id, self.writer_id, sn, serialized_payload=payload)
                )
                self.counters["graph_tx_data"] += 1
            start = sn + 1
        if start <= hi:
            submessages.append(self._gap(proxy, start, hi + 1))
        submessages.append(self._heartbeat(proxy))
        proxy.last_data = now
        proxy.sent_below = max(proxy.sent_below, min(hi, self._sn) + 1)
        self._send(proxy, submessages)

    def _gap(self, proxy: _Proxy, start: int, end: int) -> Gap:
        """Sequence numbers ``start`` .. ``end - 1`` are irrelevant."""
        self.counters["graph_tx_gap"] += 1
        return Gap(proxy.reader_id, self.writer_id, start, SequenceNumberSet(end, 0))

    def _send(self, proxy: _Proxy, submessages: list[Submessage]) -> None:
        """``submessages`` to ``proxy``'s reader, in order, in as few messages as
        ``MAX_DATAGRAM`` allows; each opens with the header and INFO_DST, so each stands
        alone (a HEARTBEAT last stays last)."""
        head = encode_header(
            Header(FASTDDS_PROTOCOL_VERSION, VendorId(VENDOR_EPROSIMA), self.prefix)
        ) + encode_submessage(InfoDst(GuidPrefix(proxy.participant.guid_prefix)))
        to = (LOOPBACK4, proxy.port)
        parts: list[bytes] = []
        size = len(head)
        for sm in submessages:
            raw = encode_submessage(sm)
            if parts and size + len(raw) > MAX_DATAGRAM:
                self._out.append((head + b"".join(parts), to))
                self.counters["graph_tx_split"] += 1
                parts, size = [], len(head)
            parts.append(raw)
            size += len(raw)
        self._out.append((head + b"".join(parts), to))
