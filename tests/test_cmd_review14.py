"""Session 14's command path, red-teamed (docs/security-history.md, "Session 14's command
path reviewed").

What changed that day: the vehicle's tasks carry the member's own token (its boot epoch in
the high 32 bits, a counter in the low), and ``CommandOutcome`` gained a ``flags`` octet
(bit 0 ``OUTCOME_NOT_SAVED``) that the commander's dedup and row read. Each test below is
one candidate attack or accident that no earlier test pinned; virtual time on the swarm
cores (``tests.test_swarm_core.Swarm``, ``tests.test_cmd_in_flight.Flight``).
"""

from __future__ import annotations

import functools
import itertools
from typing import Any

import pytest

from swarmd.dataplane.types import OUTCOME_NOT_SAVED, Command, CommandKind, CommandResult
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleRequest
from swarmd.swarm.commander import CommandTracker
from swarmd.swarm.events import OutcomeRecorded, PersistExecuted
from tests.test_cmd_in_flight import Flight, _issue, _reboot
from tests.test_cmd_two_commanders import _issue as _issue_to_m01
from tests.test_cmd_two_commanders import _two_commanders
from tests.test_px4_vehicle import Bench
from tests.test_swarm_core import Swarm


def _row(flight: Flight, cid: int, node: str = "m01") -> dict[str, Any]:
    swarm = flight.swarm
    row: dict[str, Any] = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"][
        node
    ]
    return row


def test_an_earlier_lifes_task_is_never_credited_to_the_new_lifes_command() -> None:
    """m01 takes a TAKEOFF and its daemon restarts while the task runs; the new life takes
    a LAND. Then a finish carrying the earlier life's token arrives (a vehicle core that
    outlived the swarm core: the tests' played vehicle does; the daemon's dies with its
    process). The new life's first token differs from the earlier life's first only by
    the epoch bits, so without them the LAND would be answered ``failed`` with the
    take-off's reason. It is ignored; the LAND keeps waiting for its own task."""
    flight = Flight(1, seed=70)
    swarm = flight.swarm
    swarm.run(3.0)
    takeoff = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.2)
    (old,) = swarm.requests("m01")
    assert old.origin == ("lead", takeoff)
    _reboot(flight, "m01", state_kept=True)
    swarm.run(1.5)  # the new life reports readiness, so the LAND can be dated into it
    land = int(_issue(swarm, CommandKind.LAND)["command_id"])
    swarm.run(0.3)
    new = swarm.requests("m01")[-1]
    assert (new.origin, new.kind) == (("lead", land), TaskKind.LAND)
    assert new.token != old.token
    assert new.token & 0xFFFF_FFFF == old.token & 0xFFFF_FFFF  # each life's first task
    assert _row(flight, land)["state"] == "accepted"
    stale = TaskFinished(old.token, False, "old_life_takeoff", None)
    m01 = swarm.cores["m01"]
    swarm.call("m01", lambda now: m01.task_finished(stale, now))
    swarm.run(0.2)
    assert _row(flight, land)["state"] == "accepted"  # not credited with the old task
    swarm.run(3.0)
    assert (_row(flight, land)["state"], _row(flight, land)["reason"]) == ("completed", "")


@pytest.mark.parametrize("own_drone", [False, True])
def test_an_abort_with_the_running_takeoffs_own_id_is_a_duplicate(own_drone: bool) -> None:
    """The same commander's ABORT under the id of its TAKEOFF still running (no honest
    commander makes one; a bug or a hand-made send could): exactly once is per
    (commander, id), whatever the kind, so it is a duplicate and no second task starts.
    Since the tasks carry the member's token, nothing else would have stopped it. A member
    through the data plane (its executed pairs), and the commander's own drone, whose
    commands bypass the plane (the member's started pairs)."""
    swarm = Swarm(1, seed=71, lead_vehicle=own_drone)
    node = "lead" if own_drone else "m01"
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.3)  # running (the played vehicle takes 1 s)
    assert [r.kind for r in swarm.requests(node)] == [TaskKind.TAKEOFF]
    plane = swarm.lead.plane
    assert plane is not None
    abort = Command(cid, CommandKind.ABORT, 0.0, [node], 3000, plane.time_echoes([node], 0.0))
    member = swarm.lead.member
    send = member.run_own if own_drone else plane.send_command
    swarm.call("lead", lambda now: send(abort, now))
    swarm.run(3.0)
    assert [r.kind for r in swarm.requests(node)] == [TaskKind.TAKEOFF]
    row = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"][node]
    assert (row["state"], row["reason"]) == ("completed", "IN_AIR")
    if not own_drone:
        m01 = swarm.cores["m01"].plane
        assert m01 is not None and m01.counters["command_duplicate"] >= 1


