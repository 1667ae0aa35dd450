"""The clear of a failed save, lost to a restart (session 16; docs/dataplane.md, "A failed
save").

A member whose state-file write failed tells its commander (the outcome flagged
``OUTCOME_NOT_SAVED``); the next write that succeeds holds the decision, and the member
tells that too (``OUTCOME_NOW_SAVED``, session 15). That clear goes after the write, on the
outcome writer, which lives in memory: a member that restarts before the clear reaches
the commander (it went out into a cut, or the daemon died between the write and the send)
never sent it, and the commander's ``[not saved on drone]`` stayed for good, a false alarm:
the decision's answer was on the drone's disk all along.

Now the state file keeps which decisions were told unsaved (``told_unsaved``), and a later
life whose file holds such a decision's final answer re-reports it flagged
``OUTCOME_NOW_SAVED`` (``Member.rereport``). Virtual time on the swarm cores
(``tests.test_cmd_in_flight.Flight``), the member's disk played as ``SwarmApp._persist``
answers (``tests.test_cmd_save_failed._saves``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from swarmd.dataplane.types import CommandKind, CommandResult
from swarmd.statefile import NodeState, boot, load
from swarmd.swarm.commander import MAX_DECIDED_COMMANDS, KeptDecision
from swarmd.swarm.events import PersistExecuted
from tests.test_cmd_in_flight import Flight, _issue, _reboot
from tests.test_cmd_save_failed import _issued_onto_a_full_disk, _row

CLOCK = time.time()  # the wall clock the kept decisions' times are judged against


# Entries of a state file's [commander, id] list (``told_unsaved``, ``disarm_unconfirmed``)
# that no load keeps: another shape, an unhashable field, a bool id, a name that is not a
# string, a pair naming nothing kept; and a kept pair (5) named twice, kept once.
HOSTILE_PAIRS: Final[list[Any]] = [
    "x",
    ["lead"],
    ["lead", 5, 1],
    [["lead"], 5],
    [{"a": 1}, 5],
    ["lead", True],
    [7, 5],
    ["lead", 99],  # names nothing kept
    ["lead", 5],
    ["lead", 5],  # once
]


def saved_and_booted(
    state: NodeState, key: str, pairs: list[tuple[str, int]]
) -> tuple[Path, dict[str, Any]]:
    """``state`` (node m01's) with its list ``key`` set to ``pairs``, saved, and read back by
    the next ``boot``: the same pairs, nothing replaced. The file's path and body."""
    setattr(state, key, pairs)
    state.save()
    again = boot(state.path.parent, "m01", wall_now=CLOCK)
    assert getattr(again, key) == pairs and again.recovered_from is None
    return again.path, json.loads(again.path.read_text())


def load_hostile_pairs(
    path: Path, body: dict[str, Any], key: str, cap: int, extra: Sequence[Any] = ()
) -> NodeState:
    """The state file ``body`` at ``path`` loaded with its list ``key`` holding the kept
    pair ("lead", 6) first, then more entries than are read (``cap``: 6 is past the bound),
    ``HOSTILE_PAIRS`` and ``extra``. Before that, each value of ``key`` that is not a list
    loads as an empty list, the rest of the file standing."""
    for raw in ('"x"', "{}", "7", "null", "[[1e400, 5]]"):
        body[key] = json.loads(raw)
        path.write_text(json.dumps(body))
        assert getattr(load(path, CLOCK), key) == []
    body[key] = [["lead", 6]] + [["lead", 99]] * (10 * cap) + HOSTILE_PAIRS + list(extra)
    path.write_text(json.dumps(body))
    return load(path, CLOCK)


def load_without(path: Path, body: dict[str, Any], key: str) -> NodeState:
    """The state file ``body`` at ``path`` without ``key`` (a file of a build before it)
    loaded; saved again, it is written without the key (nothing to keep: as before)."""
    del body[key]
    path.write_text(json.dumps(body))
    old = load(path, CLOCK)
    old.save()
    assert key not in json.loads(path.read_text())
    return old


def _clear_lost(seed: int) -> tuple[Flight, int]:
    """A HOLD onto m01's full disk, done and marked at the commander; then the disk has room
    again and the next command's write holds the decision, but everything m01 sends is lost
    from then on (its clear too); the HOLD's id."""
    flight, disk, cid = _issued_onto_a_full_disk(seed, CommandKind.HOLD)
    swarm = flight.swarm
    swarm.run(5.0)
    assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == ("completed", True)
    flight.cut = lambda a, b: a == "m01"
    disk["full"] = False
    _issue(swarm, CommandKind.HOLD)
    swarm.run(2.0)
    assert swarm.cores["m01"].executor_counters["told_saved"] == 1  # sent, into the cut
    assert _row(flight, cid)["save_failed"] is True
    return flight, cid


def test_a_clear_lost_to_a_restart_is_sent_by_the_next_life() -> None:
    """The clear never reached the commander and m01 restarts on what its disk holds (the
    decision, final, and that its commander was told it unsaved): the new life re-reports
    the outcome flagged saved, and the commander's mark goes. The command ran once.
    [main: the re-report carried no flag; the row stayed ``save_failed`` for good]"""
    flight, cid = _clear_lost(90)
    swarm = flight.swarm
    kept = flight.kept("m01")
    assert ("lead", cid) in kept.told_unsaved
    reborn = _reboot(flight, "m01", state_kept=True)
    flight.cut = lambda a, b: False
    swarm.run(5.0)
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"], row["after_restart"]) == ("completed", False, False)
    assert reborn.executor_counters["told_saved"] == 1
    assert len(flight.ran("m01", cid)) == 1
    # the new life's writes keep it too: its own clear may die with it in turn
    _issue(swarm, CommandKind.HOLD)
    swarm.run(2.0)
    assert ("lead", cid) in flight.kept("m01").told_unsaved


def test_the_new_life_clears_only_what_its_file_holds_the_final_answer_of() -> None:
    """The control: the file names the decision as told unsaved but holds only its
    ACCEPTED (the write of its final answer failed and no later one succeeded): its answer
    across the restart is truly lost, the alarm is right, and the new life's re-report
    leaves the mark."""
    flight, cid = _clear_lost(91)
    kept = flight.kept("m01")

    def accepted(d: KeptDecision) -> KeptDecision:
        if (d.commander, d.command_id) != ("lead", cid):
            return d
        return d._replace(state="accepted", reason="", done_s=None)

    older = PersistExecuted(
        kept.executed,
        tuple(
            (c, i, CommandResult.ACCEPTED.value, "") if (c, i) == ("lead", cid) else (c, i, r, why)
            for c, i, r, why in kept.outcomes
        ),
        tuple(accepted(d) for d in kept.decisions),
        kept.command,
        kept.told_unsaved,
    )
    reborn = _reboot(flight, "m01", state_kept=True, kept=older)
    flight.cut = lambda a, b: False
    flight.swarm.run(5.0)
    assert _row(flight, cid)["save_failed"] is True
    assert reborn.executor_counters.get("told_saved", 0) == 0


def test_the_state_file_keeps_what_was_told_unsaved_and_bounds_it_at_load(
    tmp_path: Path,
) -> None:
    """``told_unsaved`` goes to the file and back through ``boot``; at load only entries
    naming a kept decision, once each, at most ``MAX_DECIDED_COMMANDS`` read; anything
    else (another shape, a bool id, an unhashable field, a decision not kept) is left out
    alone, and the rest of the file stands. A file without the key (session 15) loads with
    none, and one that has none is written without it."""
    first = boot(tmp_path, "m01", wall_now=CLOCK)
    first.executed = [("lead", 5), ("lead", 6)]
    first.decisions = [
        KeptDecision(1, "lead", i, "hold", "completed", "", CLOCK - 10.0, 1.0) for i in (5, 6)
    ]
    path, body = saved_and_booted(first, "told_unsaved", [("lead", 6)])
    third = load_hostile_pairs(path, body, "told_unsaved", MAX_DECIDED_COMMANDS)
    assert third.told_unsaved == [("lead", 5)]
    assert (third.executed, len(third.decisions), third.recovered_from) == (
        [("lead", 5), ("lead", 6)],
        2,
        None,
    )
    old = load_without(path, body, "told_unsaved")
    assert (old.told_unsaved, len(old.decisions)) == ([], 2)
