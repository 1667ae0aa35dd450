"""A captured member's HEARTBEAT flood: what it makes the commander's readers send, and where
(review 16).

Attacker 2 of docs/security.md (a captured member, m01: its node key and pair keys). The
commander's outcome reader answers each fresh HEARTBEAT of m01's outcome writer with an
ACKNACK (DDSI-RTPS 8.4.12), sent to m01's locator, which m01 signed in its SPDP: where the
bundle does not pin m01's address, a victim of its choice ("Locators"). This is the
writer-side ACKNACK flood's twin (``tests/test_dataplane_acknack_flood.py``, session 10):
one genuine 32 KiB datagram of 1,000 HEARTBEATs drew 1,000 ACKNACKs, 41 datagrams and 56 KB
(1.75x its bytes); 400 one-HEARTBEAT datagrams a second drew 400 ACKNACKs, each larger
than the HEARTBEAT. The bounds: a reader answers only the last HEARTBEAT of a writer in
one datagram (it says all the earlier ones would), and a writer's HEARTBEATs at most
``HEARTBEAT_REPLY_RATE`` times a second (burst ``HEARTBEAT_REPLY_BURST``), twice an honest
writer's fastest pace. Virtual time, the data plane's in-memory network.
"""

from __future__ import annotations

from swarmd.dataplane.reader import HEARTBEAT_REPLY_BURST, HEARTBEAT_REPLY_RATE
from swarmd.dataplane.writer import HEARTBEAT_PERIOD_S
from swarmd.rtps import Heartbeat
from tests.test_dataplane_acknack_flood import drawn
from tests.test_dataplane_auth import OUT_R, OUT_W, flying_swarm, sealed
from tests.test_dataplane_swarm import address_of


def _flood(per_datagram: int, datagrams: int, flood_s: float) -> tuple[int, int, int, int]:
    """m01, captured, sends the commander ``datagrams`` genuine datagrams over ``flood_s``,
    each of ``per_datagram`` fresh HEARTBEATs of its outcome writer announcing samples the
    commander never had: (datagrams, their bytes, datagrams the commander sent m01's signed
    locator, their bytes)."""
    swarm = flying_swarm()
    lead = swarm.planes["lead"]
    m01 = swarm.bundle.participant("m01")
    lead.datagrams_to_send()
    victim = address_of(swarm.bundle, "m01")
    start, count = swarm.now, 10_000
    flood_bytes = sent = sent_bytes = 0
    for k in range(datagrams):
        beats = []
        for _ in range(per_datagram):
            count += 1
            beats.append(Heartbeat(OUT_R, OUT_W, 1, count, count, final=False))
        datagram = sealed(swarm, "m01", m01, "lead", *beats, seq=70_000 + k)
        flood_bytes += len(datagram)
        out, octets = drawn(lead, datagram, start + flood_s * k / datagrams, victim)
        sent += out
        sent_bytes += octets
    assert lead.counters["rx_authenticated"] >= datagrams  # genuine: every one accepted
    return datagrams, flood_bytes, sent, sent_bytes


def test_one_datagram_of_a_thousand_heartbeats_draws_one_small_answer() -> None:
    _, flood_bytes, sent, sent_bytes = _flood(1000, 1, 1.0)
    assert sent == 1
    assert sent_bytes < flood_bytes / 100


def test_a_heartbeat_flood_draws_a_bounded_stream_to_the_signed_locator() -> None:
    flood_s = 1.0
    _, flood_bytes, sent, sent_bytes = _flood(1, 400, flood_s)
    assert sent <= HEARTBEAT_REPLY_BURST + HEARTBEAT_REPLY_RATE * flood_s
    assert sent_bytes < flood_bytes  # no amplification of the captured member's bytes


def test_an_honest_writers_heartbeats_are_each_answered() -> None:
    """The bound's control: HEARTBEATs at an honest writer's fastest pace
    (``HEARTBEAT_PERIOD_S``) are answered every one: the rate is twice that pace."""
    assert HEARTBEAT_REPLY_RATE * HEARTBEAT_PERIOD_S >= 2
    datagrams = 10
    _, _, sent, _ = _flood(1, datagrams, datagrams * HEARTBEAT_PERIOD_S)
    assert sent == datagrams
