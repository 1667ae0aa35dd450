"""A sans-IO DDS-XRCE client: swarmd as a second client of an existing MicroXRCEAgent.

Theory of operation (DDS-XRCE 1.0 §8.4, the way Micro XRCE-DDS's client does it):
CREATE_CLIENT (session 0x81, our key) every ``CONNECT_PERIOD_S`` until STATUS_AGENT; then,
on the reliable stream 0x80, a participant by XML confined to 127.0.0.1 (its DDS discovery
never leaves the host), and per subscription a topic, subscriber and data reader followed by
READ_DATA (samples come back as DATA on best-effort stream 0x01), per publication a topic,
publisher and data writer. ``publish`` sends WRITE_DATA on the reliable stream. The agent's
reliable output is ACKNACKed; ours is retransmitted on NACK and announced by HEARTBEAT.
An in-session GET_INFO every ``PING_PERIOD_S``; ``MISSED_PINGS`` unanswered start over (the
agent restarted), as PX4 does.

Driving sources: ``receive_datagram(data, source, now)``, ``handle_timer(now)``, and the
``connect``/``publish``/``disconnect`` commands. Outputs: ``datagrams_to_send()``,
``get_timer()``, ``next_event()``. Network input never raises (``PacketDropped``).
"""

from __future__ import annotations

from typing import Final

from swarmd.xrce.binary import (
    QOS_HISTORY_KEEP_LAST,
    QOS_RELIABLE,
    EndpointBinary,
    GroupBinary,
    TopicBinary,
    encode_endpoint,
    encode_group,
    encode_topic,
)
from swarmd.xrce.buffer import DecodeError
from swarmd.xrce.endpoint import Endpoint, receive_stream, stand_in
from swarmd.xrce.events import (
    Address,
    EntityCreated,
    SampleReceived,
    SessionCreated,
    SessionEnded,
)
from swarmd.xrce.message import (
    OBJECT_ID_AGENT,
    OBJECT_ID_CLIENT,
    AckNack,
    Create,
    CreateClient,
    Data,
    Delete,
    DeliveryControl,
    GetInfo,
    Header,
    Heartbeat,
    Info,
    ObjectKind,
    ReadData,
    Repr,
    Status,
    StatusAgent,
    StatusReply,
    Submessage,
    WriteData,
    decode_header,
    decode_submessage,
    encode_message,
    object_id,
    split_submessages,
)
from swarmd.xrce.streams import BestEffortIn, ReliableIn, ReliableOut, seq_add

SESSION_ID: Final = 0x81
STREAM_RELIABLE: Final = 0x80
STREAM_BEST_EFFORT: Final = 0x01
CONNECT_PERIOD_S: Final = 1.0
PING_PERIOD_S: Final = 1.0
MISSED_PINGS: Final = 3
HEARTBEAT_PERIOD_S: Final = 0.2
LOCALHOST_PARTICIPANT: Final = (
    "<dds><profiles><transport_descriptors><transport_descriptor>"
    "<transport_id>swarmd_localhost</transport_id><type>UDPv4</type>"
    "<interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>"
    "</transport_descriptor></transport_descriptors></profiles>"
    "<participant><rtps><name>{name}</name><useBuiltinTransports>false</useBuiltinTransports>"
    "<userTransports><transport_id>swarmd_localhost</transport_id></userTransports>"
    "</rtps></participant></dds>"
)
PARTICIPANT_ID: Final = object_id(0x001, ObjectKind.PARTICIPANT)


