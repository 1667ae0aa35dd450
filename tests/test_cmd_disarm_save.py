"""An unconfirmed DISARM survives the drone's restart: the re-report carries it (session 18;
docs/dataplane.md, "Outcomes across a restart"; docs/operations.md, the mark).

A failed take-off whose DISARM was never confirmed is amended: the member sends the same
FAILED again flagged ``OUTCOME_DISARM_UNCONFIRMED`` and the commander marks the row
``[disarm not confirmed]``. Until this change the amendment lived in memory only: the state
file kept the FAILED, not the flag, so a drone whose daemon restarted (a crash, the
watchdog, a reboot in the air) re-reported a plain FAILED, and a commander that had not
heard the amendment (it went into a cut, or the commander restarted and asks again) never
learned that the vehicle may still be armed. The drone is the one place that knows.

Now the member keeps the mark with the outcome (``Member._disarm_marks``), writes it like
the outcome (``PersistExecuted.disarm_unconfirmed``, the state file's
``disarm_unconfirmed``), and a later life's re-report of that FAILED carries the flag.

The swarm core on MemNet, virtual time (``tests.test_cmd_in_flight.Flight``): m01's played
vehicle fails the take-off (``takeoff_no_ack``) and, 2 s later, hands the amendment
(``DisarmUnconfirmed``) as the bridge does; the restarted life is built from what a real
state file (``statefile.boot``) gives back of m01's last ``PersistExecuted``, as
``SwarmApp._persist`` writes it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest

from swarmd.dataplane.types import OUTCOME_DISARM_UNCONFIRMED, CommandKind, CommandResult
from swarmd.px4.takeoff import FailReason, TakeoffFailed
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished, TaskKind, VehicleRequest
from swarmd.statefile import boot, state_path
from swarmd.swarm.commander import MAX_DISARM_MARKS, KeptDecision
from swarmd.swarm.events import OutcomeRecorded, OutcomeReported, PersistExecuted
from tests.test_cmd_in_flight import Flight, _issue
from tests.test_cmd_restart import _found, _row, _takeoff
from tests.test_cmd_save_clear_restart import (
    load_hostile_pairs,
    load_without,
    saved_and_booted,
)
from tests.test_cmd_save_failed import _saves
from tests.test_dataplane_swarm import address_of
from tests.test_swarm_core import VEHICLE_TASK_S

CLOCK = time.time()  # the wall clock the kept decisions' times are judged against
NO_ACK = FailReason.TAKEOFF_NO_ACK.value
DISARM_REPEATS_S = 2.0  # the failed take-off's DISARM repeats (docs/px4.md)


def _fails(request: VehicleRequest) -> TaskFinished:
    """m01's vehicle: a take-off fails ``takeoff_no_ack`` (armed, NAV_TAKEOFF unanswered);
    anything else completes."""
    if request.kind is TaskKind.TAKEOFF:
        failed = TakeoffFailed(FailReason.TAKEOFF_NO_ACK, None, "no ack", 2.0)
        return TaskFinished(request.token, False, NO_ACK, failed)
    return TaskFinished(request.token, True, "", None)


def _amendment_lost(seed: int) -> tuple[Flight, int]:
    """A take-off to m01 fails, its answer reaches the commander; then everything m01 sends
    is lost, and the vehicle's DISARM repeats end unconfirmed: m01 sends the amendment into
    the cut. The take-off's id."""
    flight = Flight(2, seed)
    swarm = flight.swarm
    swarm.vehicles["m01"].answer = _fails
    swarm.run(3.0)
    cid, _ = _takeoff(flight)
    swarm.run(VEHICLE_TASK_S + 0.5)
    assert (_row(flight, cid)["state"], _row(flight, cid)["reason"]) == ("failed", NO_ACK)
    flight.cut = lambda a, b: a == "m01"
    (request,) = swarm.requests("m01")
    m01 = swarm.cores["m01"]
    amendment = DisarmUnconfirmed(request.token, NO_ACK, "DISARM no ack after 4 sends")
    swarm.net.call_at(
        swarm.net.now + DISARM_REPEATS_S, lambda now: m01.task_finished(amendment, now)
    )
    swarm.run(DISARM_REPEATS_S + 1.0)
    assert m01.executor_counters["takeoff_disarm_unconfirmed"] == 1  # sent, into the cut
    assert _row(flight, cid)["disarm_unconfirmed"] is False
    return flight, cid


