"""`unreachable` says no answer came, never that the drone did not run the command (session
16 command review).

The commander calls a target that has not answered by the end of the validity plus 2 s
``unreachable`` (``not_reached_while_valid``): the command can no longer *start* there.
It cannot know the drone did not run it: the drone may have received it and answered, and
its answers may all have been lost since (a lossy or one-way link); the reliable writer
repairs them later and the row turns ``completed``. swarmctl said "it can no longer run
there" and, in its last line, "unreachable while valid, will not run there", about a drone
that was climbing. ``bench/unreachable_but_ran.py`` counts it on the virtual-time swarm,
10 members, 100 take-offs per line, every user datagram lost with the probability given
each way: at 0.3 loss 1 row `unreachable`, none ran; at 0.5, 2 of 13 ran; at 0.6, 3 of 22;
at 0.7, 11 of 91 (LAND at 0.7: 2 of 14).
"""

from __future__ import annotations

import argparse

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.dataplane import CommandKind
from swarmd.px4.vehicle import TaskKind
from swarmd.swarm.commander import NOT_REACHED, UNREACHABLE, UNREACHABLE_GRACE_S
from swarmd.swarm.core import DEFAULT_VALID_FOR_S
from tests.test_cmd_validity import _Outcomes
from tests.test_swarm_core import Swarm


def test_a_drone_whose_answers_are_lost_is_not_said_not_to_have_run(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """m01 receives the TAKEOFF and runs it; everything it sends the commander is lost
    until after the verdict. [fails on main: swarmctl said 'will not run there' of m01,
    which was climbing]"""
    swarm = Swarm(2, seed=16)
    m01, lead = swarm.ids["m01"], swarm.ids["lead"]
    muted = [False]
    swarm.net.link_loss = lambda src, dst: 1.0 if muted[0] and (src, dst) == (m01, lead) else 0.0
    swarm.run(3.0)
    muted[0] = True  # m01's way back goes (range, interference at the commander)
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    cid = int(sent["command_id"])
    swarm.run(DEFAULT_VALID_FOR_S[CommandKind.TAKEOFF] + UNREACHABLE_GRACE_S + 0.5)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]  # it ran
    snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
    assert snap["done"]
    assert (snap["nodes"]["m01"]["state"], snap["nodes"]["m01"]["reason"]) == (
        UNREACHABLE,
        NOT_REACHED,
    )
    args = argparse.Namespace(json=False, timeout=30.0)
    reply = {"command_id": cid, "ready": sent["ready"], "valid_for_s": snap["valid_for_s"]}
    code = takeoff_cmd._follow(_Outcomes(snap), takeoff_cmd._Run(args), reply, "takeoff")  # type: ignore[arg-type]
    out = capsys.readouterr().out
    assert code == 1
    line = next(x for x in out.splitlines() if x.startswith("  m01:"))
    assert "no answer" in line and "no longer start there" in line, line
    assert "its answer is late" in line and f"swarmctl outcomes {cid:#x}" in line, line
    assert "will not run" not in out and "no longer run" not in out, out
    assert out.splitlines()[-1].endswith("no answer while valid, can no longer start there: m01")
    # the way back returns: the answers are repaired and the row tells the truth
    muted[0] = False
    swarm.run(10.0)
    row = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"]["m01"]
    assert row["state"] == "completed"
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]
