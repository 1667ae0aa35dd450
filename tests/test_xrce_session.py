"""The XRCE session engines on virtual time: agent and client joined in memory, and hostile
input. No sockets, no clock (style.md rule 12)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Mapping
from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.xrce import binary as xb
from swarmd.xrce.agent import MAX_ENTITIES, MAX_SESSIONS, SESSION_TIMEOUT_S, XrceAgent
from swarmd.xrce.client import XrceClient
from swarmd.xrce.events import (
    EntityCreated,
    SampleReceived,
    SessionCreated,
    SessionEnded,
    XrceEvent,
)
from swarmd.xrce.message import (
    AckNack,
    Create,
    CreateClient,
    Fragment,
    GetInfo,
    Header,
    Info,
    ObjectKind,
    ReadData,
    Repr,
    StatusAgent,
    StatusReply,
    Time,
    Timestamp,
    TimestampReply,
    WriteData,
    decode_message,
    encode_message,
    object_id,
)
from swarmd.xrce.streams import MAX_REASSEMBLY, ReliableIn, ReliableOut, seq_diff, seq_lt

PX4 = ("127.0.0.1", 40000)
AGENT = ("127.0.0.1", 8888)
TOPIC = "rt/fmu/out/vehicle_status_v1"
CMD = "rt/fmu/in/vehicle_command"


def _pair() -> tuple[XrceAgent, XrceClient, XrceClient]:
    agent = XrceAgent(clock_offset_s=1000.0)
    px4 = XrceClient(b"\x00\x00\x00\x01", subscriptions={CMD: "cmd"}, publications={TOPIC: "st"})
    swarmd = XrceClient(b"SWMD", subscriptions={TOPIC: "st"}, publications={CMD: "cmd"})
    return agent, px4, swarmd


def _run(agent: XrceAgent, clients: Mapping[Any, XrceClient], now: float, drop: int = 0) -> None:
    """Deliver every queued datagram both ways until quiet (``drop``: lose every n-th)."""
    n = 0
    for _ in range(200):
        moved = False
        for addr, c in clients.items():
            for data, _dest in c.datagrams_to_send():
                n += 1
                moved = True
                if not (drop and n % drop == 0):
                    agent.receive_datagram(data, addr, now)
        for data, dest in agent.datagrams_to_send():
            n += 1
            moved = True
            if not (drop and n % drop == 0):
                clients[dest].receive_datagram(data, AGENT, now)
        if not moved:
            return


def _events(engine: XrceAgent | XrceClient) -> list[XrceEvent]:
    out: list[XrceEvent] = []
    while (e := engine.next_event()) is not None:
        out.append(e)
    return out


def test_sans_io_boundary() -> None:
    code = (
        "import sys, swarmd.xrce.agent, swarmd.xrce.client, swarmd.xrce.framing, swarmd.xrce.px4;"
        "print(sorted({'asyncio', 'socket'} & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_session_entities_and_samples_between_agent_and_two_clients() -> None:
    agent, px4, swarmd = _pair()
    clients = {PX4: px4, ("127.0.0.1", 40001): swarmd}
    px4.connect(AGENT, 0.0)
    swarmd.connect(AGENT, 0.0)
    _run(agent, clients, 0.0)
    assert px4.state == swarmd.state == "established"
    created = [e for e in _events(agent) if isinstance(e, EntityCreated)]
    assert len(created) == 2 * (1 + 3 + 3)  # participant, reader triple, writer triple each
    assert all(e.status == 0 for e in created)
    assert {e.name for e in created if e.kind == ObjectKind.DATAWRITER} == {TOPIC, CMD}
    # swarmd's command reaches PX4's reader; PX4's status reaches swarmd's reader
    assert swarmd.publish(CMD, b"arm", 0.1) == 1
    assert px4.publish(TOPIC, b"status", 0.1) == 1
    _run(agent, clients, 0.1)
    samples = [e for e in _events(agent) if isinstance(e, SampleReceived)]
    assert {(e.topic_name, e.data) for e in samples} == {(CMD, b"arm"), (TOPIC, b"status")}
    for s in samples:
        agent.publish(s.topic_name, s.data, 0.2)
    _run(agent, clients, 0.2)
    got = {(e.topic_name, e.data) for c in (px4, swarmd) for e in _events(c)
           if isinstance(e, SampleReceived)}  # fmt: skip
    assert got == {(CMD, b"arm"), (TOPIC, b"status")}


def test_reliable_streams_survive_loss() -> None:
    agent, px4, _ = _pair()
    px4.connect(AGENT, 0.0)
    now = 0.0
    for _ in range(100):  # lose every 3rd datagram; timers retransmit
        _run(agent, {PX4: px4}, now, drop=3)
        now += 0.2
        px4.handle_timer(now)
        agent.handle_timer(now)
    assert px4.state == "established"
    created = [e for e in _events(agent) if isinstance(e, EntityCreated)]
    assert {e.object_id for e in created} >= {object_id(0x001, 1)}
    assert len({e.object_id for e in created}) == 7


def test_timestamp_reply_uses_the_injected_clock() -> None:
    agent, px4, _ = _pair()
    px4.connect(AGENT, 0.0)
    _run(agent, {PX4: px4}, 0.0)
    ts = Timestamp(Time(5, 250))
    agent.receive_datagram(encode_message(Header(0x81, 0, 0), [ts]), PX4, 2.5)
    (reply,) = [decode_message(d) for d, _ in agent.datagrams_to_send()]
    sub = reply.submessages[0]
    assert isinstance(sub, TimestampReply)
    assert sub.receive == sub.transmit == Time(1002, 500_000_000) and sub.originate == Time(5, 250)


def test_ping_in_and_out_of_session() -> None:
    agent = XrceAgent()
    agent.receive_datagram(encode_message(Header(0x80, 0, 0), [GetInfo(1, 0xFFFD, 2)]), PX4, 0.0)
    (out,) = agent.datagrams_to_send()
    pong = decode_message(out[0]).submessages[0]
    assert isinstance(pong, Info) and pong.availability == 1 and pong.implementation_status == 0
    cc = CreateClient(b"\x00\x00\x00\x01", 0x81)
    agent.receive_datagram(encode_message(Header(0x80, 0, 0), [cc]), PX4, 0.0)
    agent.datagrams_to_send()
    agent.receive_datagram(encode_message(Header(0x81, 0, 0), [GetInfo(2, 0xFFFD, 2)]), PX4, 0.0)
    (out,) = agent.datagrams_to_send()
    pong = decode_message(out[0]).submessages[0]
    # PX4's fork: implementation_status != 0 and availability > 0, or it disconnects
    assert isinstance(pong, Info) and pong.implementation_status == 1 and pong.availability == 1


def test_sessions_time_out_and_restart() -> None:
    agent, px4, _ = _pair()
    px4.connect(AGENT, 0.0)
    _run(agent, {PX4: px4}, 0.0)
    agent.handle_timer(SESSION_TIMEOUT_S + 0.1)
    assert not agent.sessions
    assert any(isinstance(e, SessionEnded) and e.reason == "timeout" for e in _events(agent))
    # the client notices missing pongs and opens a new session
    now = SESSION_TIMEOUT_S
    for _ in range(6):
        now += 1.0
        px4.handle_timer(now)
        _run(agent, {PX4: px4}, now)
    assert agent.sessions and px4.state == "established"


def _attach(agent: XrceAgent, key: bytes = b"\x00\x00\x00\x01", src: object = PX4) -> None:
    cc = CreateClient(key, 0x81)
    agent.receive_datagram(encode_message(Header(0x80, 0, 0), [cc]), src, 0.0)
    agent.datagrams_to_send()


def test_forged_and_garbage_datagrams_are_counted_and_dropped() -> None:
    agent = XrceAgent()
    _attach(agent)
    session = agent.sessions[PX4]
    # a forger on another port: no session there, nothing moves
    forged = encode_message(Header(0x81, 0x01, 5), [WriteData(1, 0x0FD5, b"x" * 80)])
    agent.receive_datagram(forged, ("127.0.0.1", 9), 0.0)
    for junk in (b"", b"\x81", b"\x81\x00\x00\x00\xff\xff\xff\xff", bytes(range(256))):
        agent.receive_datagram(junk, PX4, 0.0)
    assert agent.dropped["no_session"] == 1
    assert agent.dropped["malformed"] >= 3
    assert agent.sessions[PX4] is session and not session.entities


def test_expected_key_refuses_other_clients() -> None:
    agent = XrceAgent(expected_key=b"\x00\x00\x00\x01")
    cc = CreateClient(b"EVIL", 0x81)
    agent.receive_datagram(encode_message(Header(0x80, 0, 0), [cc]), PX4, 0.0)
    # refused and counted, unanswered (no key oracle: docs/security.md "XRCE's key, guessed")
    assert agent.datagrams_to_send() == [] and not agent.sessions
    assert agent.refused == {"wrong_key": 1}


def test_tables_are_capped() -> None:
    agent = XrceAgent()
    for i in range(MAX_SESSIONS + 3):
        _attach(agent, key=i.to_bytes(4, "big") + b"", src=("127.0.0.1", 50000 + i))
    assert len(agent.sessions) == MAX_SESSIONS
    assert agent.dropped["create_client_refused"] == 3
    agent = XrceAgent()
    _attach(agent)
    for i in range(MAX_ENTITIES + 5):
        c = Create(i, object_id(i, ObjectKind.PUBLISHER), ObjectKind.PUBLISHER, Repr.BIN,
                   b"\x00\x00", parent_id=0x0011)  # fmt: skip
        agent.receive_datagram(encode_message(Header(0x81, 0x80, i % 65536), [c]), PX4, 0.0)
    statuses = [
        s for d, _ in agent.datagrams_to_send() for s in decode_message(d).submessages
        if isinstance(s, StatusReply)
    ]  # fmt: skip
    assert len(agent.sessions[PX4].entities) == MAX_ENTITIES
    assert sum(s.status == 0x87 for s in statuses) == 5  # ERR_RESOURCES


def test_fragment_reassembly_is_bounded() -> None:
    agent = XrceAgent()
    _attach(agent)
    chunk = Fragment(b"\x00" * 1000, last=False)
    for i in range((MAX_REASSEMBLY // 1000) + 5):
        agent.receive_datagram(encode_message(Header(0x81, 0x80, i), [chunk]), PX4, 0.0)
    assert agent.dropped["reassembly_overflow"] >= 1
    assert len(agent.sessions[PX4].reassembly[0x80].buf) <= MAX_REASSEMBLY


def test_fragmented_create_is_reassembled() -> None:
    agent = XrceAgent()
    _attach(agent)
    c = Create(7, object_id(1, 1), 1, Repr.XML, "<dds>" + "x" * 600 + "</dds>", domain_id=0)
    whole = encode_message(Header(0x81, 0x80, 0), [c])[4:]
    parts = [whole[:300], whole[300:]]
    for i, p in enumerate(parts):
        frag = Fragment(p, last=i == 1)
        agent.receive_datagram(encode_message(Header(0x81, 0x80, i), [frag]), PX4, 0.0)
    assert object_id(1, 1) in agent.sessions[PX4].entities


@given(st.lists(st.binary(max_size=80), max_size=20))
@settings(max_examples=200, deadline=None)
def test_arbitrary_datagrams_never_raise(datagrams: list[bytes]) -> None:
    agent = XrceAgent()
    _attach(agent)
    for i, d in enumerate(datagrams):
        agent.receive_datagram(b"\x81" + d, PX4, float(i))
        agent.receive_datagram(d, PX4, float(i))
        agent.handle_timer(float(i))
    agent.datagrams_to_send()


@given(st.integers(0, 0xFFFF), st.integers(1, 0x7FFF))
def test_serial_number_arithmetic_wraps(a: int, n: int) -> None:
    b = (a + n) % 65536
    assert seq_lt(a, b) and not seq_lt(b, a) and seq_diff(b, a) == n


def test_reliable_window_across_the_wrap() -> None:
    rin = ReliableIn(expected=0xFFFE)
    assert rin.receive(0x0000, b"c") == []
    assert rin.acknack() == (0xFFFE, 0b011)
    assert rin.receive(0xFFFE, b"a") == [b"a"]
    assert rin.receive(0xFFFF, b"b") == [b"b", b"c"]
    assert rin.expected == 1 and rin.receive(0xFFFF, b"b") == [] and rin.duplicates == 1
    out = ReliableOut(next_seq=0xFFFF)
    out.push(b"x")
    out.push(b"y")
    assert out.heartbeat() == (0xFFFF, 0x0000)
    assert out.on_acknack(0xFFFF, 0b10, 0.0) == [b"y"]
    assert out.on_acknack(0x0001, 0, 0.0) == [] and out.heartbeat() is None
    assert AckNack(0, 0, 0x80) == AckNack(0, 0, 0x80)


def test_an_expired_message_is_repaired_only_as_its_stand_in() -> None:
    """A message pushed with an expiry is sent again as itself before it and as its stand-in
    at and after it; the stand-in keeps its sequence number, so the gap is filled
    (docs/security.md, "A command frame delivered late")."""
    out = ReliableOut()
    out.push(b"arm", (1.0, b"nothing"))
    out.push(b"status")
    assert out.on_acknack(0, 0b11, 0.5) == [b"arm", b"status"]
    assert out.expired == 0
    assert out.on_acknack(0, 0b11, 1.0) == [b"nothing", b"status"]
    assert out.on_acknack(0, 0b01, 9.0) == [b"nothing"]
    assert out.expired == 1 and out.heartbeat() == (0, 1)
    assert out.on_acknack(2, 0, 9.0) == [] and out.heartbeat() is None and not out.expiry


def test_agent_refuses_nothing_px4_creates() -> None:
    agent, px4, _ = _pair()
    px4.connect(AGENT, 0.0)
    _run(agent, {PX4: px4}, 0.0)
    events = _events(px4)
    assert [e for e in events if isinstance(e, SessionCreated)]
    ents = [e for e in events if isinstance(e, EntityCreated)]
    assert ents and all(e.status == 0 for e in ents)


def test_agent_backend_over_a_serial_line() -> None:
    """The UART path: Micro XRCE-DDS framing both ways over a pseudo-terminal; the far end
    is the client engine playing PX4 (only its framing and session, not PX4's library)."""
    import asyncio
    import os

    from swarmd.px4.messages import Observation
    from swarmd.px4.xrce_backend import XrceBackend
    from swarmd.xrce.framing import Deframer, frame
    from swarmd.xrce.px4 import encode_fields
    from swarmd.xrce.px4_layouts import LAYOUTS

    status = "rt/fmu/out/vehicle_status_v1"

    async def scenario() -> None:
        master, slave = os.openpty()
        loop = asyncio.get_running_loop()
        backend = XrceBackend("xrce-agent", f"serial:{os.ttyname(slave)}:921600")
        got: list[Observation] = []
        await backend.start(lambda obs, now: got.append(obs))
        px4 = XrceClient(b"\x00\x00\x00\x01", subscriptions={}, publications={status: "st"})
        deframer = Deframer()

        def flush() -> None:
            for data, _ in px4.datagrams_to_send():
                os.write(master, frame(data, src=1, dst=0))

        def readable() -> None:
            for _s, _d, payload in deframer.feed(os.read(master, 4096)):
                px4.receive_datagram(payload, "agent", loop.time())
            flush()

        loop.add_reader(master, readable)
        try:
            px4.connect("agent", loop.time())
            flush()
            for _ in range(200):
                if px4.state == "established" and not px4._pending:
                    break
                await asyncio.sleep(0.02)
            # a 1.16 VehicleStatus of vehicle 1 (the backend's sysid): disarmed, MANUAL
            sample = encode_fields(LAYOUTS["1.16"]["VehicleStatus"], {"system_id": 1})
            assert px4.publish(status, sample, loop.time()) == 1
            flush()
            for _ in range(100):
                if any(type(o).__name__ == "Heartbeat" for o in got):
                    break
                await asyncio.sleep(0.02)
            # a new session first tells the vehicle to forget the last PX4 life's state
            # (xrce_translate: StateReset), then the sample's own translation
            kinds = [type(o).__name__ for o in got]
            assert kinds[:1] == ["StateReset"] and "Heartbeat" in kinds[1:], kinds
            assert backend.stats()["bad_frames"] == 0 and backend.session == "established"
        finally:
            loop.remove_reader(master)
            await backend.close()
            os.close(master)
            os.close(slave)

    asyncio.run(scenario())


def test_replayed_best_effort_samples_are_dropped_as_stale() -> None:
    agent, px4, _ = _pair()
    px4.connect(AGENT, 0.0)
    _run(agent, {PX4: px4}, 0.0)
    _events(agent)
    sample = encode_message(Header(0x81, 0x01, 7), [WriteData(1, object_id(0x200, 5), b"s")])
    agent.receive_datagram(sample, PX4, 1.0)
    agent.receive_datagram(sample, PX4, 1.1)  # the same datagram again: a replay
    got = [e for e in _events(agent) if isinstance(e, SampleReceived)]
    assert len(got) == 1 and agent.dropped["stale_best_effort"] == 1


def _entities_created(client: XrceClient) -> list[tuple[Any, ...]]:
    """What ``client`` sends once an agent accepted it: per CREATE (kind, object id, parent
    or domain, binary blob), per READ_DATA its reader, in the order sent."""
    client.connect(AGENT, 0.0)
    assert client.datagrams_to_send()  # CREATE_CLIENT
    accepted = StatusAgent(0, 0)
    client.receive_datagram(encode_message(Header(0x81, 0, 0), [accepted]), AGENT, 0.0)
    assert client.state == "established"
    out: list[tuple[Any, ...]] = []
    for data, dest in client.datagrams_to_send():
        assert dest == AGENT
        for sub in decode_message(data).submessages:
            if isinstance(sub, Create):
                parent = sub.domain_id if sub.kind == ObjectKind.PARTICIPANT else sub.parent_id
                blob = sub.representation if sub.repr_format == Repr.BIN else None
                out.append(("create", sub.kind, sub.object_id, parent, blob))
            elif isinstance(sub, ReadData):
                out.append(("read", sub.object_id, sub.preferred_stream_id))
    return out


def test_client_creates_its_readers_and_writers_under_their_own_groups() -> None:
    """Per subscription (sorted) a topic, a subscriber and a best-effort keep-last reader
    then READ_DATA; per publication a topic, a publisher and a reliable writer; each entity
    under the participant or its group, object ids from 0x100 (readers) and 0x200 (writers)."""
    client = XrceClient(b"SWMD", subscriptions={"b": "tb", "a": "ta"}, publications={"c": "tc"})
    participant = object_id(0x001, ObjectKind.PARTICIPANT)
    expected: list[tuple[Any, ...]] = [("create", ObjectKind.PARTICIPANT, participant, 0, None)]
    for ident, topic, typ, writer in ((0x100, "a", "ta", False), (0x101, "b", "tb", False),
                                      (0x200, "c", "tc", True)):  # fmt: skip
        tid = object_id(ident, ObjectKind.TOPIC)
        group = ObjectKind.PUBLISHER if writer else ObjectKind.SUBSCRIBER
        kind = ObjectKind.DATAWRITER if writer else ObjectKind.DATAREADER
        qos = xb.QOS_RELIABLE | xb.QOS_HISTORY_KEEP_LAST if writer else xb.QOS_HISTORY_KEEP_LAST
        gid, eid = object_id(ident, group), object_id(ident, kind)
        topic_blob = xb.encode_topic(xb.TopicBinary(topic, typ))
        expected += [
            ("create", ObjectKind.TOPIC, tid, participant, topic_blob),
            ("create", group, gid, participant, xb.encode_group(xb.GroupBinary())),
            ("create", kind, eid, gid, xb.encode_endpoint(xb.EndpointBinary(tid, writer, qos, 10))),
        ]
        if not writer:
            expected.append(("read", eid, 0x01))
    assert _entities_created(client) == expected