def _through_the_file(kept: PersistExecuted, folder: Path) -> PersistExecuted:
    """``kept`` written as ``SwarmApp._persist`` writes it, and what ``statefile.boot``
    gives the next life back (one clock here: decision times need no conversion)."""
    state = boot(folder, "m01", wall_now=CLOCK)
    state.executed = list(kept.executed)
    state.outcomes = list(kept.outcomes)
    state.decisions = [d._replace(received_at=CLOCK) for d in kept.decisions]
    state.told_unsaved = list(kept.told_unsaved)
    state.disarm_unconfirmed = list(kept.disarm_unconfirmed)
    state.save()
    loaded = boot(folder, "m01", wall_now=CLOCK)
    assert loaded.recovered_from is None
    return PersistExecuted(
        tuple(loaded.executed),
        tuple(loaded.outcomes),
        tuple(loaded.decisions),
        None,
        tuple(loaded.told_unsaved),
        tuple(loaded.disarm_unconfirmed),
    )


def _restarted(flight: Flight, folder: Path, epoch: int) -> None:
    """m01's daemon restarts in boot ``epoch`` from its state file; the commander finds
    the new life (its SPDP) with the cut healed."""
    kept = _through_the_file(flight.kept("m01"), folder)
    flight.restart("m01", epoch=epoch, kept=kept)
    flight.cut = lambda a, b: False
    _found(flight, "m01", epoch)
    flight.swarm.run(5.0)


def test_a_restarted_member_re_reports_its_unconfirmed_disarm(tmp_path: Path) -> None:
    """The amendment went into a cut and m01's daemon restarted: its new life re-reports
    the FAILED flagged, and the commander's row is marked; nothing runs again. A second
    restart still carries it (each life writes the mark it loaded). [main: the state file
    kept no mark, the re-report was a plain FAILED, the row said ``failed`` alone]"""
    flight, cid = _amendment_lost(180)
    swarm = flight.swarm
    assert ("lead", cid) in flight.kept("m01").disarm_unconfirmed
    _restarted(flight, tmp_path, epoch=2)
    row = _row(flight, cid)
    assert (row["state"], row["reason"], row["disarm_unconfirmed"]) == ("failed", NO_ACK, True)
    assert swarm.cores["m01"].counters["outcomes_rereported"] == 1
    heard = [
        e.disarm_unconfirmed
        for e in swarm.events["lead"]
        if isinstance(e, OutcomeRecorded) and e.command_id == cid and e.result.name == "FAILED"
    ]
    assert heard == [False, True]  # the failure live, the re-report flagged
    assert len(flight.ran("m01", cid)) == 1
    # the new life writes the mark it loaded: a third life still knows it
    _issue(swarm, CommandKind.HOLD)
    swarm.run(2.0)
    assert ("lead", cid) in flight.kept("m01").disarm_unconfirmed
    _restarted(flight, tmp_path, epoch=3)
    assert swarm.cores["m01"].counters["outcomes_rereported"] >= 1
    assert _row(flight, cid)["disarm_unconfirmed"] is True


def test_a_confirmed_disarm_is_re_reported_plain(tmp_path: Path) -> None:
    """The control: the same failure with its DISARM confirmed (no amendment): the file
    holds no mark and the re-report is the FAILED alone."""
    flight = Flight(2, 181)
    swarm = flight.swarm
    swarm.vehicles["m01"].answer = _fails
    swarm.run(3.0)
    cid, _ = _takeoff(flight)
    swarm.run(VEHICLE_TASK_S + 0.5)
    flight.cut = lambda a, b: a == "m01"
    swarm.run(DISARM_REPEATS_S + 1.0)
    assert flight.kept("m01").disarm_unconfirmed == ()
    _restarted(flight, tmp_path, epoch=2)
    assert swarm.cores["m01"].counters["outcomes_rereported"] == 1
    row = _row(flight, cid)
    assert (row["state"], row["disarm_unconfirmed"]) == ("failed", False)
    assert "disarm_unconfirmed" not in json.loads(state_path(tmp_path, "m01").read_text())


