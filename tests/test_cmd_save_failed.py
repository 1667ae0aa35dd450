"""A failed save of the state file, then a restart (docs/dataplane.md, "A failed save").

The member writes the executed id before the vehicle moves (``PersistExecuted``, the
write-ahead) and each outcome after it is decided. When that write fails (a full or
read-only state dir) the daemon logs it and the command still runs. Could it then run a
second time? The state dir holds what the last successful write left: the earlier
commands, not this one. So a restart boots on a file without its id, as after a lost
file, and every path that can bring the id back meets the new life's own rule ("A life
runs only its own commands"): the commander's resend carries the first dating (an echo of
the earlier life: ``memory_lost``), its repairs and hand-overs are voided at the new epoch,
and captured datagrams are sealed to the earlier epoch. These tests drive each kind through
that sequence on virtual time, with the answer delivered or lost, and a second restart on
what the new life wrote: the vehicle is told once. What the record protects is shown by
taking those rules away: then the resend runs a second time exactly when the save failed
(each of the four kinds), and once when it succeeded.

What the failed save does lose is the answer across a restart (no re-report), so the
operator is told: the decision is marked unsaved (``swarmctl outcomes``, ``saved: false``)
until a later write holds it; the daemon's log line and counter are
``tests/test_cmd_memory_loopback.py``'s (a real daemon on a read-only state dir). And
since session 14 the commander's operator is told too: the member sends the decision's
outcome again flagged ``OUTCOME_NOT_SAVED`` (its ACCEPTED went before the write's result
was known), and each later outcome while it stays unsaved; the commander's row keeps the
mark (``save_failed``, ``swarmctl outcomes`` on the commander) until the member says a
later write held it (session 15: ``tests/test_cmd_save_cleared.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from swarmd.dataplane.types import Command, CommandKind, CommandResult
from swarmd.dataplane.validity import MEMORY_LOST, Judgement, ReportLog
from swarmd.swarm import member
from swarmd.swarm.core import SwarmCore
from swarmd.swarm.events import OutcomeRecorded, OutcomeReported, PersistExecuted
from tests.test_cmd_in_flight import Flight, _issue, _reboot
from tests.test_swarm_core import Swarm


def _resend(swarm: Swarm, cid: int, kind: CommandKind) -> None:
    """The commander's code sends ``cid`` again to m01 (same id, new SN), freshly dated by
    its caller from m01's new life: the plane puts the first send's dating back."""
    plane = swarm.lead.plane
    assert plane is not None
    echoes = plane.time_echoes(["m01"], swarm.net.now)
    alt = 5.0 if kind == CommandKind.TAKEOFF else 0.0
    retry = Command(cid, kind, alt, ["m01"], 3000, echoes)
    swarm.call("lead", lambda now: plane.send_command(retry, now))


def _run_saves_failed_and_restart(
    kind: CommandKind, answer_lost: bool, *, saved: bool, seed: int = 60
) -> tuple[Flight, int, int, SwarmCore]:
    """m01 takes a HOLD (written), then ``kind``, whose writes fail unless ``saved``; its
    daemon restarts on what the state dir holds and the commander's code resends the id,
    then once more after a second restart on what the new life wrote."""
    flight = Flight(1, seed=seed)
    swarm = flight.swarm
    swarm.run(3.0)
    earlier = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(0.5)
    on_disk = flight.kept("m01")  # the last write that succeeded: the HOLD and its answer
    assert ("lead", earlier) in on_disk.executed
    if answer_lost:  # the commander keeps repairing the copy it was never acknowledged
        flight.cut = lambda a, b: a == "m01"
    cid = int(_issue(swarm, kind)["command_id"])
    swarm.run(0.3)
    assert len(flight.ran("m01", cid)) == 1  # it ran
    assert ("lead", cid) in flight.kept("m01").executed  # what the writes held
    reborn = _reboot(flight, "m01", state_kept=True, kept=None if saved else on_disk)
    flight.cut = lambda a, b: False
    swarm.run(0.5)
    _resend(swarm, cid, kind)
    swarm.run(10.0)
    # and again, on what the new life wrote (its refusal persisted the id)
    _reboot(flight, "m01", state_kept=True)
    swarm.run(0.5)
    _resend(swarm, cid, kind)
    swarm.run(10.0)
    return flight, earlier, cid, reborn


KINDS = [CommandKind.TAKEOFF, CommandKind.LAND, CommandKind.HOLD, CommandKind.ABORT]


@pytest.mark.parametrize("answer_lost", [False, True])
@pytest.mark.parametrize("kind", KINDS)
def test_a_command_whose_saves_failed_never_runs_again_after_a_restart(
    kind: CommandKind, answer_lost: bool
) -> None:
    flight, earlier, cid, reborn = _run_saves_failed_and_restart(kind, answer_lost, saved=False)
    assert len(flight.ran("m01", cid)) == 1
    assert [r.origin for r in flight.swarm.requests("m01")] == [
        ("lead", earlier),
        ("lead", cid),
    ]
    assert reborn.executor_counters.get("refused_memory_lost") == 1
    refusals = [
        e
        for e in flight.swarm.events["m01"]
        if isinstance(e, OutcomeReported) and e.command_id == cid and e.reason == MEMORY_LOST
    ]
    assert refusals and all(e.result == CommandResult.REJECTED for e in refusals)


@pytest.mark.parametrize("saved", [True, False])
@pytest.mark.parametrize("kind", KINDS)
def test_without_the_life_rules_the_record_is_what_stops_a_second_run(
    kind: CommandKind, saved: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the saved record protects, shown by taking away the rules that stand in front
    of it (the echo's epoch, the clock rule and the report log: ``Member._may_run``): then
    the resend after the restart runs a second time exactly when the save failed. With the
    rules (the test above) it never does, saved or not: the record is the second line."""
    monkeypatch.setattr(member, "another_life", lambda *args: None)
    monkeypatch.setattr(member, "issued_in_life", lambda *args: Judgement(True, 1, ""))
    monkeypatch.setattr(ReportLog, "unknown", lambda *args: None)
    flight, _, cid, _ = _run_saves_failed_and_restart(kind, False, saved=saved)
    assert len(flight.ran("m01", cid)) == (1 if saved else 2)