def test_a_reserved_flag_bit_is_ignored_by_the_dedup_too() -> None:
    """A member of a later build sets a flag this build does not know (bit 3) on an answer
    it already gave. The wire says reserved bits are ignored on receipt
    (docs/wire.md, "The outcome's flags"); the commander's dedup keyed the whole octet, so
    the same answer was taken again: a second ``OutcomeRecorded`` (log line) for one
    result. Now only the bits this build reads make an outcome new; bit 0 with a reserved
    bit beside it still marks the row."""
    flight = Flight(1, seed=72)
    swarm = flight.swarm
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(3.0)
    assert _row(flight, cid)["state"] == "completed"

    def recorded() -> list[tuple[CommandResult, bool]]:
        events = swarm.events["lead"]
        return [(e.result, e.saved) for e in events if isinstance(e, OutcomeRecorded)]

    before = recorded()
    plane = swarm.cores["m01"].plane
    assert plane is not None
    done = CommandResult.COMPLETED

    def answer_again(flags: int) -> None:  # the member's answer, the same, with ``flags``
        swarm.call(
            "m01",
            lambda now: plane.report_outcome(cid, done, now, commander="lead", flags=flags),
        )
        swarm.run(0.5)

    # reserved bits only: the answer it gave (bit 1 is OUTCOME_NOW_SAVED since session 15,
    # bit 2 OUTCOME_DISARM_UNCONFIRMED since session 18)
    for flags in (0x08, 0x80, 0xF8):
        answer_again(flags)
    assert recorded() == before
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", False)
    lead = swarm.lead.plane
    assert lead is not None and lead.counters["outcome_duplicate"] >= 3
    for flags in (OUTCOME_NOT_SAVED | 0x08, OUTCOME_NOT_SAVED | 0x10):
        answer_again(flags)
    assert recorded() == [*before, (done, False)]  # bit 0 is new once, the rest ignored
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", True)


RESULTS = [CommandResult.ACCEPTED, CommandResult.COMPLETED]


def test_no_order_of_flagged_and_unflagged_answers_moves_a_row_back() -> None:
    """Every order of a member's four possible answers to one command (ACCEPTED and
    COMPLETED, each unflagged and flagged), each delivered twice, from the life it was
    sent to: the row never leaves ``completed`` once there, never loses ``save_failed``
    once set, and ends the same whatever the order (24 orders)."""
    answers = [(r, f) for r in RESULTS for f in (False, True)]
    ends = set()
    for order in itertools.permutations(answers):
        tracker = CommandTracker()
        tracker.sent(1, "takeoff", ["m01"], 0.0, valid_for_s=3.0, epochs={"m01": 1})
        completed = marked = False
        for step, (result, not_saved) in enumerate([*order, *order]):
            now = 0.1 * (step + 1)
            assert tracker.record(1, "m01", result, "IN_AIR", now, epoch=1, not_saved=not_saved)
            row = tracker.snapshot(1, now)["nodes"]["m01"]  # type: ignore[index]
            completed = completed or result == CommandResult.COMPLETED
            marked = marked or not_saved
            assert row["state"] == ("completed" if completed else "accepted"), order
            assert row["save_failed"] is marked, order
        row = tracker.snapshot(1, 10.0)["nodes"]["m01"]  # type: ignore[index]
        ends.add((row["state"], row["reason"], row["save_failed"], row["after_restart"]))
    assert ends == {("completed", "IN_AIR", True, False)}


def _ended(bench: Bench, token: int) -> bool:
    return bench.finished(token) is not None


def test_the_vehicle_never_reads_a_requests_origin() -> None:
    """``VehicleRequest.origin`` (the commander and command id a token stands for) is for
    logs and tests: two vehicles given the same tasks with other origins, or none, send the
    simulated PX4 the same commands and end each task the same way."""

    def fly(origins: list[tuple[str, int] | None]) -> tuple[list[Any], list[Any]]:
        bench = Bench()
        bench.run(3.0)  # GPS fix, home, readiness
        tasks = [(TaskKind.TAKEOFF, 4.0), (TaskKind.HOLD, None), (TaskKind.ABORT, None)]
        for token, ((kind, alt), origin) in enumerate(zip(tasks, origins, strict=True), 1):
            bench.core.request(VehicleRequest(token, kind, alt, origin), bench.now)
            bench._pump_core()
            bench.run(30.0, stop=functools.partial(_ended, bench, token))
        return bench.sent, bench.events

    plain = fly([None, None, None])
    assert [e.ok for e in plain[1] if isinstance(e, TaskFinished)] == [True, True, True]
    assert fly([("lead", 1), ("lead2", 1), ("lead", 2**64 - 1)]) == plain


def test_a_failed_save_is_told_to_the_commander_whose_command_it_was_only(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Two commanders of one epoch: the same id is lead's HOLD and lead2's LAND on m01,
    and only the writes of lead2's decision fail. The flagged outcome goes again to lead2
    alone: sent to every reader, lead would take it as an answer to its own id (a row
    marked for a save that did not fail, and an ACCEPTED of a LAND for its HOLD)."""
    swarm = _two_commanders(monkeypatch)
    on_event = swarm.net.on_event
    assert on_event is not None

    def disk(node_id: int, event: Any, now: float) -> None:  # lead2's records do not fit
        on_event(node_id, event, now)
        if isinstance(event, PersistExecuted) and node_id == swarm.ids["m01"]:
            error = None if event.command is None or event.command[0] != "lead2" else "full"
            swarm.cores["m01"].state_saved(event.command, error, now)

    swarm.net.on_event = disk
    hold = _issue_to_m01(swarm, "lead", "hold")
    land = _issue_to_m01(swarm, "lead2", "land")
    assert hold == land
    swarm.run(5.0)
    rows = {
        name: swarm.cores[name].request_outcomes({"command_id": hold}, swarm.net.now)["nodes"][
            "m01"
        ]
        for name in ("lead", "lead2")
    }
    assert (rows["lead"]["state"], rows["lead"]["save_failed"]) == ("completed", False)
    assert (rows["lead2"]["state"], rows["lead2"]["save_failed"]) == ("completed", True)
    # told at each failure after a write of lead's held everything (docs/dataplane.md)
    assert swarm.cores["m01"].executor_counters["told_not_saved"] >= 1
    heard = [e for e in swarm.events["lead"] if isinstance(e, OutcomeRecorded)]
    assert all(e.saved for e in heard) and len(heard) == 2  # its HOLD's ACCEPTED, COMPLETED