def test_the_mark_is_written_like_the_outcome_and_holds_no_request() -> None:
    """The amendment's write: one ``PersistExecuted`` after the flagged answer, naming the
    command (a failed write is told like any other), with the mark; no vehicle request is
    made or held for it (nothing moves on it: the write-ahead is for ids, before the vehicle
    moves, and this write follows an end)."""
    flight, cid = _amendment_lost(182)
    events = flight.swarm.events["m01"]
    told = next(
        i
        for i, e in enumerate(events)
        if isinstance(e, OutcomeReported) and e.command_id == cid and e.disarm_unconfirmed
    )
    after = events[told + 1 :]
    persisted = [e for e in after if isinstance(e, PersistExecuted)]
    assert len(persisted) == 1
    assert persisted[0].command == ("lead", cid)
    assert persisted[0].disarm_unconfirmed == (("lead", cid),)
    assert ("lead", cid, CommandResult.FAILED.value, NO_ACK) in persisted[0].outcomes
    assert not [e for e in after if isinstance(e, VehicleRequest)]


def test_the_re_report_flags_only_a_kept_failure_it_marks() -> None:
    """``Member.rereport`` sets the flag on a FAILED the file marks, alone: an outcome of
    another result, or a FAILED not marked, goes without it."""
    flight = Flight(2, 183)
    kept = PersistExecuted(
        (("lead", 5), ("lead", 6), ("lead", 7)),
        (
            ("lead", 5, CommandResult.FAILED.value, NO_ACK),
            ("lead", 6, CommandResult.FAILED.value, NO_ACK),
            ("lead", 7, CommandResult.COMPLETED.value, "IN_AIR"),
        ),
        (),
        None,
        (),
        (("lead", 5), ("lead", 7)),  # 7 is not a failure: a hand-edited file's word
    )
    sent: list[tuple[int, int]] = []
    core = flight.restart("m01", epoch=2, kept=kept, start=False)
    plane = core.plane
    assert plane is not None
    real = plane.report_outcome

    def spy(command_id: int, result: CommandResult, now: float, *a: Any, **kw: Any) -> int:
        sent.append((command_id, int(kw.get("flags", 0))))
        return real(command_id, result, now, *a, **kw)

    plane.report_outcome = spy  # type: ignore[method-assign]
    core.start(flight.swarm.net.now)
    _found(flight, "m01", 2)
    assert sorted(sent) == [(5, OUTCOME_DISARM_UNCONFIRMED), (6, 0), (7, 0)]


def test_the_state_file_keeps_the_marks_and_bounds_them_at_load(tmp_path: Path) -> None:
    """``disarm_unconfirmed`` goes to the file and back through ``boot``; at load only
    entries naming a kept FAILED outcome, once each, the last ``MAX_DISARM_MARKS`` read;
    anything else (another shape, a bool id, an unhashable field, an id not kept, one kept
    but not FAILED) is left out alone and the rest of the file stands. A file without the
    key (before session 18) loads with none, and one with none is written without it, as
    before; a file with it loads in a build that does not know it (every key is read by
    name: ``load`` never refused an unknown one)."""
    first = boot(tmp_path, "m01", wall_now=CLOCK)
    first.executed = [("lead", 5), ("lead", 6), ("lead", 7)]
    first.outcomes = [
        ("lead", 5, CommandResult.FAILED.value, NO_ACK),
        ("lead", 6, CommandResult.FAILED.value, NO_ACK),
        ("lead", 7, CommandResult.COMPLETED.value, "IN_AIR"),
    ]
    first.decisions = [KeptDecision(1, "lead", 6, "takeoff", "failed", NO_ACK, CLOCK - 10.0, 2.0)]
    path, body = saved_and_booted(first, "disarm_unconfirmed", [("lead", 6)])
    # one kept but COMPLETED: nothing to amend
    third = load_hostile_pairs(path, body, "disarm_unconfirmed", MAX_DISARM_MARKS, [["lead", 7]])
    assert third.disarm_unconfirmed == [("lead", 5)]
    assert (third.executed, len(third.outcomes), len(third.decisions), third.recovered_from) == (
        [("lead", 5), ("lead", 6), ("lead", 7)],
        3,
        1,
        None,
    )
    old = load_without(path, body, "disarm_unconfirmed")
    assert (old.disarm_unconfirmed, len(old.outcomes)) == ([], 3)


