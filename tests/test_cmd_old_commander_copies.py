"""A commander restarted in a new boot epoch while its earlier life's copies are still on
the air (session 12 review; docs/dataplane.md, "Writer restarts", "Validity").

The attacker holds m01's copies of a TAKEOFF (m01 cut off) and the commander's daemon
restarts (epoch 1 -> 2). Until m01 has the new SPDP it still knows the commander in
epoch 1, so a held copy authenticates: it runs once if still valid (the command was
issued, in its validity), and never after; once m01 knows epoch 2, every copy of epoch 1
is refused (``auth_stale_epoch``). What is left (docs/security.md, residual "A commander
restarted while its command is valid"): m01's answer is sealed to the commander's earlier
epoch, which the new life refuses (``auth_receiver_epoch``), and when m01 learns the new
epoch its outcome writer starts afresh for it (a new volatile reader): no tracker row says
the TAKEOFF ran, only m01's readiness row (armed, in the air) shows it.
"""

from __future__ import annotations

import pytest

from swarmd.px4.vehicle import TaskKind
from tests.test_cmd_in_flight import Flight
from tests.test_cmd_memory import _restart_commander
from tests.test_cmd_validity import _command_datagrams, _cut_takeoff
from tests.test_dataplane_swarm import address_of
from tests.test_swarm_core import Swarm


def _release(swarm: Swarm, datagram: bytes) -> None:
    core = swarm.cores["m01"]
    source = address_of(swarm.bundle, "lead")
    swarm.call("m01", lambda now: core.receive_datagram(datagram, source, now))


@pytest.mark.parametrize("late", [False, True])
def test_an_earlier_commander_lifes_copy_runs_once_in_its_validity_and_never_after(
    late: bool,
) -> None:
    flight = Flight(1, seed=61)
    swarm = flight.swarm
    cid, sent_at = _cut_takeoff(swarm)  # valid 3 s
    swarm.run(1.0)  # the commander's repairs towards m01, held too
    held = _command_datagrams(swarm, cid, "m01", sent_at)
    assert len(held) >= 2
    # the commander restarts in epoch 2 and finds m01 at once; m01 has not heard it yet
    lead = _restart_commander(flight, epoch=2, incarnation=2, members_hear_it=False)
    swarm.net.isolate(swarm.ids["m01"], False)
    swarm.run(3.0 if late else 0.3)
    _release(swarm, held[0])  # m01 still knows the commander in epoch 1
    swarm.run(1.0)
    ran = [r.kind for r in swarm.requests("m01")]
    assert ran == ([] if late else [TaskKind.TAKEOFF])
    m01 = swarm.cores["m01"].executor_status()["counters"]
    assert m01.get("refused_expired", 0) == int(late)
    lead_plane = lead.plane
    assert lead_plane is not None
    assert lead_plane.counters["dropped_auth_receiver_epoch"] >= 1  # m01's answer
    # m01 learns the commander's new life: no copy of the earlier one counts any more
    m01_core = swarm.cores["m01"]
    swarm.call(
        "m01", lambda now: m01_core.peer_up("lead", address_of(swarm.bundle, "lead"), 2, now)
    )
    for copy in held[1:]:
        _release(swarm, copy)
    swarm.run(2.0)
    assert [r.kind for r in swarm.requests("m01")] == ran
    plane = m01_core.plane
    assert plane is not None
    assert plane.counters["dropped_auth_stale_epoch"] == len(held) - 1
    assert lead.tracker.unknown_outcomes == 0  # the residual: the answer never arrives
