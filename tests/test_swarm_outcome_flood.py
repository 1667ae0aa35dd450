"""A captured member's outcome flood at the commander (session 10 network review).

Attacker 2 of docs/security.md: m01's node key and pair keys, so its outcome samples are
genuine and reach the commander's tracker. Outcomes for command ids the commander never sent
(or never sent to m01) change nothing there (``CommandTracker.record`` returns False), but
each was reported as ``OutcomeRecorded(known=False)``, which the daemon logs at info
(``command_outcome_received``): one line per invented outcome, as fast as m01 writes them,
several per datagram. The bound: unknown outcomes are reported at most
``UNKNOWN_OUTCOME_REPORTS_PER_S`` a second (burst ``UNKNOWN_OUTCOME_REPORT_BURST``), the rest
counted (``unknown_outcomes_suppressed``); known outcomes are reported every one. Virtual
time, the swarm core on the data plane's in-memory network.
"""

from __future__ import annotations

from functools import partial

from swarmd.dataplane import CommandResult, DataPlane
from swarmd.swarm.core import UNKNOWN_OUTCOME_REPORT_BURST, UNKNOWN_OUTCOME_REPORTS_PER_S
from swarmd.swarm.events import OutcomeRecorded
from tests.test_swarm_core import Swarm


def invent(plane: DataPlane, command_id: int, now: float) -> int:
    return plane.report_outcome(
        command_id, CommandResult.COMPLETED, now, "forged", commander="lead"
    )


def test_invented_outcomes_from_a_captured_member_are_reported_at_a_bounded_rate() -> None:
    swarm = Swarm(2)
    swarm.run(2.0)
    captured = swarm.cores["m01"].plane
    assert captured is not None
    invented, flood_s = 400, 2.0
    for k in range(invented):
        command_id = 900_000 + k
        swarm.call("m01", partial(invent, captured, command_id))
        swarm.run(flood_s / invented)
    swarm.run(1.0)
    unknown = [e for e in swarm.events["lead"] if isinstance(e, OutcomeRecorded) and not e.known]
    assert swarm.lead.tracker.unknown_outcomes == invented  # every one reached the tracker
    allowed = UNKNOWN_OUTCOME_REPORT_BURST + UNKNOWN_OUTCOME_REPORTS_PER_S * (flood_s + 1.0)
    assert len(unknown) <= allowed
    assert swarm.lead.counters["unknown_outcomes_suppressed"] == invented - len(unknown)
    # the real commander's next command is still reported, every outcome of it
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert {n: s["state"] for n, s in nodes.items()} == {"m01": "completed", "m02": "completed"}
    known = [
        e
        for e in swarm.events["lead"]
        if isinstance(e, OutcomeRecorded) and e.known and e.command_id == sent["command_id"]
    ]
    assert {e.member for e in known} == {"m01", "m02"}
