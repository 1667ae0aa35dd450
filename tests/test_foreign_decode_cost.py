"""What one forged SPDP datagram under an invented prefix costs to decode (review 16).

Attacker 1 of docs/security.md, no key: a datagram whose RTPS header names a GUID prefix
outside the bundle is decoded (within the foreign decode budget) to be listed as a foreign
participant. The budget counted datagrams, 50 a second, on the premise that a decode costs
~50 us. Two things broke it:

- the codec sorted another vendor's parameters by ``params.index``, quadratic in their
  number: one 64 KiB DATA(p) of ~16,000 empty parameters and one swarmd vendor PID cost
  ~2 s of the daemon's loop on this machine (``bench/foreign_decode_cost.py``), and the
  budget let 50 of them through at once;
- even decoded in one pass, a decode's work grows with the datagram's octets (~9 ms for
  64 KiB), so a count of datagrams does not bound it: the budget is now also in octets.

The first counts parameter comparisons, the second runs the engine on virtual time, the
third sends the datagrams to a real daemon's SPDP port on loopback (64 KiB datagrams do
arrive whole) and asserts counters only.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import socket
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from swarmd_lab.testing import auth_for, peer_datagram

import swarmd.rtps.parameters as parameters
from swarmd.auth.spdp import PLACEHOLDER
from swarmd.control import MAX_LINE_BYTES, encode_line, request
from swarmd.daemon import Daemon
from swarmd.discovery import PeerDiscovered, PeerRos2Liveness
from swarmd.discovery.engine import MAX_PENDING_EVENTS
from swarmd.discovery.foreign import (
    FOREIGN_DECODE_BURST,
    FOREIGN_DECODE_OCTET_BURST,
    FOREIGN_DECODE_OCTETS_PER_S,
)
from swarmd.discovery.peers import MAX_FOREIGN
from swarmd.rawclock import run_on_raw_clock
from swarmd.rtps.message import Data, Submessage, decode_header, decode_message, encode_message
from swarmd.rtps.parameters import Parameter
from swarmd.rtps.spdp import MAX_SPDP_SAMPLES, SWARMD_PIDS, SpdpAlive, decode_spdp, encode_spdp
from swarmd.rtps.types import GuidPrefix
from tests.attacker.forge import (
    MAX_UDP_PAYLOAD,
    bloated_participant,
    foreign_participant,
    many_samples,
)
from tests.daemon_support import BundleFiles, loopback_daemon, run_domain, write_bundle
from tests.test_daemon_loopback import _until
from tests.test_discovery_auth import A1, BUNDLE, drain, receiver


def _invented(i: int) -> GuidPrefix:
    return GuidPrefix(b"\xf0\x0d" + i.to_bytes(10, "big"))


def test_decoding_a_forged_data_p_compares_each_parameter_a_bounded_number_of_times(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Linear work: the decoder compares no parameter with the others (it used to, for a
    sort by list position, ~n^2 / 2 comparisons: 56,000 for this one Wi-Fi frame)."""
    compared = 0

    class Counted(Parameter):
        __slots__ = ()

        def __eq__(self, other: object) -> bool:
            nonlocal compared
            compared += 1
            return tuple.__eq__(self, other)

        def __ne__(self, other: object) -> bool:
            return not self == other

        __hash__ = tuple.__hash__

    monkeypatch.setattr(parameters, "_new_parameter", lambda _cls, fields: Counted(*fields))
    datagram = bloated_participant(_invented(1), size=1400)
    _header, (sample,) = decode_spdp(datagram)
    assert isinstance(sample, SpdpAlive)
    n = len(sample.participant.extra_parameters)
    assert n > 300  # the forgery: one frame, hundreds of parameters kept opaque, in order
    pids = [p.pid for p in sample.participant.extra_parameters]
    assert pids[0] in SWARMD_PIDS and pids[1:] == sorted(pids[1:])  # as on the wire
    assert compared <= n


