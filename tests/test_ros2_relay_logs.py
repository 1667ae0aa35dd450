"""The log lines the ROS 2 relay's adapter (swarmd.ros2app) writes for what others make
happen (review 18).

Session 16 (h-insider16) bounded the daemon's own lines for a captured member's signed
changes (``peer_ros2_liveness``, ``peer_locators_changed``: 1 a second per peer, burst 10),
and review 16 the relay's ``ros2_unknown_participant``. The relay's own lines for the same
changes were left: the daemon hands the relay every ``PeerRos2Liveness`` and every move
(``swarmd.daemon_events``: only its own line is budgeted), and the relay logged a
``ros2_remote_node_liveness`` per node per flip and a ``ros2_relay_peer`` per move. On its
own drone, a local process (any user, without ``ros2.node_users``) sending a declared
node's dispose and DATA(p) in turn made three lines of each pair
(``ros2_node_liveness`` twice, ``ros2_participant_heard``), as fast as it could send. Such
floods make journald's per-unit rate limit drop the daemon's other lines. Now each of
those lines is logged at most ``RELAY_LINES_PER_S`` a second per peer or node (burst
``RELAY_LINE_BURST``), the next one carrying how many were held back (``suppressed``),
counted ``lines_suppressed``; what the relay does (disposes, announcements, the signed
liveness word) is not held.

Real sockets and the real adapter (as tests/test_local_uid.py); counts, no timing
asserted (the budget's refill over the run's own time is allowed for).
"""

from __future__ import annotations

import asyncio
import socket
from typing import Any

from swarmd.ros2app import RELAY_LINE_BURST, RELAY_LINES_PER_S, Ros2App
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp, encode_spdp_dispose
from swarmd.rtps.types import Duration, GuidPrefix, VendorId
from tests.test_local_uid import _lead_node, _Log, _node_spdp, _ros2_app, _until

FLIPS = 200  # a captured member's 10 s at its verification budget of 20 signed DATA(p)/s
PAIRS = 200  # a local process's dispose + DATA(p) pairs, sent back to back
LISTS = 100  # a local process's DATA(p)s of a node, two lists of 32 undeclared in turn


def _allowed(elapsed_s: float) -> float:
    """The most lines one key may have in a run of ``elapsed_s``: its burst and the refill."""
    return RELAY_LINE_BURST + RELAY_LINES_PER_S * elapsed_s


def _lines(lines: list[tuple[str, dict[str, Any]]], event: str) -> list[dict[str, Any]]:
    return [fields for name, fields in lines if name == event]


def test_a_captured_members_flips_and_moves_reach_the_relays_lines_at_a_bounded_rate() -> None:
    """drone-1 (its key captured) flips its talker's alive bit and moves its address on
    every signed DATA(p): the daemon passes each on (authenticated), the relay announces
    the node at each new address and acts on its word (at most once per
    ``LIVENESS_MIN_INTERVAL_S``: tests/test_ros2_liveness.py), and logs a bounded number of
    lines. [fails on main: 200 ``ros2_remote_node_liveness`` and 201 ``ros2_relay_peer``
    lines]"""

    def relayed(app: Ros2App) -> bool:
        return any(
            r["drone"] == "drone-1" and r["state"] == "relayed" for r in app.status(0.0)["remote"]
        )

    async def main() -> tuple[dict[str, Any], list[tuple[str, dict[str, Any]]], float]:
        log = _Log()
        app = _ros2_app(None, log, [])
        loop = asyncio.get_running_loop()
        app.start(loop)
        try:
            start = loop.time()
            app.peer_up("drone-1", "10.42.0.11")
            for i in range(FLIPS):
                app.peer_liveness("drone-1", bytes((i % 2,)))  # down, up, down, ...
                app.peer_up("drone-1", f"10.42.{1 + i // 200}.{11 + i % 200}")
            # its last word (up) is acted on at the interval's end, or held by the drone's
            # damping (review 18b, up to FLAP_HOLD_MAX_S): late, never lost
            assert await _until(lambda: relayed(app) or app.relay.liveness_due() is not None)
            return app.status(0.0), log.lines, loop.time() - start
        finally:
            app.close()

    status, lines, elapsed = asyncio.run(main())
    flips = _lines(lines, "ros2_remote_node_liveness")
    moves = _lines(lines, "ros2_relay_peer")
    assert 1 <= len(flips) <= _allowed(elapsed)
    assert 1 <= len(moves) <= _allowed(elapsed)
    # every move held back is counted; the relay served each new address
    assert status["counters"]["lines_suppressed"] >= FLIPS + 1 - len(moves)
    assert status["counters"]["tx_spdp"] >= FLIPS
    row = next(r for r in status["remote"] if r["drone"] == "drone-1")
    last = FLIPS - 1
    assert row["user_locator"].startswith(f"10.42.{1 + last // 200}.{11 + last % 200}:")