class XrceClient(Endpoint):
    """The client side of DDS-XRCE (see the module docstring)."""

    def __init__(
        self,
        client_key: bytes,
        *,
        subscriptions: dict[str, str],
        publications: dict[str, str],
        domain_id: int = 0,
        participant_name: str = "/swarmd",
        mtu: int = 512,
    ) -> None:
        super().__init__()
        self.client_key = client_key
        self.subscriptions = dict(subscriptions)  # topic name -> type name
        self.publications = dict(publications)
        self.domain_id = domain_id
        self.participant_name = participant_name
        self.mtu = mtu  # CREATE_CLIENT's MTU (PX4's client announces 508: 512 minus framing)
        self.agent: Address | None = None
        self.state = "idle"  # idle | connecting | established
        self._request = 0
        self._readers: dict[int, str] = {}  # reader object id -> topic name
        self._writers: dict[str, int] = {}  # topic name -> writer object id
        self._pending: dict[int, int] = {}  # request id -> object id awaiting STATUS
        self._reset_streams()
        self._connect_at: float | None = None
        self._ping_at: float | None = None
        self._pings_missed = 0
        self._heartbeat_at: float | None = None
        self.refused = 0

    def _reset_streams(self) -> None:
        self._rel_out = ReliableOut()
        self._rel_in = ReliableIn()
        self._be_in = BestEffortIn()
        self._be_out_seq = 0

    # ---- commands ----------------------------------------------------------------------------

    def connect(self, agent: Address, now: float) -> None:
        self.agent = agent
        self.state = "connecting"
        self._send_create_client(now)

    def disconnect(self, now: float) -> None:
        if self.state == "established":
            self._send0([Delete(self._next_request(), OBJECT_ID_CLIENT)])
            self._events.append(SessionEnded(self.agent, self.client_key, "deleted"))
        self.state = "idle"
        self._connect_at = self._ping_at = self._heartbeat_at = None

    def publish(
        self, topic_name: str, data: bytes, now: float, *, until: float | None = None
    ) -> int:
        """WRITE_DATA on the reliable stream. ``until``: repaired as itself only before that
        time, then as a message that does nothing (``ReliableOut``; a command's frame)."""
        oid = self._writers.get(topic_name)
        if self.state != "established" or oid is None:
            return 0
        self._send_reliable([WriteData(self._next_request(), oid, data)], now, until)
        return 1

    # ---- driving ----------------------------------------------------------------------------

    def receive_datagram(self, data: bytes, source: Address, now: float) -> None:
        if source != self.agent:
            self._drop(source, "not_our_agent")
            return
        try:
            header, offset = decode_header(data)
            parts, _pad = split_submessages(data, offset)
        except DecodeError as exc:
            self._drop(source, f"malformed: {exc}")
            return
        if header.session_id != SESSION_ID:
            self._drop(source, "other_session")
            return
        receive_stream(
            header, data, offset, parts,
            reliable={STREAM_RELIABLE: self._rel_in}, best_effort={1: self._be_in},
            handle=lambda p: self._handle(p, now), reply=lambda _h, subs: self._send0(subs),
        )  # fmt: skip

    def handle_timer(self, now: float) -> None:
        if self._connect_at is not None and now >= self._connect_at:
            self._send_create_client(now)
        if self._ping_at is not None and now >= self._ping_at:
            self._pings_missed += 1
            if self._pings_missed > MISSED_PINGS:
                self._events.append(SessionEnded(self.agent, self.client_key, "agent_lost"))
                self.state = "connecting"
                self._ping_at = self._heartbeat_at = None
                self._send_create_client(now)
                return
            self._send0([GetInfo(self._ping_request_id(), OBJECT_ID_AGENT, 0x02)])
            self._ping_at = now + PING_PERIOD_S
        if self._heartbeat_at is not None and now >= self._heartbeat_at:
            hb = self._rel_out.heartbeat()
            if hb is None:
                self._heartbeat_at = None
            else:
                self._send0([Heartbeat(hb[0], hb[1], STREAM_RELIABLE)])
                self._heartbeat_at = now + HEARTBEAT_PERIOD_S

    def get_timer(self) -> float | None:
        times = [t for t in (self._connect_at, self._ping_at, self._heartbeat_at) if t is not None]
        return min(times, default=None)

    # ---- internals ----------------------------------------------------------------------------

    def _handle(self, parts: list[tuple[int, int, bytes]], now: float) -> None:
        for sid, flags, payload in parts:
            try:
                sub = decode_submessage(sid, flags, payload)
            except DecodeError as exc:
                self._drop(self.agent, f"malformed: {exc}")
                continue
            match sub:
                case StatusAgent():
                    self._status_agent(sub, now)
                case StatusReply():
                    self._status(sub)
                case Data():
                    topic = self._readers.get(sub.object_id)
                    if topic is None:
                        self._drop(self.agent, "data_unknown_reader")
                    else:
                        typ = self.subscriptions.get(topic, "")
                        self._emit(SampleReceived(self.agent, topic, typ, sub.data))
                case AckNack():
                    if sub.stream_id == STREAM_RELIABLE:
                        expired = self._rel_out.expired
                        for msg in self._rel_out.on_acknack(
                            sub.first_unacked, sub.nack_bitmap, now
                        ):
                            self._out.append((msg, self.agent))
                        self.stand_ins += self._rel_out.expired - expired
                case Heartbeat():
                    self._rel_in.on_heartbeat(sub.first_unacked, sub.last_unacked)
                    first, bitmap = self._rel_in.acknack(sub.last_unacked)
                    self._send0([AckNack(first, bitmap, sub.stream_id)])
                case Info():
                    if sub.implementation_status and (sub.availability or 0) > 0:
                        self._pings_missed = 0
                case _:
                    self._other_submessage(sub, now)

    def _other_submessage(self, sub: Submessage, now: float) -> None:
        """A submessage this engine does not handle (TIMESTAMP_REPLY and the like): nothing
        asked for it here; a subclass that sends TIMESTAMP (PX4's time sync) reads it."""

    def _ping_request_id(self) -> int:
        """The in-session GET_INFO's request id: a fresh one (PX4's client always uses 10)."""
        return self._next_request()

    def _status_agent(self, sa: StatusAgent, now: float) -> None:
        if self.state != "connecting":
            return
        if sa.status != Status.OK:
            self.refused += 1
            self._drop(self.agent, f"refused:{sa.status}")
            return
        self.state = "established"
        self._connect_at = None
        self._ping_at = now + PING_PERIOD_S
        self._pings_missed = 0
        self._reset_streams()
        self._readers.clear()
        self._writers.clear()
        self._emit(SessionCreated(self.agent, self.client_key, SESSION_ID, 512))
        self._create_entities(now)

    def _status(self, st: StatusReply) -> None:
        oid = self._pending.pop(st.request_id, None)
        if oid is None:
            return
        self._emit(EntityCreated(self.agent, oid, oid & 0xF, None, None, st.status))

    def _create_entities(self, now: float) -> None:
        xml = LOCALHOST_PARTICIPANT.format(name=self.participant_name)
        self._create(
            Create(self._next_request(), PARTICIPANT_ID, ObjectKind.PARTICIPANT, Repr.XML, xml,
                   domain_id=self.domain_id, replace=True),
            now,
        )  # fmt: skip
        for i, (topic, typ) in enumerate(sorted(self.subscriptions.items())):
            rid = self._create_endpoint(0x100 + i, topic, typ, writer=False, now=now)
            self._readers[rid] = topic
            # unlimited samples, as PX4 asks; without delivery control the agent sends one
            read = ReadData(self._next_request(), rid, STREAM_BEST_EFFORT,
                            delivery_control=DeliveryControl(max_samples=0xFFFF))  # fmt: skip
            self._send_reliable([read], now)
        for j, (topic, typ) in enumerate(sorted(self.publications.items())):
            self._writers[topic] = self._create_endpoint(
                0x200 + j, topic, typ, writer=True, now=now
            )

    def _create_endpoint(
        self, ident: int, topic: str, typ: str, *, writer: bool, now: float
    ) -> int:
        """A topic, its group (subscriber or publisher) and the data reader or writer in it,
        all under object id ``ident`` and by binary representation; the endpoint's object id.
        Both keep the last 10; the writer (``vehicle_command``) is reliable, the readers are
        best-effort."""
        tid = self._topic(ident, topic, typ, now)
        if writer:
            group, kind = ObjectKind.PUBLISHER, ObjectKind.DATAWRITER
            qos = QOS_RELIABLE | QOS_HISTORY_KEEP_LAST
        else:
            group, kind = ObjectKind.SUBSCRIBER, ObjectKind.DATAREADER
            qos = QOS_HISTORY_KEEP_LAST
        gid = object_id(ident, group)
        self._create_bin(gid, group, encode_group(GroupBinary()), PARTICIPANT_ID, now)
        eid = object_id(ident, kind)
        endpoint = EndpointBinary(tid, writer, qos, 10)
        self._create_bin(eid, kind, encode_endpoint(endpoint), gid, now)
        return eid

    def _topic(self, ident: int, topic: str, typ: str, now: float) -> int:
        tid = object_id(ident, ObjectKind.TOPIC)
        blob = encode_topic(TopicBinary(topic, typ))
        self._create_bin(tid, ObjectKind.TOPIC, blob, PARTICIPANT_ID, now)
        return tid

    def _create_bin(self, oid: int, kind: int, blob: bytes, parent: int, now: float) -> None:
        req = self._next_request()
        self._create(Create(req, oid, kind, Repr.BIN, blob, parent_id=parent, replace=True), now)

    def _create(self, c: Create, now: float) -> None:
        self._pending[c.request_id] = c.object_id
        self._send_reliable([c], now)

    def _send_create_client(self, now: float) -> None:
        cc = CreateClient(self.client_key, SESSION_ID, self.mtu)
        if self.agent is not None:
            self._out.append((encode_message(Header(0x80, 0, 0), [cc]), self.agent))
        self._connect_at = now + CONNECT_PERIOD_S

    def _next_request(self) -> int:
        self._request = (self._request + 1) & 0xFFFF or 1
        return self._request

    def _header(self, stream: int, seq: int) -> Header:
        return Header(SESSION_ID, stream, seq)

    def _send0(self, subs: list[Submessage]) -> None:
        if self.agent is not None:
            self._out.append((encode_message(self._header(0, 0), subs), self.agent))

    def _send_reliable(
        self, subs: list[Submessage], now: float, until: float | None = None
    ) -> None:
        header = self._header(STREAM_RELIABLE, self._rel_out.next_seq)
        msg = encode_message(header, subs)
        self._rel_out.push(msg, None if until is None else (until, stand_in(header)))
        if self.agent is not None:
            self._out.append((msg, self.agent))
        if self._heartbeat_at is None:
            self._heartbeat_at = now + HEARTBEAT_PERIOD_S

    def _send_best_effort(self, subs: list[Submessage]) -> None:
        seq, self._be_out_seq = self._be_out_seq, seq_add(self._be_out_seq, 1)
        msg = encode_message(self._header(STREAM_BEST_EFFORT, seq), subs)
        if self.agent is not None:
            self._out.append((msg, self.agent))
