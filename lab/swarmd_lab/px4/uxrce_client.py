"""PX4's ``uxrce_dds_client`` as a sans-IO engine on swarmd's XRCE client (lab: the stand-in).

Not PX4: the session, streams and entities PX4's client creates, call for call and byte for
byte where the recorded session (``../shared/peers/xrce/golden/px4-1.16-core``, PX4 v1.16's
sequence against eProsima's MicroXRCEAgent) pins them, so swarmd's agent can be tested
against PX4's wire without PX4.

Theory of operation (DDS-XRCE 1.0 §8.4, the way PX4's client drives it):
1. a session-less GET_INFO ping (request id 10) every second until the agent answers INFO;
2. CREATE_CLIENT (session 0x81, ``UXRCE_DDS_KEY``, MTU 508) until STATUS_AGENT;
3. on reliable stream 0x80 the participant (XML: localhost-only with ``UXRCE_DDS_PTCFG=1``),
   request id 10, and its STATUS;
4. time sync: TIMESTAMP every 10 ms, replies slower than 10 ms discarded, until 500 good
   samples (PX4 ``Timesync``); then one a second for the rest of the session;
5. per subscription one reliable message TOPIC + SUBSCRIBER + DATAREADER, all STATUS awaited
   (1 s each batch, PX4 ``uxr_run_session_until_all_status``), its READ_DATA buffered and
   sent with the next message; from 1.15 per publication TOPIC + PUBLISHER + DATAWRITER the
   same way and the ``vehicle_command`` REPLIER (its READ_DATA on the reliable stream);
   1.14 creates a writer lazily, when its topic first publishes (and has no replier);
6. samples as WRITE_DATA on best-effort stream 0x01, service replies on the reliable stream;
   an in-session GET_INFO (request id 10) every second; 3 missed starts over.
A refused or unanswered CREATE aborts the set-up (PX4 deletes the session and starts over).

Driving sources: ``receive_datagram(data, source, now)``, ``handle_timer(now)``, the
``connect``/``publish_sample``/``reply``/``disconnect`` commands. Outputs:
``datagrams_to_send()``, ``get_timer()``, ``next_event()`` (``SampleReceived`` for commands).
Network input never raises (the base engine counts and drops what does not decode).
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass
from typing import Final

from swarmd.xrce.binary import (
    EndpointBinary,
    GroupBinary,
    ServiceBinary,
    TopicBinary,
    encode_endpoint,
    encode_group,
    encode_service,
    encode_topic,
)
from swarmd.xrce.buffer import DecodeError
from swarmd.xrce.client import SESSION_ID, STREAM_BEST_EFFORT, XrceClient
from swarmd.xrce.events import Address, SessionEnded
from swarmd.xrce.message import (
    OBJECT_ID_AGENT,
    OBJECT_ID_CLIENT,
    Create,
    Delete,
    DeliveryControl,
    GetInfo,
    Header,
    Info,
    ObjectKind,
    ReadData,
    Repr,
    Status,
    StatusReply,
    Submessage,
    SubmessageId,
    Time,
    Timestamp,
    TimestampReply,
    WriteData,
    decode_header,
    decode_submessage,
    encode_message,
    object_id,
    split_submessages,
)
from swarmd.xrce.px4 import dds_topic, dds_type
from swarmd.xrce.px4_layouts import LAYOUTS

PX4_REQUEST_ID: Final = 0x000A  # PX4's pings and its participant's CREATE (golden)
PX4_MTU: Final = 508  # CREATE_CLIENT's MTU as PX4 announces it (golden)
PING_PERIOD_S: Final = 1.0
TIMESYNC_FAST_S: Final = 0.010  # until converged (golden: ~10.5 ms apart)
TIMESYNC_SLOW_S: Final = 1.0  # afterwards (golden)
TIMESYNC_SAMPLES: Final = 500  # PX4 Timesync CONVERGENCE_WINDOW
TIMESYNC_MAX_RTT_S: Final = 0.010  # PX4 Timesync MAX_RTT_SAMPLE: slower replies discarded
ALPHA_INITIAL: Final = 0.05  # PX4 Timesync ALPHA_GAIN_INITIAL .. ALPHA_GAIN_FINAL
ALPHA_FINAL: Final = 0.003
CREATE_TIMEOUT_S: Final = 1.0  # each batch of CREATEs waits this long for its STATUS
RESTART_AFTER_S: Final = 1.0  # a failed set-up starts over after this
MAX_LAZY_SAMPLES: Final = 16  # 1.14: samples held while their writer is being created
READER_QOS: Final = 0x02  # golden: best effort, keep last, depth 16
READER_DEPTH: Final = 16
WRITER_QOS: Final = 0x0A  # golden
PARTICIPANT_NAME: Final = "px4_micro_xrce_dds"
LOCALHOST_XML: Final = (
    "<dds><profiles><transport_descriptors><transport_descriptor>"
    "<transport_id>udp_localhost</transport_id><type>UDPv4</type>"
    "<interfaceWhiteList><address>127.0.0.1</address></interfaceWhiteList>"
    "</transport_descriptor></transport_descriptors></profiles>"
    "<participant><rtps><name>{name}</name><useBuiltinTransports>false</useBuiltinTransports>"
    "<userTransports><transport_id>udp_localhost</transport_id></userTransports>"
    "</rtps></participant></dds>"
)
DEFAULT_XML: Final = "<dds><participant><rtps><name>{name}</name></rtps></participant></dds>"


@dataclass(frozen=True, slots=True)
class TopicSpec:
    """A uORB topic on the bridge: its message and the object id PX4 gives its entities."""

    topic: str
    message: str
    ident: int


# The core set, in PX4's dds_topics.yaml order, with the object ids of the golden session
# (PX4 numbers them from its build's uORB ids; the agent does not interpret them).
CORE_SUBSCRIPTIONS: Final = (TopicSpec("vehicle_command", "VehicleCommand", 0x814),)
CORE_PUBLICATIONS: Final = (
    TopicSpec("battery_status", "BatteryStatus", 0x014),
    TopicSpec("failsafe_flags", "FailsafeFlags", 0x049),
    TopicSpec("timesync_status", "TimesyncStatus", 0x0DE),
    TopicSpec("vehicle_land_detected", "VehicleLandDetected", 0x0F6),
    TopicSpec("vehicle_command_ack", "VehicleCommandAck", 0x0EF),
    TopicSpec("vehicle_gps_position", "SensorGps", 0x0F3),
    TopicSpec("vehicle_status", "VehicleStatus", 0x0FD),
)
REPLIER_IDENT: Final = 0x800
SERVICE: Final = "vehicle_command"
REQUEST_TYPE: Final = "px4_msgs::srv::dds_::VehicleCommand_Request_"
REPLY_TYPE: Final = "px4_msgs::srv::dds_::VehicleCommand_Response_"
TIMESYNC_STATUS_SIZE: Final = 44  # TimesyncStatus (v1.14..v1.17): u64, u8, u64, i64, i64, u32


def _pad4(data: bytes) -> bytes:
    if len(data) > 4 and data[4] == SubmessageId.ACKNACK:
        return data
    return data + bytes(-len(data) % 4)


def message_version(release: str, message: str) -> int:
    """The ``_vN`` suffix of ``message`` in ``release`` (0 for messages swarmd never reads)."""
    layout = LAYOUTS[release].get(message)
    return 0 if layout is None else layout[1]


def has_replier(release: str) -> bool:
    """PX4 offers the ``vehicle_command`` service from 1.15."""
    return release != "1.14"


def lazy_writers(release: str) -> bool:
    """PX4 1.14 creates a data writer when its topic first publishes; later ones at set-up."""
    return release == "1.14"


class Px4UxrceClient(XrceClient):
    """PX4's uXRCE-DDS client side (see the module docstring)."""

    def __init__(
        self,
        release: str,
        key: int,
        *,
        boot: float,
        namespace: str | None = None,
        localhost_only: bool = True,
        domain_id: int = 0,
    ) -> None:
        if release not in LAYOUTS:
            raise ValueError(f"PX4 release {release!r}: one of {', '.join(LAYOUTS)}")
        ns = f"/{namespace}" if namespace else ""
        self.release = release
        self.namespace = namespace
        self.localhost_only = localhost_only
        self.boot = boot  # PX4's hrt clock starts here (monotonic seconds)
        self.names = {
            s.topic: dds_topic(s.topic, "out", message_version(release, s.message), namespace)
            for s in CORE_PUBLICATIONS
        } | {
            s.topic: dds_topic(s.topic, "in", message_version(release, s.message), namespace)
            for s in CORE_SUBSCRIPTIONS
        }
        prefix = f"{namespace}/" if namespace else ""
        self.request_topic = f"rq/{prefix}fmu/{SERVICE}Request"
        self.reply_topic = f"rr/{prefix}fmu/{SERVICE}Reply"
        super().__init__(
            key.to_bytes(4, "big"),
            subscriptions={self.names[s.topic]: dds_type(s.message) for s in CORE_SUBSCRIPTIONS},
            publications={self.names[s.topic]: dds_type(s.message) for s in CORE_PUBLICATIONS},
            domain_id=domain_id,
            participant_name=f"{ns}/{PARTICIPANT_NAME}",
            mtu=PX4_MTU,
        )
        self.phase = "idle"  # idle | pinging | connecting | participant | timesync | entities
        #                      | running
        self.offset_ns: int | None = None  # agent clock - hrt clock, once sampled
        self.timesync_good = 0
        self.timesync_rtt_ns = 0
        self.last_observed_offset_ns = 0
        self.failures: list[str] = []
        self._ping0_at: float | None = None
        self._sync_at: float | None = None
        self._batch_deadline: float | None = None
        self._restart_at: float | None = None
        self._waiting: dict[int, str] = {}  # request id -> what it creates
        self._buffered: list[Submessage] = []  # reliable submessages PX4 has not flushed yet
        self._steps: deque[tuple[str, list[Create], Submessage | None]] = deque()
        self._after: Submessage | None = None  # READ_DATA of the batch under way
        self._lazy: dict[str, deque[bytes]] = {}  # 1.14: topic -> samples awaiting a writer
        self._replier: int | None = None
        self._abort_pending: str | None = None  # a refused CREATE, acted on after its message

    # ---- clocks --------------------------------------------------------------------------

    def hrt_ns(self, now: float) -> int:
        """PX4's boot clock (``hrt_absolute_time``) in nanoseconds."""
        return round((now - self.boot) * 1e9)

    def timestamp_us(self, now: float) -> int:
        """A sample's timestamp: PX4's clock moved to the agent's once synced (µs)."""
        return (self.hrt_ns(now) + (self.offset_ns or 0)) // 1000

    @property
    def running(self) -> bool:
        return self.phase == "running"

    # ---- commands ------------------------------------------------------------------------

    def connect(self, agent: Address, now: float) -> None:
        self.agent = agent
        self.state = "idle"
        self.phase = "pinging"
        self._send_ping0(now)

    def disconnect(self, now: float) -> None:
        super().disconnect(now)
        self.phase = "idle"
        self._ping0_at = self._sync_at = self._batch_deadline = self._restart_at = None

    def publish_sample(self, topic: str, data: bytes, now: float) -> bool:
        """Write a sample of uORB ``topic``; False when PX4 would not (not running)."""
        if not self.running:
            return False
        name = self.names[topic]
        oid = self._writers.get(name)
        if oid is not None:
            self._send_best_effort([WriteData(self._next_request(), oid, data)])
            return True
        if not lazy_writers(self.release):
            return False
        queue = self._lazy.get(topic)
        if queue is None:  # first sample: create its writer, as PX4 1.14's send() does
            queue = self._lazy[topic] = deque(maxlen=MAX_LAZY_SAMPLES)
            spec = next(s for s in CORE_PUBLICATIONS if s.topic == topic)
            self._steps.append((f"writer {name}", self._endpoint(spec, writer=True), None))
            if self._batch_deadline is None:
                self._next_step(now)
        queue.append(data)
        return True

    def reply(self, identity: bytes, data: bytes, now: float) -> bool:
        """A ``vehicle_command`` service reply: the request's SampleIdentity, then the ack."""
        if self._replier is None or not self.running:
            return False
        self._send_reliable([WriteData(self._next_request(), self._replier, identity + data)], now)
        return True

    # ---- driving -------------------------------------------------------------------------

    def datagrams_to_send(self) -> list[tuple[bytes, Address]]:
        """As Micro XRCE-DDS writes them: a message ends 4-aligned (its serialisation buffer
        pads the last submessage), except a lone ACKNACK (golden: 13-octet datagrams)."""
        return [(_pad4(data), addr) for data, addr in super().datagrams_to_send()]

    def receive_datagram(self, data: bytes, source: Address, now: float) -> None:
        if self.phase == "pinging" and source == self.agent and data[:1] == b"\x80":
            self._pong0(data, source, now)
            return
        super().receive_datagram(data, source, now)

    def handle_timer(self, now: float) -> None:
        if self._restart_at is not None and now >= self._restart_at:
            self._restart_at = None
            self.phase = "pinging"
            self._send_ping0(now)
        if self._ping0_at is not None and now >= self._ping0_at:
            self._send_ping0(now)
        if self._batch_deadline is not None and now >= self._batch_deadline:
            self._abort(f"no STATUS within {CREATE_TIMEOUT_S:g} s for {self._describe()}", now)
        if self._sync_at is not None and now >= self._sync_at:
            self._send0([Timestamp(Time.from_ns(self.hrt_ns(now)))])
            converged = self.timesync_good >= TIMESYNC_SAMPLES
            self._sync_at = now + (TIMESYNC_SLOW_S if converged else TIMESYNC_FAST_S)
        was = self.state
        super().handle_timer(now)
        if was == "established" and self.state == "connecting":  # 3 missed pings
            self.phase = "connecting"
            self._sync_at = self._batch_deadline = None

    def get_timer(self) -> float | None:
        mine = (self._restart_at, self._ping0_at, self._batch_deadline, self._sync_at)
        times = [t for t in (*mine, super().get_timer()) if t is not None]
        return min(times, default=None)

    # ---- session set-up ------------------------------------------------------------------

    def _send_ping0(self, now: float) -> None:
        if self.agent is not None:
            ping = GetInfo(PX4_REQUEST_ID, OBJECT_ID_AGENT, 0x02)
            self._out.append((encode_message(Header(0x80, 0, 0), [ping]), self.agent))
        self._ping0_at = now + PING_PERIOD_S

    def _pong0(self, data: bytes, source: Address, now: float) -> None:
        try:
            header, offset = decode_header(data)
            parts, _pad = split_submessages(data, offset)
            subs = [decode_submessage(sid, flags, payload) for sid, flags, payload in parts]
        except DecodeError as exc:
            self._drop(source, f"malformed: {exc}")
            return
        if any(isinstance(s, Info) for s in subs):
            self._ping0_at = None
            self.phase = "connecting"
            self.state = "connecting"
            self._send_create_client(now)
        else:
            self._drop(source, "sessionless_not_info")

    def _ping_request_id(self) -> int:
        return PX4_REQUEST_ID

    def _create_entities(self, now: float) -> None:
        """STATUS_AGENT came: the participant first, alone; the rest after the time sync."""
        self._ping_at = None  # PX4 pings in session only once set up
        self._request = PX4_REQUEST_ID - 1  # a new session numbers its requests afresh
        self._buffered.clear()
        self._steps.clear()
        self._lazy.clear()
        self._replier = None
        self.offset_ns, self.timesync_good = None, 0
        self.phase = "participant"
        template = LOCALHOST_XML if self.localhost_only else DEFAULT_XML
        participant = Create(
            self._next_request(), object_id(0x001, ObjectKind.PARTICIPANT),
            ObjectKind.PARTICIPANT, Repr.XML, template.format(name=self.participant_name),
            domain_id=self.domain_id, replace=True,
        )  # fmt: skip
        self._steps.append(("participant", [participant], None))
        self._next_step(now)

    def _plan_entities(self) -> None:
        for spec in CORE_SUBSCRIPTIONS:
            creates = self._endpoint(spec, writer=False)
            read = ReadData(0, creates[-1].object_id, STREAM_BEST_EFFORT,
                            delivery_control=DeliveryControl(max_samples=0xFFFF))  # fmt: skip
            self._steps.append((f"reader {self.names[spec.topic]}", creates, read))
        if not lazy_writers(self.release):
            for spec in CORE_PUBLICATIONS:
                name = self.names[spec.topic]
                self._steps.append((f"writer {name}", self._endpoint(spec, writer=True), None))
        if has_replier(self.release):
            service = ServiceBinary(
                SERVICE, REQUEST_TYPE, REPLY_TYPE, self.request_topic, self.reply_topic
            )
            blob = encode_service(service)
            rid = object_id(REPLIER_IDENT, ObjectKind.REPLIER)
            create = Create(0, rid, ObjectKind.REPLIER, Repr.BIN, blob,
                            parent_id=self._participant(), replace=True)  # fmt: skip
            read = ReadData(0, rid, 0x80, delivery_control=DeliveryControl(max_samples=0xFFFF))
            self._steps.append(("replier vehicle_command", [create], read))

    def _participant(self) -> int:
        return object_id(0x001, ObjectKind.PARTICIPANT)

    def _endpoint(self, spec: TopicSpec, *, writer: bool) -> list[Create]:
        """TOPIC, PUBLISHER/SUBSCRIBER and DATAWRITER/DATAREADER under ``spec.ident``; the
        request ids are given when the batch is sent."""
        name = self.names[spec.topic]
        tid = object_id(spec.ident, ObjectKind.TOPIC)
        group = ObjectKind.PUBLISHER if writer else ObjectKind.SUBSCRIBER
        kind = ObjectKind.DATAWRITER if writer else ObjectKind.DATAREADER
        gid, eid = object_id(spec.ident, group), object_id(spec.ident, kind)
        topic = encode_topic(TopicBinary(name, dds_type(spec.message)))
        if writer:
            endpoint = EndpointBinary(tid, True, WRITER_QOS)
        else:
            endpoint = EndpointBinary(tid, False, READER_QOS, READER_DEPTH)
        parent = self._participant()
        return [
            Create(0, tid, ObjectKind.TOPIC, Repr.BIN, topic, parent_id=parent, replace=True),
            Create(0, gid, group, Repr.BIN, encode_group(GroupBinary()), parent_id=parent,
                   replace=True),
            Create(0, eid, kind, Repr.BIN, encode_endpoint(endpoint), parent_id=gid,
                   replace=True),
        ]  # fmt: skip

    def _next_step(self, now: float) -> None:
        """Send the next batch of CREATEs (with whatever PX4 had buffered) and wait for it."""
        if not self._steps:
            self._batch_deadline = None
            if self.phase == "entities":
                self._setup_done(now)
            return
        what, creates, after = self._steps[0]
        numbered = []
        for c in creates:
            rid = c.request_id if what == "participant" else self._next_request()
            numbered.append(Create(rid, c.object_id, c.kind, c.repr_format, c.representation,
                                   c.domain_id, c.parent_id, c.reuse, c.replace))  # fmt: skip
            self._pending[rid] = c.object_id
            self._waiting[rid] = what
        self._after = after
        self._flush([*self._buffered, *numbered], now)
        self._buffered.clear()
        self._batch_deadline = now + CREATE_TIMEOUT_S

    def _flush(self, subs: list[Submessage], now: float) -> None:
        if subs:
            self._send_reliable(subs, now)

    def _status(self, st: StatusReply) -> None:
        super()._status(st)
        what = self._waiting.pop(st.request_id, None)
        if what is None:
            return
        if st.status not in (Status.OK, Status.OK_MATCHED):
            self.failures.append(f"{what}: status {st.status}")
            self._abort_pending = f"{what} refused (status {st.status})"

    def _handle(self, parts: list[tuple[int, int, bytes]], now: float) -> None:
        super()._handle(parts, now)
        if self._abort_pending is not None:
            why, self._abort_pending = self._abort_pending, None
            self._abort(why, now)
        elif self._batch_deadline is not None and self._steps and not self._waiting:
            self._batch_done(now)

    def _batch_done(self, now: float) -> None:
        what, creates, _after = self._steps.popleft()
        if self._after is not None:
            read = self._after
            assert isinstance(read, ReadData)  # noqa: S101 - only READ_DATA is buffered
            self._buffered.append(ReadData(self._next_request(), read.object_id,
                                           read.preferred_stream_id,
                                           delivery_control=read.delivery_control))  # fmt: skip
            if read.preferred_stream_id == 0x80:
                self._replier = read.object_id
                self._readers[read.object_id] = self.request_topic
                self.subscriptions[self.request_topic] = REQUEST_TYPE
            else:
                self._readers[read.object_id] = self._topic_of(creates)
            self._after = None
        self._batch_deadline = None
        if what == "participant":
            self.phase = "timesync"
            self._sync_at = now
            return
        if what.startswith("writer "):
            topic_name = self._topic_of(creates)
            self._writers[topic_name] = creates[-1].object_id
            self._drain_lazy(topic_name, now)
        self._next_step(now)

    def _topic_of(self, creates: list[Create]) -> str:
        blob = creates[0].representation
        assert isinstance(blob, bytes)  # noqa: S101 - our own TOPIC, by binary
        n = struct.unpack_from("<I", blob)[0]
        return blob[4 : 4 + n - 1].decode()

    def _drain_lazy(self, topic_name: str, now: float) -> None:
        topic = next((t for t, n in self.names.items() if n == topic_name), None)
        queue = self._lazy.get(topic or "")
        oid = self._writers[topic_name]
        while queue:
            self._send_best_effort([WriteData(self._next_request(), oid, queue.popleft())])

    def _setup_done(self, now: float) -> None:
        self.phase = "running"
        self._flush(self._buffered, now)  # the last READ_DATA, alone (golden seq 10)
        self._buffered.clear()
        self._ping_at = now + PING_PERIOD_S
        self._pings_missed = 0

    def _describe(self) -> str:
        return self._steps[0][0] if self._steps else "?"

    def _abort(self, why: str, now: float) -> None:
        """PX4: a failed set-up deletes the session and starts again from the ping."""
        self.failures.append(why)
        if self.state == "established":
            self._send0([Delete(self._next_request(), OBJECT_ID_CLIENT)])
        self._emit(SessionEnded(self.agent, self.client_key, f"setup_failed: {why}"))
        self.state = "idle"
        self.phase = "idle"
        self._steps.clear()
        self._waiting.clear()
        self._connect_at = self._ping_at = self._heartbeat_at = None
        self._sync_at = self._batch_deadline = None
        self._restart_at = now + RESTART_AFTER_S

    # ---- time sync ------------------------------------------------------------------------

    def _other_submessage(self, sub: Submessage, now: float) -> None:
        if not isinstance(sub, TimestampReply):
            return
        t4 = self.hrt_ns(now)
        rtt = t4 - sub.originate.ns
        if rtt < 0 or rtt > TIMESYNC_MAX_RTT_S * 1e9:
            return  # PX4 discards a slow (or impossible) round trip
        # NTP-style: the agent's mid-point minus ours (DDS-XRCE §8.3.5.16)
        observed = (sub.receive.ns + sub.transmit.ns) // 2 - (sub.originate.ns + t4) // 2
        self.last_observed_offset_ns, self.timesync_rtt_ns = observed, rtt
        if self.offset_ns is None:
            self.offset_ns = observed
        else:
            progress = min(1.0, self.timesync_good / TIMESYNC_SAMPLES)
            alpha = ALPHA_INITIAL + (ALPHA_FINAL - ALPHA_INITIAL) * progress
            self.offset_ns = round(alpha * observed + (1 - alpha) * self.offset_ns)
        self.timesync_good += 1
        if self.phase == "timesync" and self.timesync_good >= TIMESYNC_SAMPLES:
            self.phase = "entities"
            self._plan_entities()
            self._next_step(now)

    def timesync_status(self, now: float) -> bytes:
        """A ``TimesyncStatus`` sample (source_protocol 2 = DDS, as PX4's bridge sets it)."""
        buf = bytearray(TIMESYNC_STATUS_SIZE)
        struct.pack_into("<QB", buf, 0, self.timestamp_us(now), 2)
        struct.pack_into(
            "<QqqI", buf, 16, (self.hrt_ns(now) + (self.offset_ns or 0)) // 1000,
            self.last_observed_offset_ns // 1000, (self.offset_ns or 0) // 1000,
            self.timesync_rtt_ns // 1000,
        )  # fmt: skip
        return bytes(buf)


__all__ = ["SESSION_ID", "Px4UxrceClient", "TopicSpec"]