async def _sent_to_the_leads_relay(
    datagrams: list[bytes],
) -> tuple[dict[str, Any], list[tuple[str, dict[str, Any]]], list[bytes], float]:
    """``datagrams`` from one local socket (any user: ``ros2.node_users`` unset) to the
    lead's relay, run by the real adapter: its status, log lines, the liveness words it
    handed swarmd, and the run's own time."""
    log, alive = _Log(), list[bytes]()
    app = _ros2_app(None, log, alive)
    loop = asyncio.get_running_loop()
    app.start(loop)
    relay_at = ("::1", app.config.ros2.relay_port)
    try:
        start = loop.time()
        with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as sender:
            sender.bind(("::1", 0))
            for i, data in enumerate(datagrams):
                sender.sendto(data, relay_at)
                if i % 40 == 39:  # let the loop read: the socket's buffer is finite
                    await _until(lambda n=i + 1: app.relay.counters["rx"] >= n)
        assert await _until(lambda: app.relay.counters["rx"] >= len(datagrams))
        return app.status(0.0), log.lines, alive, loop.time() - start
    finally:
        app.close()


def test_a_local_process_cycling_a_declared_nodes_lives_reaches_the_log_at_a_bounded_rate() -> None:
    """A local process (any user: ``ros2.node_users`` unset) sends the lead's declared
    node's DATA(p[UD]) and DATA(p) in turn: each pair is a life to the relay (it is trusted
    as the node, docs/security.md), and each life still reaches the signed liveness word.
    The lines about it are bounded. [fails on main: 400 ``ros2_node_liveness`` and 200
    ``ros2_participant_heard`` lines for 200 pairs]"""
    node = _lead_node()
    dispose = encode_spdp_dispose(GuidPrefix(node.guid_prefix), sequence_number=2, timestamp=None)
    pairs = [dispose, _node_spdp(node, 1)] * PAIRS
    status, lines, alive, elapsed = asyncio.run(_sent_to_the_leads_relay(pairs))
    liveness = _lines(lines, "ros2_node_liveness")
    heard = _lines(lines, "ros2_participant_heard")
    assert 1 <= len(liveness) <= _allowed(elapsed)
    assert 1 <= len(heard) <= _allowed(elapsed)
    # what swarmd signs moved with every life: the lines are held, not the word
    assert len(alive) == 2 * PAIRS
    assert status["local"][0]["restarts"] == (PAIRS - 1) % 256
    counters = status["counters"]
    assert counters["lines_suppressed"] == 2 * PAIRS - len(liveness) + PAIRS - len(heard)
    # the line after a pause says what it stands for
    assert all(isinstance(f["suppressed"], int) for f in liveness + heard)


def _listing(node_prefix: bytes, sn: int, entities: range) -> bytes:
    """A declared node's DATA(p) listing undeclared writers (no id: 65535) by entity."""
    return encode_spdp(
        SpdpParticipant(
            GuidPrefix(node_prefix),
            lease_duration=Duration.from_seconds(100.0),
            vendor_id=VendorId(b"\x01\x0f"),
            entity_name="/",
            properties=tuple(
                ("eProsimaEDPStatic_Writer_ALIVE_ID_65535", f"0.0.{i}.3") for i in entities
            ),
        ),
        sequence_number=sn,
        timestamp=None,
    )


def test_a_local_process_alternating_undeclared_lists_reaches_the_log_at_a_bounded_rate() -> None:
    """Review 18b: a node's undeclared rows are what its latest DATA(p) lists, and a row is
    reported when it appears. A local process (``ros2.node_users`` unset) sending the
    node's DATA(p) with two lists of 32 in turn makes every datagram 32 new rows; the
    ``ros2_undeclared_endpoint`` warnings are budgeted as the relay's other lines, per node.
    [without the budget: 32 lines a datagram, 3,200 here]"""
    prefix = _lead_node().guid_prefix
    lists = [
        _listing(prefix, 2 + i, range(1, 33) if i % 2 == 0 else range(101, 133))
        for i in range(LISTS)
    ]
    status, lines, _alive, elapsed = asyncio.run(_sent_to_the_leads_relay(lists))
    undeclared = _lines(lines, "ros2_undeclared_endpoint")
    assert 1 <= len(undeclared) <= _allowed(elapsed)
    assert status["local"][0]["undeclared_not_shown"] == 0
    assert len(status["local"][0]["undeclared_endpoints"]) == 32
    # every row reported reached the budget (the relay's event queue may drop some first)
    assert 0 < status["counters"]["lines_suppressed"] <= 32 * LISTS - len(undeclared)
