"""operations.md's "What swarmctl tells you about a command" lists every code the CLI prints.

An operator reads a command's RESULT and REASON in ``swarmctl takeoff``/``land``/``hold``/
``abort`` (follow lines, final table, ``--json``) and in ``swarmctl outcomes``, and looks it
up in that one table. The codes were added over many sessions in three places (the
commander's tracker, the member, the PX4 vehicle core), each helper documenting its own. So
the list here is read from the code, never typed in: the states a real ``CommandTracker``
shows, every reason constant and enum the member and the vehicle report, the marks
``render_outcomes``/``render_kept`` add, the way ``reason_text`` writes a supersede. A code
added to the code and not to the table fails here, naming it; so does a number the table
states (a timeout, a cap) that the code no longer has.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Final

import pytest

from swarmd.cli.commands_view import reason_text
from swarmd.cli.outcomes_cmd import render_kept
from swarmd.cli.takeoff_cmd import render_outcomes
from swarmd.dataplane.types import CommandResult
from swarmd.dataplane.validity import EXPIRED, MEMORY_LOST
from swarmd.px4.actions import CONFIRM_TIMEOUT_S, NOT_CONFIRMED, ActionKind, action_command
from swarmd.px4.command_sender import CommandFinished, Finish, SenderConfig
from swarmd.px4.constants import MavResult
from swarmd.px4.messages import VehicleCommand
from swarmd.px4.readiness import DEFAULT_HEARTBEAT_TIMEOUT_S, Reason
from swarmd.px4.takeoff import AIRBORNE, MAX_TAKEOFF_ALT_M, FailReason, TakeoffConfig
from swarmd.px4.vehicle import ON_GROUND_DISARMED, TaskKind
from swarmd.swarm import commander, member

ROOT: Final = Path(__file__).resolve().parent.parent
HEADING: Final = "### What swarmctl tells you about a command"


def _section() -> str:
    """The section, as one line of text (a cell may wrap anywhere in the source)."""
    text = (ROOT / "docs/operations.md").read_text(encoding="utf-8")
    start = text.index(HEADING)
    end = text.index("\n#", start + len(HEADING))
    return " ".join(text[start:end].split())


def _rows() -> list[str]:
    """The table's rows, header and rule left out."""
    text = (ROOT / "docs/operations.md").read_text(encoding="utf-8")
    start = text.index(HEADING)
    end = text.index("\n#", start + len(HEADING))
    rows = [line for line in text[start:end].splitlines() if line.startswith("|")]
    assert rows[0].startswith("| RESULT, REASON |"), rows[0]
    assert set(rows[1]) <= set("|-"), rows[1]
    return rows[2:]


def _first_cells() -> str:
    return "\n".join(row.split(" | ")[0] for row in _rows())


def _states() -> set[str]:
    """Every RESULT a real ``CommandTracker`` gives a row, driven through its life:
    refused at send, pending, accepted, each final result, unreachable after the validity."""
    tracker = commander.CommandTracker()
    results = list(CommandResult)
    names = [f"n{i}" for i in range(len(results) + 1)]
    tracker.sent(1, "takeoff", names, 0.0, refused={"r": "no_3d_fix"}, valid_for_s=1.0)
    seen = {n["state"] for n in _nodes(tracker, 1, 0.0)}
    for name, result in zip(names, results, strict=False):
        tracker.record(1, name, CommandResult.ACCEPTED, "", 0.1)
        tracker.record(1, name, result, "", 0.2)
    seen |= {n["state"] for n in _nodes(tracker, 1, 0.3)}
    late = 1.0 + commander.UNREACHABLE_GRACE_S + 1.0
    seen |= {n["state"] for n in _nodes(tracker, 1, late)}
    return seen


def _nodes(tracker: commander.CommandTracker, cid: int, now: float) -> list[dict[str, Any]]:
    snap = tracker.snapshot(cid, now)
    assert snap is not None
    return list(snap["nodes"].values())


