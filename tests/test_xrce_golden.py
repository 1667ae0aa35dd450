"""The golden session as an always-on oracle (no third-party binary needed).

``tests/fixtures/xrce/px4-1.16-core.tap.jsonl`` (from ../shared/peers/xrce/golden) holds every
datagram of a 40 s session between a client that sets up as PX4 v1.16's uxrce_dds_client
does (``127.0.0.1:39384``, key 1), a command sender (``127.0.0.1:44165``) and eProsima's
MicroXRCEAgent v2.4.2.

1. Replaying each client's recorded datagrams into swarmd's agent gives what the real agent
   gave where that is deterministic: STATUS_AGENT, every STATUS (request id, object id,
   status: the entity ids), every INFO answer, every TIMESTAMP_REPLY's echoed originate.
   Where they differ, and why:
   - TIMESTAMP_REPLY transmit/receive: the agent's clock at that instant (swarmd answers
     with one instant for both; eProsima's are ~200 ns apart);
   - DATA to the clients: eProsima's agent routes the command sender's samples to PX4
     through DDS; swarmd's agent has no DDS behind it and sends only what swarmd publishes
     (so the sender's WRITE_DATA to its REQUESTER is dropped and counted);
   - ACKNACK/HEARTBEAT timing on the reliable streams: when each side flushes.
2. The PX4 stand-in's own session (``swarmd_lab.px4.uxrce_client``, PX4 1.16, key 1,
   PTCFG=1) matches the golden client side: the session-less ping and CREATE_CLIENT byte for
   byte, the 500 TIMESTAMPs before the first topic, every reliable set-up message byte for
   byte but the padding octets the client library leaves stale, the in-session ping, the
   first request ids of its samples and every (writer, sample size). Not compared: sample
   contents and timestamps (the vehicle's state and clock) and the ping schedule (PX4 skips
   pings while samples arrive).
"""

from __future__ import annotations

import json
import random
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.xrce_standin import Px4XrceStandin, StandinConfig

from swarmd.xrce.agent import XrceAgent
from swarmd.xrce.message import (
    GetInfo,
    Info,
    Message,
    StatusAgent,
    StatusReply,
    TimestampReply,
    WriteData,
    decode_message,
)

TAP = Path(__file__).parent / "fixtures" / "xrce" / "px4-1.16-core.tap.jsonl"
RECORDS: list[dict[str, Any]] = [json.loads(line) for line in TAP.read_text().splitlines()]
PX4 = RECORDS[0]["client"]  # the PX4-like client spoke first
SENDER = next(r["client"] for r in RECORDS if r["client"] != PX4)


def _same_but_padding(ours: bytes, theirs: bytes) -> bool:
    """Equal, except where we wrote a zero alignment octet and the recorder left stale bytes."""
    return len(ours) == len(theirs) and all(
        a == 0 for a, b in zip(ours, theirs, strict=True) if a != b
    )


def _answers(msgs: list[Message]) -> dict[str, list[tuple[Any, ...]]]:
    """The deterministic part of an agent's answers, by kind, in order."""
    out: dict[str, list[tuple[Any, ...]]] = {"status_agent": [], "status": [], "info": [],
                                              "timestamp_originate": []}  # fmt: skip
    for m in msgs:
        for sub in m.submessages:
            match sub:
                case StatusAgent():
                    out["status_agent"].append((sub.status,))
                case StatusReply():
                    out["status"].append((sub.request_id, sub.object_id, sub.status))
                case Info():
                    out["info"].append(
                        (sub.request_id, sub.object_id, sub.status, sub.implementation_status)
                    )
                case TimestampReply():
                    out["timestamp_originate"].append((sub.originate,))
                case _:
                    pass
    return out


def replay_into_agent(
    records: list[dict[str, Any]], client: str
) -> Iterator[tuple[float, XrceAgent]]:
    """One client's recorded datagrams into a fresh swarmd agent, at their recorded times
    (seconds from the first record): yields the time and the agent after each one."""
    agent = XrceAgent(clock_offset_s=0.0)
    t0 = records[0]["t"]
    for r in records:
        if r["client"] != client or r["dir"] != "c2a":
            continue
        now = r["t"] - t0
        agent.handle_timer(now)
        agent.receive_datagram(bytes.fromhex(r["hex"]), client, now)
        yield now, agent


def _replay(client: str) -> tuple[dict[str, list[tuple[Any, ...]]], XrceAgent]:
    ours: list[Message] = []
    agent = XrceAgent(clock_offset_s=0.0)
    for _now, agent in replay_into_agent(RECORDS, client):
        ours += [decode_message(d) for d, _a in agent.datagrams_to_send()]
    return _answers(ours), agent


def _recorded(client: str) -> dict[str, list[tuple[Any, ...]]]:
    return _answers(
        [
            decode_message(bytes.fromhex(r["hex"]))
            for r in RECORDS
            if r["client"] == client and r["dir"] == "a2c"
        ]  # fmt: skip
    )


def test_replayed_px4_session_gets_the_real_agents_answers() -> None:
    ours, agent = _replay(PX4)
    theirs = _recorded(PX4)
    assert ours["status_agent"] == theirs["status_agent"] == [(0,)]
    # every CREATE's STATUS (entity ids, request ids, OK), and the DELETE's at the end
    assert ours["status"] == theirs["status"] and len(theirs["status"]) == 27
    assert ours["info"] == theirs["info"]  # session-less (status 0) and in-session (1)
    assert ours["timestamp_originate"] == theirs["timestamp_originate"]
    assert len(theirs["timestamp_originate"]) == 535
    assert agent.dropped == Counter()  # nothing of PX4's was refused


