"""The log lines a captured member's genuine datagrams drive at a daemon (session 16,
h-insider16).

Attacker 2 of docs/security.md: its key signs, so every datagram that moves its locators
or flips its ROS 2 alive word (PID 0x8A06) is taken, and each was a ``peer_locators_changed``
and a ``peer_ros2_liveness`` info line: up to 4 a datagram (``MAX_SPDP_SAMPLES``), within its
verification budget of 20 a second, burst 40. Now at most ``PEER_CHANGE_REPORTS_PER_S`` a
second per peer and kind (burst ``PEER_CHANGE_REPORT_BURST``) reach the log, the rest are
counted (``peer_changes_suppressed``), as the commander's readiness lines are
(``swarmd.changereports``). What the change does is not held: the status has the newest.

Real sockets: uav2's signed datagrams sent back to back to uav1's daemon on loopback;
counters and log lines asserted, no timing.
"""

from __future__ import annotations

from pathlib import Path

from structlog.testing import capture_logs
from swarmd_lab.testing import auth_for, peer_datagram

from swarmd.daemon import Daemon
from swarmd.daemon_events import PEER_CHANGE_REPORT_BURST
from swarmd.rawclock import run_on_raw_clock
from tests.daemon_support import run_domain, write_bundle
from tests.test_daemon_loopback import _peer, _until
from tests.test_foreign_decode_cost import _sent_to_a_daemon

DATAGRAMS = 40  # its verification budget's burst: all taken at once


def test_a_captured_members_moves_and_liveness_flips_are_logged_at_a_bounded_rate(
    workdir: Path,
) -> None:
    files = write_bundle(workdir, 2, domain_id=run_domain())
    auth = auth_for(files.bundle, 1, epoch=1)
    # each datagram: another default locator (loopback: it comes over loopback) and another
    # ROS 2 alive word
    pool = [
        peer_datagram(
            files.bundle,
            1,
            sequence_number=1 + i,
            auth=auth,
            host="127.0.0.1",
            default_host=f"127.0.0.{2 + i}",
            ros2_alive=bytes((1 + i,)),
        )
        for i in range(DATAGRAMS)
    ]

    async def check(daemon: Daemon) -> None:
        engine = daemon.engine
        assert engine is not None
        newest = f"127.0.0.{1 + DATAGRAMS}"
        await _until(
            lambda: any(newest in str(x) for x in engine.peers()[0].default_unicast_locators),
            lambda: str(engine.counters()),
        )
        changes = DATAGRAMS - 1  # the first is its discovery
        logged = [e for e in logs if e["event"] == "peer_locators_changed"]
        flips = [e for e in logs if e["event"] == "peer_ros2_liveness"]
        # on main: 39 and 40 lines
        assert 1 <= len(logged) <= PEER_CHANGE_REPORT_BURST + 1
        assert 1 <= len(flips) <= PEER_CHANGE_REPORT_BURST + 1
        suppressed = daemon.status()["counters"]["daemon"]["peer_changes_suppressed"]
        # liveness: its first word is news too (the discovery carries it)
        assert suppressed == changes - len(logged) + (changes + 1) - len(flips)
        assert _peer(daemon.status(), "uav2")["state"] == "discovered"

    with capture_logs() as logs:
        run_on_raw_clock(_sent_to_a_daemon(workdir, pool, check, files))
