"""A sans-IO DDS-XRCE agent: the side PX4's ``uxrce_dds_client`` connects to.

Theory of operation. PX4 (DDS-XRCE 1.0 §8.4, as the Micro XRCE-DDS client implements it)
pings with GET_INFO outside any session until an agent answers, sends CREATE_CLIENT for
session 0x81 with its key (``UXRCE_DDS_KEY``), opens a reliable stream 0x80 and a
best-effort stream 0x01 each way, creates a participant, then topic/subscriber/datareader
per subscription (each followed by READ_DATA) and topic/publisher/datawriter per
publication, waiting up to 1 s for each CREATE's STATUS; a refused writer aborts its whole
set-up. It syncs time with TIMESTAMP (discarding replies slower than 10 ms), publishes with
WRITE_DATA on 0x01, pings in session (GET_INFO) when idle, and starts over after 3 missed
pings. This agent accepts every entity (tables capped), answers every CREATE with STATUS on
its reliable stream, TIMESTAMP at once from the injected clock, GET_INFO with
``implementation_status`` 1 and ``availability`` 1 (PX4 disconnects otherwise), turns
WRITE_DATA into ``SampleReceived`` and ``publish()`` into DATA for every reader that asked.
No DDS participant exists behind it: nothing reaches any network but the client's link.

One agent, one vehicle. With ``expected_key`` (the daemon always gives one: ``px4.xrce_key``
or the key generated into the state directory) the agent is *bound*: it holds at most one
session, the vehicle's, and ``publish``/``request`` go to that session only. A CREATE_CLIENT
with another key is refused; one with the vehicle's key from another address is refused
while the bound session is alive, and takes the binding over only once that session has been
silent for ``VEHICLE_DEAD_AFTER_S`` (PX4 itself gives up on an agent after 3 missed 1 s
pings, and while connected sends a time-sync request every 1 s besides its samples and pings:
``src/modules/uxrce_dds_client/uxrce_dds_client.cpp``, ``checkConnectivity`` and ``run``).
The same key from the same address is PX4 restarted behind the same port (always so on a
UART) and starts the session afresh at once. Neither refusal is answered: a client that
hears nothing retries (Micro XRCE-DDS resends CREATE_CLIENT, by default 10 times 1 s apart,
as it must over a transport that loses datagrams), and silence tells a local prober
nothing, not even that its try was checked. Each key compared spends the
``KeyCheckBudget`` (per source and per origin, ``keycheck.py``); a CREATE_CLIENT over it is
dropped unchecked, so a flood tests at most a few keys a second (``refused["over_budget"]``).
With ``vehicle_uid`` (PX4 SITL on loopback, ``px4.loopback_user``) a loopback datagram of any
other local user is dropped before all of it (``dropped["foreign_user"]``): the kernel's
socket table says who sent it, so the loopback's budget is that user's alone.
Every refusal is counted in ``refused`` and reported as ``ClientRefused``. The key is a
session identifier sent in the clear, not a credential (docs/px4.md, "One agent, one
vehicle").
Without ``expected_key`` (lab tools, the golden-session oracle) the agent is unbound: up to
``MAX_SESSIONS`` clients, samples and commands routed among all of them, as MicroXRCEAgent.

Driving sources (style.md rule 2): ``receive_datagram(data, source, now)``,
``handle_timer(now)`` and the ``publish`` command. Outputs: ``datagrams_to_send()``,
``get_timer()``, ``next_event()``.

Invariant: network input never raises out of this class; a datagram that does not decode
or belongs to no session is dropped, counted in ``dropped`` and reported as
``PacketDropped``. Any other exception is a bug.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

from swarmd.xrce.binary import parse_endpoint, parse_service, parse_topic
from swarmd.xrce.buffer import DecodeError
from swarmd.xrce.endpoint import Endpoint, receive_stream, stand_in
from swarmd.xrce.events import (
    Address,
    ClientRefused,
    EntityCreated,
    SampleReceived,
    SessionCreated,
    SessionEnded,
)
from swarmd.xrce.keycheck import LOOPBACK_ORIGIN, KeyCheckBudget, origin_of
from swarmd.xrce.message import (
    OBJECT_ID_CLIENT,
    XRCE_COOKIE,
    AckNack,
    AgentRepresentation,
    Create,
    CreateClient,
    Data,
    Delete,
    Fragment,
    GetInfo,
    Header,
    Heartbeat,
    Info,
    ObjectKind,
    ReadData,
    Repr,
    Reset,
    Status,
    StatusAgent,
    StatusReply,
    Submessage,
    Time,
    Timestamp,
    TimestampReply,
    WriteData,
    decode_header,
    decode_submessage,
    encode_message,
    object_kind,
    split_submessages,
)
from swarmd.xrce.streams import BestEffortIn, Reassembly, ReliableIn, ReliableOut, seq_add

# Client sessions at once. PX4 is one; cmd_sender-like tools add a few. Stops a local
# process from growing the agent without bound with CREATE_CLIENTs of fresh keys.
MAX_SESSIONS: Final = 8
# Entities per session. PX4 with every topic of dds_topics.yaml (``-a``) creates ~200;
# stops a client from exhausting memory with CREATEs.
MAX_ENTITIES: Final = 1024
HEARTBEAT_PERIOD_S: Final = 0.2  # while our reliable output holds unacknowledged messages
# A session with no datagram for this long is gone (PX4 pings every 1 s when idle).
SESSION_TIMEOUT_S: Final = 10.0
# A bound vehicle session silent this long is dead, and the vehicle's key may open a new one
# from another address: PX4 (uxrce_dds_client.cpp checkConnectivity) pings every 1 s while its
# payloads do not flow both ways and disconnects at 3 missed pings; connected, it also sends
# TIMESTAMP every 1 s (run(): uxr_sync_session when last_sync_session > 1 s) and its samples.
# A live PX4 is never silent for 3 s; a restarted one (new port) is accepted on its first
# CREATE_CLIENT retry (PX4 retries every 1 s) after this much silence. Shorter would let a
# local process take a live vehicle's link over during a 3 s stall PX4 itself would ride out.
VEHICLE_DEAD_AFTER_S: Final = 3.0
STREAM_RELIABLE: Final = 0x80
SAMPLE_IDENTITY_SIZE: Final = 24  # GUID_t (16) + SequenceNumber_t (8), before service samples
# our requests' writer GUID: prefix "swarmd" + zero padding, entity 00 00 04 03 (a writer)
REQUESTER_GUID: Final = b"swarmd\0\0\0\0\0\0" + bytes((0, 0, 4, 3))
STREAM_BEST_EFFORT: Final = 0x01
# Refusals that depend on the key, left unanswered (bound agent): an answer would tell a
# prober its try was checked, and a different one for the right key would tell it the key.
# DDS-XRCE 1.0 §8.3.5.4 makes STATUS_AGENT the answer to every CREATE_CLIENT; leaving these
# out departs from it on purpose, and costs a real client nothing (it resends, as over any
# lossy transport). The refusals that do not look at the key (cookie, version, session id)
# are answered.
UNANSWERED: Final = frozenset({"wrong_key", "vehicle_alive", "over_budget"})


@dataclass(slots=True)
class Entity:
    object_id: int
    kind: int
    parent_id: int | None
    name: str | None = None  # topic name for topics; service name for repliers/requesters
    type_name: str | None = None
    topic_id: int | None = None  # writers and readers: the topic they serve
    reply_topic: str | None = None  # repliers: where their replies would go in DDS


@dataclass(slots=True)
class ReadRequest:
    request_id: int
    stream_id: int


@dataclass(slots=True)
class Session:
    source: Address
    client_key: bytes
    session_id: int
    mtu: int
    last_heard: float
    entities: dict[int, Entity] = field(default_factory=dict)
    reads: dict[int, ReadRequest] = field(default_factory=dict)
    rel_in: dict[int, ReliableIn] = field(default_factory=dict)
    be_in: dict[int, BestEffortIn] = field(default_factory=dict)
    rel_out: ReliableOut = field(default_factory=ReliableOut)
    be_out_seq: int = 0
    reassembly: dict[int, Reassembly] = field(default_factory=dict)
    heartbeat_at: float | None = None
    samples_in: int = 0
    samples_out: int = 0

    def topic_of(self, endpoint: Entity) -> Entity | None:
        return None if endpoint.topic_id is None else self.entities.get(endpoint.topic_id)


class XrceAgent(Endpoint):
    """The agent side of DDS-XRCE for PX4 clients (see the module docstring)."""

    def __init__(
        self,
        *,
        clock_offset_s: float = 0.0,
        expected_key: bytes | None = None,
        agent: AgentRepresentation | None = None,
        vehicle_uid: int | None = None,
    ) -> None:
        """``vehicle_uid``: the local user PX4 runs as when it is on this computer's
        loopback (SITL; ``px4.loopback_user``). Set, a loopback datagram from any other
        user, or from a socket the kernel no longer lists, is dropped before it is read
        (``dropped["foreign_user"]``): no other local user can ping the agent, try a key or
        spend the loopback's key-check budget, so a flood from every loopback port cannot
        keep a loopback PX4 out. Other origins (an FMU on Ethernet, the UART) are not
        affected."""
        # agent time = now + clock_offset_s: the driver passes wall time - monotonic time so
        # PX4's synchronised timestamps are Unix time, as with eProsima's agent
        self.clock_offset_s = clock_offset_s
        self.expected_key = expected_key
        self.vehicle_uid = vehicle_uid
        self.agent = agent or AgentRepresentation()
        super().__init__()
        self.sessions: dict[Address, Session] = {}
        # CREATE_CLIENTs refused by reason (wrong_key, vehicle_alive, over_budget, cookie, ...)
        self.refused: Counter[str] = Counter()
        # bound: how many client keys may be compared, per source and origin (keycheck.py)
        self.key_checks = KeyCheckBudget()
        self._request_seq = 0
        self.timestamps_answered = 0
        self.pings_answered = 0

    # ---- driving ----------------------------------------------------------------------------

    def receive_datagram(
        self, data: bytes, source: Address, now: float, sender_uid: int | None = None
    ) -> None:
        """``sender_uid``: the local user whose socket sent a loopback datagram (the
        adapter's lookup: swarmd.senderuid), None when unknown or not on loopback."""
        if (
            self.vehicle_uid is not None
            and sender_uid != self.vehicle_uid
            and origin_of(source) == LOOPBACK_ORIGIN
        ):
            # the kernel's word: another user's socket (or one already gone) sent it
            self._drop(source, "foreign_user")
            return
        try:
            header, offset = decode_header(data)
            parts, _pad = split_submessages(data, offset)
        except DecodeError as exc:
            self._drop(source, f"malformed: {exc}")
            return
        if header.session_id in (0x00, 0x80):
            self._sessionless(header, parts, source, now)
            return
        session = self.sessions.get(source)
        if session is None or session.session_id != header.session_id:
            self._drop(source, "no_session")
            return
        if header.session_id < 0x80 and header.client_key != session.client_key:
            self._drop(source, "wrong_key")
            return
        session.last_heard = now
        self._stream(session, header, data, offset, parts, now)

    def handle_timer(self, now: float) -> None:
        for source, s in list(self.sessions.items()):
            if now - s.last_heard >= SESSION_TIMEOUT_S:
                del self.sessions[source]
                self._emit(SessionEnded(source, s.client_key, "timeout"))
                continue
            if s.heartbeat_at is not None and now >= s.heartbeat_at:
                hb = s.rel_out.heartbeat()
                if hb is None:
                    s.heartbeat_at = None
                else:
                    self._send0(s, [Heartbeat(hb[0], hb[1], STREAM_RELIABLE)])
                    s.heartbeat_at = now + HEARTBEAT_PERIOD_S

    def get_timer(self) -> float | None:
        deadlines = [s.last_heard + SESSION_TIMEOUT_S for s in self.sessions.values()]
        deadlines += [s.heartbeat_at for s in self.sessions.values() if s.heartbeat_at]
        return min(deadlines, default=None)

    # ---- commands ----------------------------------------------------------------------------

    @property
    def bound(self) -> bool:
        """True when this agent serves one vehicle (``expected_key`` set)."""
        return self.expected_key is not None

    @property
    def vehicle(self) -> Session | None:
        """The bound vehicle's session (None: unbound, or no vehicle connected)."""
        if not self.bound:
            return None
        return next(iter(self.sessions.values()), None)

    def _targets(self) -> list[Session]:
        """Where commands go: the vehicle's session only when bound, else every session."""
        if self.bound:
            vehicle = self.vehicle
            return [] if vehicle is None else [vehicle]
        return list(self.sessions.values())

    def publish(
        self, topic_name: str, data: bytes, now: float, *, until: float | None = None
    ) -> int:
        """Send ``data`` to every reader of ``topic_name`` that asked (READ_DATA), in the bound
        vehicle's session only (every session when unbound). ``until``: on a reliable
        stream, repaired as itself only before that time, then as a message that does
        nothing (``ReliableOut``): a command's frame, worth sending while its sender waits.

        Returns how many readers it went to (0: nobody subscribed yet).
        """
        sent = 0
        for s in self._targets():
            for oid, req in s.reads.items():
                reader = s.entities.get(oid)
                if reader is None or reader.kind != ObjectKind.DATAREADER:
                    continue
                topic = s.topic_of(reader)
                if topic is None or topic.name != topic_name:
                    continue
                sub = Data(req.request_id, oid, data)
                if req.stream_id >= 0x80:
                    self._send_reliable(s, [sub], now, until)
                else:
                    self._send_best_effort(s, [sub])
                s.samples_out += 1
                sent += 1
        return sent

    def request(self, service: str, data: bytes, now: float, *, until: float | None = None) -> int:
        """Send a request to every client replier of ``service`` that asked (READ_DATA).

        eProsima's replier DATA carries the request's SampleIdentity (writer GUID, sequence
        number: 24 octets) before the sample; the replier echoes it in its reply. Bound: the
        vehicle's session only. ``until``: as for ``publish`` (PX4's replier reads on the
        reliable stream, so a request is repaired until then and never after).
        """
        sent = 0
        for s in self._targets():
            for oid, req in s.reads.items():
                replier = s.entities.get(oid)
                if replier is None or replier.kind != ObjectKind.REPLIER or replier.name != service:
                    continue
                self._request_seq += 1
                identity = REQUESTER_GUID + struct.pack("<iI", 0, self._request_seq & 0xFFFFFFFF)
                sub = Data(req.request_id, oid, identity + data)
                if req.stream_id >= 0x80:
                    self._send_reliable(s, [sub], now, until)
                else:
                    self._send_best_effort(s, [sub])
                sent += 1
        return sent

    def has_replier(self, service: str) -> bool:
        return any(
            e.kind == ObjectKind.REPLIER and e.name == service and oid in s.reads
            for s in self._targets()
            for oid, e in s.entities.items()
        )

    def close_session(self, source: Address) -> None:
        s = self.sessions.pop(source, None)
        if s is not None:
            self._emit(SessionEnded(source, s.client_key, "closed"))

    # ---- sessionless: ping and CREATE_CLIENT ---------------------------------------------------

    def _sessionless(
        self, header: Header, parts: list[tuple[int, int, bytes]], source: Address, now: float
    ) -> None:
        for sid, flags, payload in parts:
            try:
                sub = decode_submessage(sid, flags, payload)
            except DecodeError as exc:
                self._drop(source, f"malformed: {exc}")
                return
            if isinstance(sub, GetInfo):
                # §8.4.3 discovery/ping: answer with our representation and availability
                reply = Info(
                    sub.request_id, sub.object_id, Status.OK, 0, self.agent, availability=1
                )
                self._out.append((encode_message(header, [reply]), source))
                self.pings_answered += 1
            elif isinstance(sub, CreateClient):
                self._create_client(sub, source, now)
            else:
                self._drop(source, f"sessionless_{type(sub).__name__}")

    def _create_client(self, cc: CreateClient, source: Address, now: float) -> None:
        reply_header = Header(cc.session_id, 0, 0, cc.client_key if cc.session_id < 0x80 else None)
        status: int = Status.OK
        why = ""
        if cc.cookie != XRCE_COOKIE:
            status, why = Status.ERR_INVALID_DATA, "bad_cookie"
        elif cc.version[:1] != b"\x01":
            status, why = Status.ERR_INCOMPATIBLE, "incompatible_version"
        elif cc.session_id in (0x00, 0x80):
            status, why = Status.ERR_INVALID_DATA, "sessionless_id"
        elif self.expected_key is not None and not self.key_checks.allow(source, now):
            # over the budget: dropped before the key is looked at, unanswered (keycheck.py)
            self._refuse(source, cc.client_key, "over_budget")
            return
        elif self.expected_key is not None and cc.client_key != self.expected_key:
            status, why = Status.ERR_DENIED, "wrong_key"
        old = self.sessions.get(source)
        if status == Status.OK and old is None:
            if self.bound:
                status, why = self._take_over(cc, source, now)
            else:
                # unbound: the same key from a new address is that client restarted
                for addr, s in list(self.sessions.items()):
                    if s.client_key == cc.client_key:
                        del self.sessions[addr]
                        self._emit(SessionEnded(addr, s.client_key, "replaced"))
                if len(self.sessions) >= MAX_SESSIONS:
                    status, why = Status.ERR_RESOURCES, "too_many_sessions"
        if status != Status.OK:
            self._refuse(source, cc.client_key, why)
            if why not in UNANSWERED:
                reply = StatusAgent(status, 0, self.agent)
                self._out.append((encode_message(reply_header, [reply]), source))
            return
        if old is not None:
            self._emit(SessionEnded(source, old.client_key, "replaced"))
        # a CREATE_CLIENT always starts afresh: PX4 sends it after its own restart or ours
        self.sessions[source] = Session(source, cc.client_key, cc.session_id, cc.mtu, now)
        self._out.append((encode_message(reply_header, [StatusAgent(0, 0, self.agent)]), source))
        self._emit(SessionCreated(source, cc.client_key, cc.session_id, cc.mtu))

    def _take_over(self, cc: CreateClient, source: Address, now: float) -> tuple[int, str]:
        """Bound, the vehicle's key from an address with no session: accepted when no vehicle
        session exists or it is dead (silent ``VEHICLE_DEAD_AFTER_S``), which then ends."""
        for addr, s in list(self.sessions.items()):
            if now - s.last_heard < VEHICLE_DEAD_AFTER_S:
                # unanswered as a wrong key is: no key oracle (module docstring)
                return Status.ERR_DENIED, "vehicle_alive"
            del self.sessions[addr]
            self._emit(SessionEnded(addr, s.client_key, "replaced"))
        return Status.OK, ""

    def _refuse(self, source: Address, client_key: bytes, why: str) -> None:
        self.refused[why] += 1
        self._drop(source, f"create_client_refused:{why}")
        self._emit(ClientRefused(source, client_key, why))

    # ---- in session ----------------------------------------------------------------------------

    def _stream(
        self,
        s: Session,
        header: Header,
        data: bytes,
        offset: int,
        parts: list[tuple[int, int, bytes]],
        now: float,
    ) -> None:
        stream = header.stream_id
        fresh = receive_stream(
            header, data, offset, parts, reliable=s.rel_in, best_effort=s.be_in,
            handle=lambda p: self._handle(s, p, stream, now),
            reply=lambda _h, subs: self._send0(s, subs),
        )  # fmt: skip
        if not fresh:
            self._drop(s.source, "stale_best_effort")

    def _handle(
        self, s: Session, parts: list[tuple[int, int, bytes]], stream: int, now: float
    ) -> None:
        for sid, flags, payload in parts:
            try:
                sub = decode_submessage(sid, flags, payload)
            except DecodeError as exc:
                self._drop(s.source, f"malformed: {exc}")
                continue
            self._submessage(s, sub, stream, now)
            if s.source not in self.sessions:
                return  # deleted by this submessage

    def _submessage(self, s: Session, sub: Submessage, stream: int, now: float) -> None:
        match sub:
            case WriteData():
                self._write_data(s, sub)
            case Timestamp():
                # §8.3.5.16: agent receive and transmit times, the client's time echoed; the
                # same instant, since nothing runs between them (PX4 wants < 10 ms round trips)
                t = Time.from_ns(round((now + self.clock_offset_s) * 1e9))
                self._send0(s, [TimestampReply(t, t, sub.transmit)])
                self.timestamps_answered += 1
            case GetInfo():
                # in-session ping (PX4 fork): implementation_status != 0 = "session alive",
                # availability > 0, or PX4 counts a missed ping
                # (activity is sent whatever the mask: the fork reads availability regardless)
                info = Info(sub.request_id, sub.object_id, Status.OK, 1, self.agent, 1)
                self._send0(s, [info])
                self.pings_answered += 1
            case Create():
                self._create(s, sub, now)
            case ReadData():
                s.reads[sub.object_id] = ReadRequest(sub.request_id, sub.preferred_stream_id)
            case Delete():
                if sub.object_id == OBJECT_ID_CLIENT:
                    self._send0(s, [StatusReply(sub.request_id, sub.object_id, Status.OK)])
                    del self.sessions[s.source]
                    self._emit(SessionEnded(s.source, s.client_key, "deleted"))
                    return
                found = s.entities.pop(sub.object_id, None) is not None
                s.reads.pop(sub.object_id, None)
                st = Status.OK if found else Status.ERR_UNKNOWN_REFERENCE
                self._send_reliable(s, [StatusReply(sub.request_id, sub.object_id, st)], now)
            case AckNack():
                if sub.stream_id == STREAM_RELIABLE:
                    expired = s.rel_out.expired
                    for msg in s.rel_out.on_acknack(sub.first_unacked, sub.nack_bitmap, now):
                        self._out.append((msg, s.source))
                    self.stand_ins += s.rel_out.expired - expired
                    if s.rel_out.heartbeat() is None:
                        s.heartbeat_at = None
            case Heartbeat():
                rin = s.rel_in.setdefault(sub.stream_id, ReliableIn())
                rin.on_heartbeat(sub.first_unacked, sub.last_unacked)
                first, bitmap = rin.acknack(sub.last_unacked)
                self._send0(s, [AckNack(first, bitmap, sub.stream_id)])
            case Fragment():
                asm = s.reassembly.setdefault(stream, Reassembly())
                whole = asm.add(sub.data, sub.last)
                if asm.overflows:
                    self._drop(s.source, "reassembly_overflow")
                    asm.overflows = 0
                if whole is not None:
                    try:
                        parts, _pad = split_submessages(whole, 0)
                    except DecodeError as exc:
                        self._drop(s.source, f"malformed_fragment: {exc}")
                        return
                    self._handle(s, parts, stream, now)
            case Reset():
                s.rel_in.clear()
                s.be_in.clear()
            case _:
                self._drop(s.source, f"unexpected_{type(sub).__name__}")

    def _create(self, s: Session, c: Create, now: float) -> None:
        status = Status.OK
        entity = Entity(c.object_id, c.kind, c.parent_id)
        try:
            if c.repr_format == Repr.BIN and isinstance(c.representation, bytes):
                blob = c.representation
                if c.kind == ObjectKind.TOPIC:
                    t = parse_topic(blob)
                    entity.name, entity.type_name = t.topic_name, t.type_name
                elif c.kind in (ObjectKind.DATAWRITER, ObjectKind.DATAREADER):
                    e = parse_endpoint(blob, writer=c.kind == ObjectKind.DATAWRITER)
                    entity.topic_id = e.topic_id
                elif c.kind in (ObjectKind.REPLIER, ObjectKind.REQUESTER):
                    sv = parse_service(blob)
                    entity.name, entity.type_name = sv.service_name, sv.reply_type
                    entity.reply_topic = sv.reply_topic_name or f"rr/{sv.service_name}Reply"
        except DecodeError as exc:
            status = Status.ERR_INVALID_DATA
            self._drop(s.source, f"bad_representation: {exc}")
        if status == Status.OK and c.object_id not in s.entities:
            if len(s.entities) >= MAX_ENTITIES:
                status = Status.ERR_RESOURCES
        if status == Status.OK:
            # REPLACE (PX4 always sets it) or REUSE: either way the client gets its entity
            s.entities[c.object_id] = entity
        reply = StatusReply(c.request_id, c.object_id, status)
        self._send_reliable(s, [reply], now)
        name = entity.name
        if entity.topic_id is not None and (topic := s.topic_of(entity)) is not None:
            name, entity.type_name = topic.name, topic.type_name
        self._emit(EntityCreated(s.source, c.object_id, c.kind, name, entity.type_name, status))

    def _write_data(self, s: Session, w: WriteData) -> None:
        writer = s.entities.get(w.object_id)
        if writer is not None and writer.kind == ObjectKind.REPLIER and writer.reply_topic:
            if len(w.data) < SAMPLE_IDENTITY_SIZE:
                self._drop(s.source, "short_reply")
                return
            # the reply after the echoed SampleIdentity, under the service's reply topic name
            data = w.data[SAMPLE_IDENTITY_SIZE:]
            s.samples_in += 1
            self._emit(SampleReceived(s.source, writer.reply_topic, writer.type_name or "", data))
            return
        if writer is None or object_kind(w.object_id) != ObjectKind.DATAWRITER:
            self._drop(s.source, "write_unknown_writer")
            return
        topic = s.topic_of(writer)
        if topic is None or topic.name is None:
            self._drop(s.source, "write_unknown_topic")
            return
        s.samples_in += 1
        self._emit(SampleReceived(s.source, topic.name, topic.type_name or "", w.data))

    # ---- output ----------------------------------------------------------------------------

    def _header(self, s: Session, stream: int, seq: int) -> Header:
        return Header(s.session_id, stream, seq, s.client_key if s.session_id < 0x80 else None)

    def _send0(self, s: Session, subs: list[Submessage]) -> None:
        self._out.append((encode_message(self._header(s, 0, 0), subs), s.source))

    def _send_best_effort(self, s: Session, subs: list[Submessage]) -> None:
        seq = s.be_out_seq
        s.be_out_seq = seq_add(seq, 1)
        self._out.append((encode_message(self._header(s, STREAM_BEST_EFFORT, seq), subs), s.source))

    def _send_reliable(
        self, s: Session, subs: list[Submessage], now: float, until: float | None = None
    ) -> None:
        seq = s.rel_out.next_seq
        header = self._header(s, STREAM_RELIABLE, seq)
        msg = encode_message(header, subs)
        s.rel_out.push(msg, None if until is None else (until, stand_in(header)))
        self._out.append((msg, s.source))
        if s.heartbeat_at is None:
            s.heartbeat_at = now + HEARTBEAT_PERIOD_S