def test_a_failed_save_marks_the_decision_unsaved_until_a_write_succeeds() -> None:
    """The daemon's answer to each ``PersistExecuted`` (``SwarmCore.state_saved``): a
    failure marks the decision of the command it would have kept, in ``swarmctl outcomes``
    (``saved: false``) and the executor's counters; the next successful write holds every
    decision (the file is written whole), so the mark goes."""
    flight = Flight(1, seed=61)
    swarm = flight.swarm
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(0.5)
    core = swarm.cores["m01"]

    def saved() -> dict[int, bool]:
        ran = core.request_outcomes({}, swarm.net.now)["ran"]
        return {r["command_id"]: r["saved"] for r in ran}

    assert saved() == {cid: True}
    core.state_saved(("lead", cid), "cannot write: No space left on device", swarm.net.now)
    assert saved() == {cid: False}
    assert core.executor_counters["state_save_failed"] == 1
    core.state_saved(("lead", cid), None, swarm.net.now)
    assert saved() == {cid: True}


NO_SPACE = "cannot write: No space left on device"


def _saves(flight: Flight, name: str, fails: Callable[[], bool]) -> None:
    """``name``'s daemon answers each ``PersistExecuted`` at once, as ``SwarmApp._persist``
    does: failed (a full disk) while ``fails()``, else written."""
    swarm = flight.swarm
    on_event = swarm.net.on_event
    assert on_event is not None

    def answer(node_id: int, event: Any, now: float) -> None:
        on_event(node_id, event, now)
        if isinstance(event, PersistExecuted) and node_id == swarm.ids[name]:
            swarm.cores[name].state_saved(event.command, NO_SPACE if fails() else None, now)

    swarm.net.on_event = answer


def _row(flight: Flight, cid: int) -> dict[str, Any]:
    swarm = flight.swarm
    row: dict[str, Any] = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"][
        "m01"
    ]
    return row