def test_a_restarted_commander_hears_the_mark_in_its_journal(tmp_path: Path) -> None:
    """Both daemons restart (the commander's rows live in memory): the new commander knows
    no such command, and its journal line for the re-report (``OutcomeRecorded``, logged
    ``command_outcome_received``, ``known: false``) says the vehicle may still be armed.
    [main: ``disarm_unconfirmed`` false there]"""
    flight, cid = _amendment_lost(184)
    swarm = flight.swarm
    lead = flight.restart("lead", epoch=2, kept=PersistExecuted(()))
    m01 = flight.restart("m01", epoch=2, kept=_through_the_file(flight.kept("m01"), tmp_path))
    flight.cut = lambda a, b: False
    now = swarm.net.now
    lead.peer_up("m01", address_of(swarm.bundle, "m01"), 2, now)
    m01.peer_up("lead", address_of(swarm.bundle, "lead"), 2, now)
    for name in ("lead", "m01"):
        swarm.net.poke(swarm.ids[name])
    swarm.run(5.0)
    assert m01.counters["outcomes_rereported"] == 1
    unknown = [
        e.disarm_unconfirmed
        for e in swarm.events["lead"]
        if isinstance(e, OutcomeRecorded) and e.command_id == cid and not e.known
    ]
    assert unknown == [True]


def _marked_and_told(seed: int, word: str) -> tuple[Flight, int]:
    """A take-off to m01 fails and its DISARM is never confirmed (the amendment is sent and
    heard); around it m01's disk says no: ``not-saved``, the amendment's own write fails (a
    new failure is told, flagged ``OUTCOME_NOT_SAVED``); ``saved-after-all``, every write
    fails from the take-off on and a later command's write holds the record (told once
    more, flagged ``OUTCOME_NOW_SAVED``). The take-off's id."""
    flight = Flight(2, seed)
    swarm = flight.swarm
    swarm.vehicles["m01"].answer = _fails
    disk = {"full": False}
    _saves(flight, "m01", lambda: disk["full"])
    swarm.run(3.0)
    disk["full"] = word == "saved-after-all"
    cid, _ = _takeoff(flight)
    swarm.run(VEHICLE_TASK_S + 0.5)
    (request,) = swarm.requests("m01")
    m01 = swarm.cores["m01"]
    amendment = DisarmUnconfirmed(request.token, NO_ACK, "DISARM no ack after 4 sends")
    disk["full"] = True
    swarm.net.call_at(
        swarm.net.now + DISARM_REPEATS_S, lambda now: m01.task_finished(amendment, now)
    )
    swarm.run(DISARM_REPEATS_S + 1.0)
    assert m01.executor_counters["takeoff_disarm_unconfirmed"] == 1
    if word == "saved-after-all":
        disk["full"] = False
        _issue(swarm, CommandKind.HOLD)  # its write holds the whole record
        swarm.run(2.0)
        assert m01.executor_counters["told_saved"] >= 1
    else:
        assert m01.executor_counters["told_not_saved"] == 1
    return flight, cid


@pytest.mark.parametrize("word", ["not-saved", "saved-after-all"])
def test_every_outcome_sent_for_a_marked_failure_carries_the_mark(word: str) -> None:
    """After the amendment, each outcome m01 sends for that FAILED (the "not saved" and
    "saved after all" words too, ``Member._tell``) says the DISARM was never confirmed:
    the commander's journal line for each (``OutcomeRecorded``, logged
    ``command_outcome_received``) and m01's own (``OutcomeReported``, ``command_outcome``)
    carry ``disarm_unconfirmed``, so an operator grepping the latest line of that command
    is not told the opposite. The row keeps its mark either way. [fails on main: the word
    after the amendment went unflagged, its lines ``disarm_unconfirmed`` false]"""
    flight, cid = _marked_and_told(185, word)
    swarm = flight.swarm
    failed = CommandResult.FAILED

    def lines(events: list[Any], kind: type[OutcomeRecorded | OutcomeReported]) -> list[bool]:
        return [
            e.disarm_unconfirmed
            for e in events
            if isinstance(e, kind) and e.command_id == cid and e.result == failed
        ]

    heard, told = (
        lines(swarm.events["lead"], OutcomeRecorded),
        lines(swarm.events["m01"], OutcomeReported),
    )
    # the failure, the amendment, the word after it
    assert (heard, told) == ([False, True, True], [False, True, True])
    assert _row(flight, cid)["disarm_unconfirmed"] is True
    assert _row(flight, cid)["save_failed"] is (word == "not-saved")
    assert len(flight.ran("m01", cid)) == 1
