"""The edge of the commander's dating record (``ledger.MAX_DATED_COMMANDS`` = 64), and the
end of a life's 32-bit command counter (docs/dataplane.md, "A life runs only its own
commands"; session 12 review).

A resend of an id carries its first dating while the commander keeps it (the last 64 ids
it sent); past that an id of this life goes with no echo, and every member refuses it
(``expired``: fail closed), whatever echo its caller gave. The attack pinned: 65 distinct
commands, then the first one resent with a fresh echo and validity to a member that
never got it (cut off during its validity). With the caller's dating it would run after
its own validity; it is refused, and the member that ran it drops it as a duplicate.
"""

from __future__ import annotations

import pytest

from swarmd.dataplane import CommandIdsExhausted
from swarmd.dataplane.ledger import MAX_DATED_COMMANDS
from swarmd.dataplane.types import Command, CommandKind
from swarmd.dataplane.validity import EXPIRED
from swarmd.px4.vehicle import TaskKind
from swarmd.swarm.core import RequestInvalid
from swarmd.swarm.events import OutcomeReported
from tests.test_swarm_core import Swarm


@pytest.mark.parametrize("newer", [MAX_DATED_COMMANDS - 1, MAX_DATED_COMMANDS])
def test_a_resend_past_the_dating_window_never_runs_late(newer: int) -> None:
    swarm = Swarm(2, seed=12)
    swarm.run(3.0)
    swarm.net.isolate(swarm.ids["m02"])  # m02 never hears the first TAKEOFF
    first = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    cid = int(first["command_id"])
    swarm.run(0.5)
    for _ in range(newer):  # distinct commands to m01 only, each dated and kept
        swarm.call(
            "lead", lambda now: swarm.lead.request_command({"kind": "hold", "only": ["m01"]}, now)
        )
    swarm.run(5.0)  # the TAKEOFF's 3 s are over, withdrawn; m02 back
    swarm.net.isolate(swarm.ids["m02"], False)
    swarm.run(2.0)
    plane = swarm.lead.plane
    assert plane is not None
    members = ["m01", "m02"]
    fresh = Command(
        cid, CommandKind.TAKEOFF, 5.0, members, 3000, plane.time_echoes(members, swarm.net.now)
    )
    assert {e.node for e in fresh.echoes} == set(members)  # the caller's dating would pass
    swarm.call("lead", lambda now: plane.send_command(fresh, now))
    swarm.run(5.0)
    undated = newer >= MAX_DATED_COMMANDS
    assert plane.counters["command_resent_undated"] == int(undated)
    assert plane.counters["command_resent"] == 1
    assert [r.kind for r in swarm.requests("m02")] == []
    m02 = swarm.cores["m02"].executor_status()["counters"]
    assert m02["refused_expired"] == 1
    # m02's answer (the commander's tracker keeps 64 commands too: past the window it no
    # longer has the row, and counts the answer as unknown)
    said = [(e.command_id, e.reason) for e in swarm.events["m02"] if isinstance(e, OutcomeReported)]
    assert said == [(cid, EXPIRED)]
    assert [r.kind for r in swarm.requests("m01")].count(TaskKind.TAKEOFF) == 1
    m01_plane = swarm.cores["m01"].plane
    assert m01_plane is not None and m01_plane.counters["command_duplicate"] >= 1


def test_the_counter_never_spills_into_other_ids() -> None:
    """The id is ``epoch << 32 | counter``: the 2^32-th counter ORed into the epoch's bits
    (for an odd epoch, the (2^32 + k)-th id was this life's k-th again: swallowed as a
    duplicate where that one ran). ``make_command`` refuses to go past 2^32 - 1."""
    swarm = Swarm(1, seed=13)
    swarm.run(2.0)
    plane = swarm.lead.plane
    assert plane is not None
    plane._next_command = (1 << 32) - 2  # noqa: SLF001 - the counter after 4.3 billion ids
    last = plane.make_command(CommandKind.HOLD, targets=["m01"], valid_ms=5000)
    assert last.command_id == (plane.epoch << 32) | 0xFFFF_FFFF
    with pytest.raises(CommandIdsExhausted):
        plane.make_command(CommandKind.HOLD, targets=["m01"], valid_ms=5000)
    with pytest.raises(CommandIdsExhausted):  # and stays so: no id comes round again
        plane.make_command(CommandKind.HOLD, targets=["m01"], valid_ms=5000)
    # the operator is told: the request is refused, nothing tracked or sent
    with pytest.raises(RequestInvalid, match="command ids"):
        swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