def _issued_onto_a_full_disk(seed: int, kind: CommandKind) -> tuple[Flight, dict[str, bool], int]:
    """m01's writes succeed for 3 s, then fail (``disk["full"]``, the caller may empty it)
    from the command of ``kind`` the commander issues then; its id."""
    flight = Flight(1, seed=seed)
    disk = {"full": False}
    _saves(flight, "m01", lambda: disk["full"])
    flight.swarm.run(3.0)
    disk["full"] = True
    return flight, disk, int(_issue(flight.swarm, kind)["command_id"])


@pytest.mark.parametrize("kind", KINDS)
def test_the_commanders_row_says_the_members_save_failed(kind: CommandKind) -> None:
    """The member's writes fail from the command on: its ACCEPTED left before the first
    write's result was known, so the mark follows at once on the same result, and the
    final outcome carries it too; the commander's row keeps it (``save_failed``, shown by
    ``swarmctl outcomes`` there). Before, only the drone's own view said so."""
    flight, _, cid = _issued_onto_a_full_disk(62, kind)
    swarm = flight.swarm
    swarm.run(0.3)  # answered, the task still running (the played vehicle takes 1 s)
    assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == ("accepted", True)
    swarm.run(5.0)
    assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == ("completed", True)
    issued = swarm.lead.request_outcomes({}, swarm.net.now)["issued"]
    assert issued[0]["nodes"]["m01"]["save_failed"] is True
    # the mark changed nothing else: run once, answered once per result, flagged after
    assert len(flight.ran("m01", cid)) == 1
    told = [e for e in swarm.events["m01"] if isinstance(e, OutcomeReported)]
    assert [(e.result, e.saved) for e in told if e.command_id == cid] == [
        (CommandResult.ACCEPTED, True),
        (CommandResult.ACCEPTED, False),
        (CommandResult.COMPLETED, False),
    ]
    recorded = [e for e in swarm.events["lead"] if isinstance(e, OutcomeRecorded)]
    assert [e.saved for e in recorded if e.command_id == cid] == [True, False, False]
    assert swarm.cores["m01"].executor_counters["told_not_saved"] == 1


def test_a_saved_decision_leaves_the_row_unmarked() -> None:
    """The control: every write succeeds, no outcome is flagged, no row is marked."""
    flight = Flight(1, seed=62)
    swarm = flight.swarm
    _saves(flight, "m01", lambda: False)
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(5.0)
    assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == ("completed", False)
    told = [e for e in swarm.events["m01"] if isinstance(e, OutcomeReported)]
    assert all(e.saved for e in told)


def test_a_refusal_whose_save_failed_is_marked_and_a_later_write_clears_the_mark() -> None:
    """A REJECTED decision (a TAKEOFF to a drone that is not ready when it arrives) is
    marked as well; once a later write succeeds the drone's own view says saved again,
    and so does the commander's row: the member tells it (``OUTCOME_NOW_SAVED``, session
    15). Until session 15 the row kept the mark, a false alarm for the rest of the
    session (docs/dataplane.md, "A failed save")."""
    flight, disk, cid = _issued_onto_a_full_disk(63, CommandKind.TAKEOFF)
    swarm = flight.swarm
    swarm.vehicles["m01"].verdict.ready = False  # after the commander's check, before m01's
    swarm.vehicles["m01"].verdict.reason = "gps_no_fix"
    swarm.run(3.0)
    row = _row(flight, cid)
    assert (row["state"], row["reason"], row["save_failed"]) == ("rejected", "gps_no_fix", True)
    assert flight.ran("m01", cid) == []
    disk["full"] = False
    swarm.vehicles["m01"].verdict.ready, swarm.vehicles["m01"].verdict.reason = True, None
    swarm.run(1.0)
    hold = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(5.0)
    ran = {
        r["command_id"]: r["saved"]
        for r in swarm.cores["m01"].request_outcomes({}, swarm.net.now)["ran"]
    }
    assert ran == {cid: True, hold: True}
    row = _row(flight, cid)
    assert (row["state"], row["reason"], row["save_failed"]) == ("rejected", "gps_no_fix", False)
    assert _row(flight, hold)["save_failed"] is False
    assert swarm.cores["m01"].executor_counters["told_saved"] == 1