def _reasons() -> set[str]:
    """Every reason code a drone or the commander puts in a row, as the tables print it."""
    mav_results = {r.name for r in MavResult if r is not MavResult.ACCEPTED}
    sender_causes = {
        CommandFinished(0, VehicleCommand.make(0), finish, None, 1, "").cause
        for finish in (Finish.NO_ACK, Finish.CANCELLED)
    }
    aborts = {action_command(kind).label for kind in (ActionKind.LAND, ActionKind.DISARM)}
    # a take-off never supersedes (it is refused busy); the tables print one way, --json
    # keeps the code
    codes = {f"{FailReason.SUPERSEDED}: {k}" for k in TaskKind if k is not TaskKind.TAKEOFF}
    supersedes = codes | {reason_text(code) for code in codes}
    return (
        {r.value for r in Reason}
        | {r.value for r in FailReason if r is not FailReason.SUPERSEDED}
        | {landed.name for landed in AIRBORNE}
        | aborts
        | {ON_GROUND_DISARMED, NOT_CONFIRMED}
        | sender_causes
        | mav_results
        | supersedes
        | {EXPIRED, MEMORY_LOST, member.PX4_DISABLED, member.UNKNOWN_KIND, member.ID_IN_USE}
        | {commander.NOT_REACHED, commander.RESTARTED, commander.RESTARTED_RUNNING}
        | {commander.NO_REPORT, commander.PEER_LOST, commander.REPORT_STALE}
        | {commander.NOT_A_MEMBER}
    )


def _marks() -> set[str]:
    """The ``[...]`` marks the tables add after a reason, from the renderers themselves."""
    node = {
        "state": "completed",
        "reason": None,
        "after_restart": True,
        "save_failed": True,
        "disarm_unconfirmed": True,
    }
    lines = render_outcomes({"nodes": {"uav1": node}})
    ran = {
        "command_id": 1,
        "kind": "takeoff",
        "state": "failed",
        "reason": "",
        "saved": False,
        "disarm_unconfirmed": True,
    }
    lines += render_kept({"issued": [], "ran": [ran], "life": 1}, 0.0)
    return set(re.findall(r"\[[a-z ]+\]", "\n".join(lines)))


def test_every_state_is_a_row() -> None:
    states = _states()
    assert {"pending", "refused", "accepted", commander.UNREACHABLE} <= states
    cells = _first_cells()
    assert [s for s in sorted(states) if f"`{s}`" not in cells] == []


def test_every_reason_is_in_the_table() -> None:
    reasons = _reasons()
    assert "superseded by LAND" in reasons  # as the tables print it, not the wire code
    cells = _first_cells()
    assert [r for r in sorted(reasons) if not re.search(rf"`{re.escape(r)}\b", cells)] == []


def test_every_mark_is_in_the_table() -> None:
    marks = _marks()
    assert marks == {
        "[after restart]",
        "[not saved on drone]",
        "[not saved]",
        "[disarm not confirmed]",
    }
    cells = _first_cells()
    assert [m for m in sorted(marks) if f"`{m}`" not in cells] == []


def test_every_row_says_what_happened_whether_it_runs_and_what_to_do() -> None:
    header = (ROOT / "docs/operations.md").read_text(encoding="utf-8")
    assert (
        "| RESULT, REASON | What happened on the drone | Can it still run? | What to do |" in header
    )
    short = [row for row in _rows() if len(row.strip("|").split(" | ")) != 4]
    assert short == []


@pytest.mark.parametrize(
    ("value", "sentence"),
    [
        (CONFIRM_TIMEOUT_S, "showed the effect within {:g} s"),
        (DEFAULT_HEARTBEAT_TIMEOUT_S, "at most {:g} s old"),
        (DEFAULT_HEARTBEAT_TIMEOUT_S, "its state was older than {:g} s"),
        (SenderConfig().ack_timeout_s, "received {:g} s or more after the first send"),
        (SenderConfig().retries, "no answer from PX4 to 1 + {} sends"),
        (TakeoffConfig().liftoff_timeout_s, "not seen off the ground within {:g} s"),
        (MAX_TAKEOFF_ALT_M, "outside (0, {:g}] m"),
        (commander.UNREACHABLE_GRACE_S, "(and {:g} s after, for an answer on its way)"),
        (commander.DISARM_WINDOW_S, "so a failed take-off's row settles {:g} s after it"),
    ],
)
def test_the_numbers_in_the_table_are_the_codes(value: float, sentence: str) -> None:
    assert sentence.format(value) in _section()