def test_replayed_command_sender_session_gets_the_real_agents_answers() -> None:
    ours, agent = _replay(SENDER)
    theirs = _recorded(SENDER)
    assert ours["status_agent"] == theirs["status_agent"]
    assert ours["status"] == theirs["status"]
    assert ours["info"] == theirs["info"]
    # differs: the sender's two requests written to its REQUESTER (0x030) are dropped and
    # counted: swarmd's agent serves PX4's replier for swarmd itself and routes nothing
    # between clients (eProsima's passes them to PX4's replier through DDS)
    assert agent.dropped == Counter({"write_unknown_writer": 2})


def test_timestamp_replies_differ_only_in_the_agents_clock() -> None:
    """Why transmit/receive are not compared: they are the agent's clock; swarmd gives one
    instant for both, eProsima's agent two a few hundred ns apart."""
    theirs = [
        sub for r in RECORDS if r["client"] == PX4 and r["dir"] == "a2c"
        for sub in decode_message(bytes.fromhex(r["hex"])).submessages
        if isinstance(sub, TimestampReply)
    ]  # fmt: skip
    gaps = [t.transmit.ns - t.receive.ns for t in theirs]
    assert 0 <= min(gaps) and max(gaps) < 1_000_000  # < 1 ms inside eProsima's agent


# ---- the stand-in's session against the golden client side --------------------------------


def _golden_client() -> list[bytes]:
    return [bytes.fromhex(r["hex"]) for r in RECORDS if r["client"] == PX4 and r["dir"] == "c2a"]


def _standin_session(seconds: float = 9.0) -> list[bytes]:
    """The stand-in against swarmd's agent on virtual time (replies 0.3 ms later)."""
    agent = XrceAgent()
    config = StandinConfig(release="1.16", key=1, vehicle=SimConfig(gps_fix_after_s=0.0))
    standin = Px4XrceStandin(config, random.Random(1), 0.0)
    sent: list[bytes] = []
    standin.connect("agent", 0.0)
    now = 0.0
    while now < seconds:
        for _ in range(100):  # until both sides are quiet at this instant
            out = standin.datagrams_to_send()
            for data, _a in out:
                sent.append(data)
                agent.receive_datagram(data, "px4", now)
            back = agent.datagrams_to_send()
            for data, _a in back:
                standin.receive_datagram(data, "agent", now + 0.0003)
            if not out and not back:
                break
        timers = [t for t in (standin.get_timer(), agent.get_timer()) if t is not None]
        now = max(now + 1e-4, min(timers))
        standin.handle_timer(now)
        agent.handle_timer(now)
    return sent


def _kinds(data: bytes) -> list[str]:
    return [type(s).__name__ for s in decode_message(data).submessages]


def test_standin_session_set_up_matches_the_golden_client_side() -> None:
    ours, theirs = _standin_session(), _golden_client()
    # the session-less ping and CREATE_CLIENT, byte for byte
    assert ours[0] == theirs[0] and isinstance(decode_message(ours[0]).submessages[0], GetInfo)
    assert ours[1] == theirs[1] and _kinds(ours[1]) == ["CreateClient"]

    def reliable(msgs: list[bytes]) -> list[bytes]:
        return [m for m in msgs if m[1] == 0x80 and "WriteData" not in _kinds(m)]

    # participant, reader batch, READ_DATA + writer batches, replier, READ_DATA: in order and
    # byte for byte (but stale padding), with PX4's request ids (10, 11, ...)
    ours_rel, theirs_rel = reliable(ours), reliable(theirs)
    assert len(theirs_rel) == 11 and len(ours_rel) == 11
    for i, (a, b) in enumerate(zip(ours_rel, theirs_rel, strict=True)):
        assert _same_but_padding(a, b), (i, _kinds(a), _kinds(b))
    # time sync: 500 TIMESTAMPs between the participant and the first topic
    first_topic = [i for i, m in enumerate(ours) if m == ours_rel[1]][0]
    first_topic_golden = theirs.index(theirs_rel[1])

    def syncs(msgs: list[bytes]) -> int:
        return sum(1 for m in msgs if _kinds(m) == ["Timestamp"])

    assert syncs(ours[:first_topic]) == syncs(theirs[:first_topic_golden]) == 500


def test_standin_samples_and_pings_match_the_golden_client_side() -> None:
    ours, theirs = _standin_session(), _golden_client()

    def writes(msgs: list[bytes]) -> list[WriteData]:
        return [s for m in msgs if m[1] == 0x01 for s in decode_message(m).submessages
                if isinstance(s, WriteData)]  # fmt: skip

    ours_w, theirs_w = writes(ours), writes(theirs)
    assert ours_w[0].request_id == theirs_w[0].request_id == 38  # right after the set-up
    sizes = {(w.object_id, len(w.data)) for w in ours_w}
    # every writer and its sample size; acks (0xEF5, 25 B) only follow a command, and the
    # golden session had commands (the flight tests check the stand-in's acks)
    assert sizes == {(w.object_id, len(w.data)) for w in theirs_w} - {(0xEF5, 25), (0x8008, 49)}
    # the in-session ping, byte for byte (request id 10, session 0x81, stream 0)
    ping = next(m for m in theirs[2:] if _kinds(m) == ["GetInfo"])
    assert ping in ours
    # the best-effort stream counts from 0 in both
    assert decode_message(next(m for m in ours if m[1] == 1)).header.sequence_nr == 0
    # Micro XRCE-DDS framing: every message 4-aligned but a lone ACKNACK, in both
    for msgs in (ours, theirs):
        assert all(len(m) % 4 == 0 for m in msgs if _kinds(m) != ["AckNack"])
    assert {_kinds(m)[0] for m in ours if m[1] == 0} == {
        "GetInfo",
        "CreateClient",
        "Timestamp",
        "AckNack",
    }
