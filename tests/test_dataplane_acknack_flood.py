"""A captured member's ACKNACK flood: what it makes the commander send, and where.

Attacker 2 of docs/security.md (a captured member, here m01: its node key and pair keys).
Its ACKNACKs are genuine (its own pair key, fresh counts and freshness), so they pass every
check; each asks the commander's command writer to repair everything. The commander's
answers go to m01's locator, which m01 itself signed in its SPDP: any unicast address but
loopback and the receiver's own ("Locators"), i.e. a victim of its choice. Before the
session 10 network review every fresh ACKNACK drew a repair (DATA + HEARTBEAT) or a GAP
(+ HEARTBEAT) at once, so the commander sent the victim one datagram per ACKNACK, at
whatever rate m01 sent them, each larger than the ACKNACK that drew it. The bound: a writer
answers one reader's requests at most ``ACKNACK_REPLY_RATE`` times a second (burst
``ACKNACK_REPLY_BURST``; ``swarmd/dataplane/writer.py``, DDSI-RTPS 8.4.7.1 leaves it to the
writer), whatever the request rate, and an honest reader (one ACKNACK per HEARTBEAT, at most
every ``HEARTBEAT_PERIOD_S``) never meets it. Virtual time, the data plane's in-memory network.
"""

from __future__ import annotations

from swarmd.dataplane import TOPIC_COMMAND, CommandKind, DataPlane
from swarmd.dataplane.writer import (
    ACKNACK_REPLY_BURST,
    ACKNACK_REPLY_RATE,
    HEARTBEAT_PERIOD_S,
    ReliableWriter,
)
from swarmd.rtps import AckNack, SequenceNumberSet
from tests.test_dataplane_auth import ATTACKER, CMD_R, CMD_W, flying_swarm, sealed
from tests.test_dataplane_swarm import address_of


def acknack_flood(rate: int, flood_s: float) -> tuple[int, int, int, int]:
    """m01, captured, sends the commander ``rate`` fresh ACKNACKs a second for ``flood_s``,
    each asking for 64 SNs from the command writer's oldest: (ACKNACKs, their bytes,
    datagrams the commander sent m01's signed locator, their bytes). ``bench.acknack_flood``
    prints it."""
    swarm = flying_swarm()
    lead = swarm.planes["lead"]
    m01 = swarm.bundle.participant("m01")
    lead.send_command(lead.make_command(CommandKind.HOLD), swarm.now)
    lead.datagrams_to_send()  # the command's first send: not the attacker's doing
    writer = lead._endpoints.by_topic[TOPIC_COMMAND]
    assert isinstance(writer, ReliableWriter)
    first = writer.first_available
    everything = SequenceNumberSet.of(first, list(range(first, first + 64)))
    start = swarm.now
    victim = address_of(swarm.bundle, "m01")
    count = int(flood_s * rate)
    sent_to_victim = sent_bytes = acknack_bytes = 0
    for k in range(count):
        ack = AckNack(CMD_R, CMD_W, everything, 1_000 + k, final=True)
        datagram = sealed(swarm, "m01", m01, "lead", ack, seq=50_000 + k)
        acknack_bytes += len(datagram)
        datagrams, octets = drawn(lead, datagram, start + k / rate, victim)
        sent_to_victim += datagrams
        sent_bytes += octets
    assert lead.counters["rx_authenticated"] >= count  # genuine: every one accepted
    return count, acknack_bytes, sent_to_victim, sent_bytes


def drawn(
    plane: DataPlane, datagram: bytes, now: float, victim: tuple[str, int]
) -> tuple[int, int]:
    """What ``datagram``, received by ``plane`` at ``now`` (from the attacker), makes it send
    ``victim``: (datagrams, octets)."""
    plane.receive_datagram(datagram, ATTACKER, now)
    while plane.next_event() is not None:
        pass
    sent = [len(data) for data, to in plane.datagrams_to_send() if to == victim]
    return len(sent), sum(sent)


def test_a_captured_members_acknack_flood_draws_a_bounded_stream_to_its_locator() -> None:
    """400 ACKNACKs in one second of virtual time: at most the answer budget comes back,
    fewer bytes than the flood (before the bound: 400 answers, 2.5x the flood's bytes)."""
    flood_s = 1.0
    _, acknack_bytes, answers, answer_bytes = acknack_flood(400, flood_s)
    assert answers <= ACKNACK_REPLY_BURST + ACKNACK_REPLY_RATE * flood_s
    assert answer_bytes < acknack_bytes  # no amplification of the captured member's bytes


def test_an_honest_readers_repairs_are_never_held_back() -> None:
    """The bound's control: a reader answering each HEARTBEAT (at most every
    ``HEARTBEAT_PERIOD_S``) has every ACKNACK answered: the rate is twice that pace."""
    assert ACKNACK_REPLY_RATE * HEARTBEAT_PERIOD_S >= 2  # twice the HEARTBEAT pace
    swarm = flying_swarm()
    lead = swarm.planes["lead"]
    m01 = swarm.bundle.participant("m01")
    lead.send_command(lead.make_command(CommandKind.HOLD), swarm.now)
    lead.datagrams_to_send()  # lost on the way to m01: it asks for it again and again
    writer = lead._endpoints.by_topic[TOPIC_COMMAND]
    everything = SequenceNumberSet.of(writer.last_sn, [writer.last_sn])
    victim = address_of(swarm.bundle, "m01")
    answered = 0
    for k in range(10):
        now = swarm.now + k * HEARTBEAT_PERIOD_S
        ack = AckNack(CMD_R, CMD_W, everything, 1_000 + k, final=True)
        lead.receive_datagram(sealed(swarm, "m01", m01, "lead", ack, seq=60_000 + k), ATTACKER, now)
        answered += sum(1 for _, to in lead.datagrams_to_send() if to == victim)
    assert answered >= 10