def test_a_flood_of_maximum_size_foreign_datagrams_decodes_a_bounded_number_of_octets() -> None:
    """The foreign decode budget holds octets as well as datagrams: at one instant only what
    fits its octet burst is decoded (it was 50 datagrams of 64 KiB, whatever their size),
    and over a flood no more than its octet rate; a stock participant's small DATA(p) is
    decoded as before once the flood stops."""
    e = receiver()
    pool = [bloated_participant(_invented(i)) for i in range(8)]
    assert all(len(d) > MAX_UDP_PAYLOAD - 8 for d in pool)
    for i in range(100):
        e.receive_datagram(pool[i % len(pool)], ("10.7.0.9", 7400), 0.5)
    dropped = e.counters()["dropped"]
    decoded = dropped["not_in_bundle"]
    assert decoded * len(pool[0]) <= FOREIGN_DECODE_OCTET_BURST
    assert decoded < FOREIGN_DECODE_BURST
    assert dropped["foreign_budget"] == 100 - decoded
    # ten seconds of 100 a second: the octet rate bounds what is decoded
    flood_s, count = 10.0, 1000
    for i in range(count):
        e.receive_datagram(pool[i % len(pool)], ("10.7.0.9", 7400), 0.5 + flood_s * i / count)
    decoded = e.counters()["dropped"]["not_in_bundle"]
    octets = decoded * len(pool[0])
    assert octets <= FOREIGN_DECODE_OCTET_BURST + FOREIGN_DECODE_OCTETS_PER_S * (flood_s + 0.5)
    # after the flood, a stock participant's ordinary DATA(p) is decoded and listed
    stock = _invented(999)
    e.receive_datagram(foreign_participant(stock, "stock-node"), ("10.7.0.8", 7400), 12.0)
    assert stock in {f.guid_prefix for f in e.foreign(12.0)}


async def _sent_to_a_daemon(
    workdir: Path,
    pool: list[bytes],
    check: Callable[[Daemon], Awaitable[None]],
    files: BundleFiles | None = None,
) -> None:
    """Start uav1's daemon on loopback (of ``files``, else a new bundle of 2), send ``pool``
    to its unicast SPDP port back to back, wait until it read them all, then ``check`` it;
    stopped either way."""
    if files is None:
        files = write_bundle(workdir, 2, domain_id=run_domain())
    daemon = loopback_daemon(workdir, files, "uav1")
    await daemon.start()
    try:
        engine = daemon.engine
        assert engine is not None
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for datagram in pool:
                sender.sendto(datagram, ("127.0.0.1", engine.metatraffic_port))
        finally:
            sender.close()
        await _until(
            lambda: daemon.counters.get("rx_unicast", 0) >= len(pool),
            lambda: str(daemon.counters),
        )
        await check(daemon)
    finally:
        await daemon.stop("test")


def test_a_daemon_decodes_at_most_one_of_a_burst_of_bloated_datagrams(workdir: Path) -> None:
    """Real sockets: three 64 KiB forgeries under invented prefixes to a daemon's unicast
    SPDP port, back to back. One fits the octet burst and is decoded (and listed), the
    others are counted unread (on main all three were decoded, ~2 s of the loop each)."""
    pool = [bloated_participant(_invented(100 + i)) for i in range(3)]

    async def check(daemon: Daemon) -> None:
        assert daemon.engine is not None
        dropped = daemon.engine.counters()["dropped"]
        assert dropped.get("not_in_bundle", 0) == 1
        assert dropped.get("foreign_budget", 0) == len(pool) - 1

    run_on_raw_clock(_sent_to_a_daemon(workdir, pool, check))


# A name of control characters: each one 6 octets in the status's JSON (\u0001), so 12 of
# these participants make a status reply longer than swarmctl takes (64 x MAX_LINE_BYTES).
HUGE_NAME = "\x01" * 60_000


def test_invented_participants_with_huge_names_cannot_grow_the_status() -> None:
    """Review 16: an ENTITY_NAME was taken at any length (the codec's 256-octet bound, which
    Fast DDS applies, was never used), so the foreign table's 64 rows could hold 64 KiB
    names each, in every ``swarmctl status`` and in the log. Now a DATA(p) whose name or
    domain tag is longer than ``MAX_STRING_OCTETS`` is refused (``decode_error``), as Fast
    DDS refuses it. The budgets are let refill between datagrams: only the names decide."""
    e = receiver()
    for i in range(MAX_FOREIGN):
        e.receive_datagram(
            foreign_participant(_invented(500 + i), HUGE_NAME), ("10.7.0.9", 7400), 2.0 * i
        )
    now = 2.0 * MAX_FOREIGN
    assert len(encode_line(e.status(now))) < MAX_LINE_BYTES
    assert e.counters()["dropped"]["decode_error"] == MAX_FOREIGN
    # an ordinary stock name is listed as before
    e.receive_datagram(foreign_participant(_invented(999), "stock-node"), ("10.7.0.8", 7400), now)
    assert [f.name for f in e.foreign(now)] == ["stock-node"]


