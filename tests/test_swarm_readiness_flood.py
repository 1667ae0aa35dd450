"""A captured member's readiness flapping at the commander (review 16).

Attacker 2 of docs/security.md: m01's node key and pair keys, so its readiness samples are
genuine. Each sample whose verdict differs from the last (ready, then not ready with a new
reason) was reported as ``MemberReadinessChanged``, which the daemon logs at info
(``member_readiness``): one line per sample, as fast as m01 writes them, whatever the
readiness period. The outcome flood (``tests/test_swarm_outcome_flood.py``) was bounded in
session 10; this is its twin on the other topic a member writes. The bound: each member's
changes are reported at most ``READINESS_REPORTS_PER_S`` a second (burst
``READINESS_REPORT_BURST``), the rest counted (``readiness_changes_suppressed``), and the
readiness tick reports the member's verdict once the flapping stops, so the log ends on
the table's word. The table itself (``swarmctl status``) follows every sample. Virtual
time, the swarm core on the data plane's in-memory network.
"""

from __future__ import annotations

from functools import partial

from swarmd.dataplane.types import Readiness
from swarmd.swarm.events import MemberReadinessChanged
from tests.test_swarm_core import Swarm, Verdict


def _flap(seq: int) -> Readiness:
    ready = seq % 2 == 0
    return Readiness(
        node="m01",
        seq=seq,
        ready=ready,
        reason="" if ready else f"flap-{seq}",
        armed=False,
        landed_state=1,
        gps_fix=3,
        satellites=12,
        battery_pct=90,
        link_q_permille=800,
    )


def _changes(swarm: Swarm, member: str) -> list[MemberReadinessChanged]:
    return [
        e
        for e in swarm.events["lead"]
        if isinstance(e, MemberReadinessChanged) and e.member == member
    ]


def test_a_captured_members_flapping_readiness_is_reported_at_a_bounded_rate() -> None:
    swarm = Swarm(2)
    swarm.run(2.0)
    captured = swarm.cores["m01"].plane
    assert captured is not None
    before = len(_changes(swarm, "m01"))
    flips, flood_s = 400, 2.0
    for k in range(flips):
        swarm.call("m01", partial(captured.publish_readiness, _flap(10_000 + k)))
        swarm.run(flood_s / flips)
    delivered = swarm.lead.counters.get("readiness_changes_suppressed", 0) + len(
        _changes(swarm, "m01")
    )
    assert delivered - before > 100  # the samples did reach the commander's table
    allowed = 10 + 1 * flood_s  # the bound: 1 a second, a burst of 10 (swarmd.swarm.core)
    assert len(_changes(swarm, "m01")) - before <= allowed
    # the flapping over, m01's own reports (ready) take the table back, and the log ends
    # on the table's word within a few readiness periods
    swarm.run(3.0)
    now = swarm.net.now
    last = _changes(swarm, "m01")[-1]
    assert (last.ready, last.reason) == swarm.lead.table.verdict("m01", now) == (True, None)
    # the honest member is reported as before: its first change after the flood is logged
    swarm.vehicles["m02"].verdict = Verdict(ready=False, reason="gps_fix")
    swarm.run(2.0)
    assert [(c.ready, c.reason) for c in _changes(swarm, "m02")][-1] == (False, "gps_fix")