def test_swarmctl_status_survives_invented_participants_with_huge_names(workdir: Path) -> None:
    """Real sockets: 12 such datagrams to a daemon's SPDP port, then the control socket's
    status, as ``swarmctl status`` asks it. On main the 12 were decoded at once (the
    budget's burst) and the reply was over 4 MiB: swarmctl refused it, "reply too long"."""
    pool = [foreign_participant(_invented(600 + i), HUGE_NAME) for i in range(12)]

    async def check(daemon: Daemon) -> None:
        status = await asyncio.to_thread(request, str(workdir / "uav1.sock"), "status")
        assert status["node"] == "uav1"
        assert len(json.dumps(status)) < MAX_LINE_BYTES

    run_on_raw_clock(_sent_to_a_daemon(workdir, pool, check))


def test_drop_reports_of_forged_datagrams_never_push_a_peers_event_out() -> None:
    """Review 16: the engine's queue of undrained events holds ``MAX_PENDING_EVENTS`` and
    made room by dropping the oldest, whatever it was. One forged datagram of 1,024 minimal
    DATA(p)s in another domain was 1,024 drop reports (``wrong_domain``, one a sample):
    read in the same batch after a member's genuine DATA(p), it pushed that member's
    ``PeerDiscovered`` out before the daemon drained it, so the data plane never had the
    member up. A datagram now carries at most ``MAX_SPDP_SAMPLES`` (the next test), and
    the queue's rule holds whatever fills it: a drop report never displaces anything. Here
    more reports than the queue holds, over time and never drained (the daemon drains each
    batch): the member's event is still there."""
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=3)), A1, 0.1)
    pool = [many_samples(_invented(700 + i), MAX_SPDP_SAMPLES) for i in range(8)]
    for i in range(MAX_PENDING_EVENTS // 2):
        e.receive_datagram(pool[i % len(pool)], ("10.7.0.9", 7400), 0.1 + 0.05 * i)
    assert e.counters()["dropped"]["wrong_domain"] > MAX_PENDING_EVENTS  # every one counted
    found = [x for x in drain(e) if isinstance(x, PeerDiscovered)]
    assert [x.name for x in found] == [BUNDLE.participants[1].name]


def _captured_many(count: int) -> bytes:
    """A captured member's (uav1's) one signed datagram of ``count`` DATA(p)s of itself,
    its relay's alive word flipping from one to the next (PID 0x8A06), the last one
    carrying the authenticator: genuine, its tag and signature hold."""
    samples: list[Submessage] = []
    for i in range(count):
        plain = peer_datagram(BUNDLE, 1, sequence_number=1 + i, ros2_alive=bytes([1 + i % 2]))
        _header, (alive,) = decode_spdp(plain)
        assert isinstance(alive, SpdpAlive)
        part = alive.participant
        if i == count - 1:
            part = dataclasses.replace(part, authenticator=PLACEHOLDER)
        single = encode_spdp(part, sequence_number=1 + i, timestamp=None)
        samples += [sm for sm in decode_message(single).submessages if isinstance(sm, Data)]
    header = decode_header(plain)
    return auth_for(BUNDLE, 1, epoch=3).seal(encode_message(header, samples))


def test_a_captured_members_datagram_of_many_samples_is_refused_whole() -> None:
    """Review 16: the decoder took any number of DATA(p)s in one datagram, and a captured
    member's are genuine (one signature covers them all). 200 of itself, its ROS 2 alive
    word flipping from each to the next, were 200 ``PeerRos2Liveness`` events (a
    ``peer_ros2_liveness`` info line each, and at 40 such datagrams a burst, enough to push
    other peers' events out of the full queue). swarmd sends one DATA(p) a datagram, stock
    stacks too: more than ``MAX_SPDP_SAMPLES`` is a ``decode_error``, before any is read."""
    e = receiver()
    many = _captured_many(200)
    assert len(many) <= MAX_UDP_PAYLOAD
    e.receive_datagram(many, A1, 0.1)
    events = drain(e)
    assert sum(isinstance(x, PeerRos2Liveness) for x in events) <= MAX_SPDP_SAMPLES
    assert e.counters()["dropped"]["decode_error"] == 1
    # its ordinary one-sample datagrams are taken as before
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=4)), A1, 0.2)
    assert [x.name for x in drain(e) if isinstance(x, PeerDiscovered)] == ["uav1"]
