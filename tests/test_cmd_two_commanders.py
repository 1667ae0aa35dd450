"""Two commanders whose command ids coincide (docs/dataplane.md, "Exactly once" 4;
docs/security.md, "The air: the data plane and commands").

A command id is ``epoch << 32 | counter`` and the epoch is the commander's boot epoch,
wall-clock seconds when its epoch file has nothing higher (``swarmd.auth.epoch``). Two
commanders of one bundle started in the same second (a ground station starting two
commander daemons at boot, clocks from GPS or NTP) have the same epoch, so their first
commands have the same id. The plane keys what a member ran by ``(commander, id)``, but:

- a member's outcome named only the id, and went to every commander: commander B's row
  for its LAND took the member's answer to A's HOLD, and said ``completed`` for a LAND
  that never ran (the operator told a drone landed that did not);
- the member's core dropped B's command, silently, as an id it had already run.

Now an outcome goes only to the commander whose command it answers (one copy, like a
command's: the other commanders are sent a GAP), and the core keys what it runs by
``(commander, id)``. Until session 14 the vehicle's tasks were still tagged with the bare
id, so a command whose id still ran here for another commander was refused (``id_in_use``),
an ABORT too; now each task has the member's own tag and both run.

Virtual time on the swarm cores (``tests.test_swarm_core.Swarm``) over a bundle with a
second commander, ``lead2``; every node starts in epoch 1.
"""

from __future__ import annotations

import functools
from typing import Any

import pytest

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.dataplane import DataPlane
from swarmd.dataplane.types import Command, CommandKind
from swarmd.px4.vehicle import TaskFinished, TaskKind
from tests import test_swarm_core
from tests.test_cmd_in_flight import Flight, _reboot
from tests.test_dataplane_swarm import mission_text
from tests.test_swarm_core import Swarm


def _two_commanders(monkeypatch: pytest.MonkeyPatch) -> Swarm:
    text = mission_text(2).replace(
        "  - {name: m01,",
        "  - {name: lead2, index: 3, role: commander, mavlink_sysid: 9}\n  - {name: m01,",
    )
    bundle = build_dev_bundle(parse_mission(text)).bundle
    monkeypatch.setattr(test_swarm_core, "make_bundle", lambda _members: bundle)
    swarm = Swarm(2, seed=31)
    swarm.run(2.0)
    return swarm


def _issue(swarm: Swarm, commander: str, kind: str) -> int:
    core = swarm.cores[commander]
    sent = swarm.call(
        commander, lambda now: core.request_command({"kind": kind, "only": ["m01"]}, now)
    )
    return int(sent["command_id"])


def _send(plane: DataPlane, command: Command, now: float) -> int:
    return plane.send_command(command, now)


def _row(swarm: Swarm, commander: str, cid: int) -> dict[str, Any]:
    snap = swarm.cores[commander].request_outcomes({"command_id": cid}, swarm.net.now)
    row: dict[str, Any] = snap["nodes"]["m01"]
    return row


def test_a_commander_is_never_told_another_commanders_command_ran(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    swarm = _two_commanders(monkeypatch)
    # each task ends with its kind for a reason, so an answer shows which command it is
    swarm.vehicles["m01"].answer = lambda r: TaskFinished(r.token, True, r.kind.value, None)
    hold = _issue(swarm, "lead", "hold")
    land = _issue(swarm, "lead2", "land")
    assert hold == land  # the same epoch, the same counter: the same id
    swarm.run(10.0)
    # the LAND came while the HOLD ran: both run, each under the member's own tag
    assert [r.origin for r in swarm.requests("m01")] == [("lead", hold), ("lead2", land)]
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.HOLD, TaskKind.LAND]
    assert len({r.token for r in swarm.requests("m01")}) == 2
    # each commander was answered about its own command only
    assert (_row(swarm, "lead", hold)["state"], _row(swarm, "lead", hold)["reason"]) == (
        "completed",
        "hold",
    )
    assert (_row(swarm, "lead2", land)["state"], _row(swarm, "lead2", land)["reason"]) == (
        "completed",
        "land",
    )


def test_the_same_id_from_another_commander_runs_once_the_first_is_done(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    swarm = _two_commanders(monkeypatch)
    hold = _issue(swarm, "lead", "hold")
    swarm.run(3.0)  # the HOLD completed
    land = _issue(swarm, "lead2", "land")
    assert hold == land
    swarm.run(10.0)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.HOLD, TaskKind.LAND]
    assert _row(swarm, "lead", hold)["state"] == "completed"
    assert _row(swarm, "lead2", land)["state"] == "completed"
    # and each id still runs once per commander: the copies resent change nothing
    swarm.run(10.0)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.HOLD, TaskKind.LAND]


def test_an_abort_is_never_refused_because_another_commander_runs_its_id(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The attack (session 14): commander B's ABORT carries the id of commander A's
    TAKEOFF, still running on m01. Before, the vehicle's tasks were tagged with the bare
    id, so the ABORT was refused (REJECTED ``id_in_use``) and the drone kept climbing. Now
    each task has the member's own tag: the ABORT runs at once, beside the take-off, and
    each commander is answered about its own command only."""
    swarm = _two_commanders(monkeypatch)
    lead = swarm.cores["lead"]
    sent = swarm.call(
        "lead", lambda now: lead.request_takeoff({"alt_m": 5.0, "only": ["m01"]}, now)
    )
    takeoff = int(sent["command_id"])
    swarm.run(0.3)  # the take-off runs on m01 (the played vehicle takes 1 s)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]
    abort = _issue(swarm, "lead2", "abort")
    assert abort == takeoff  # the same epoch, the same counter: the same id
    swarm.run(0.3)
    kinds = [r.kind for r in swarm.requests("m01")]
    assert kinds == [TaskKind.TAKEOFF, TaskKind.ABORT]  # refused id_in_use before
    assert _row(swarm, "lead2", abort)["state"] in ("accepted", "completed")
    swarm.run(10.0)
    assert _row(swarm, "lead2", abort)["state"] == "completed"
    assert (_row(swarm, "lead", takeoff)["state"], _row(swarm, "lead", takeoff)["reason"]) == (
        "completed",
        "IN_AIR",  # the take-off's own answer, not the ABORT's
    )
    assert _row(swarm, "lead2", abort)["reason"] == ""  # the ABORT's, not the take-off's
    # each (commander, id) still runs once: the copies resent change nothing
    swarm.run(10.0)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF, TaskKind.ABORT]


@pytest.mark.parametrize("state_kept", [True, False])
def test_both_commanders_ids_run_once_across_a_member_restart(
    monkeypatch: pytest.MonkeyPatch, state_kept: bool
) -> None:
    """Exactly once is still per (commander, id), also across a restart of the member
    (its state file kept, or lost): both commanders' same id ran once each, and each
    commander's code resending it to the new life runs nothing (the executed pairs, or
    the life rules: docs/dataplane.md, "A life runs only its own commands")."""
    _two_commanders(monkeypatch)  # the bundle with lead2, for the flight below
    flight = Flight(2, seed=32)
    swarm = flight.swarm
    swarm.run(2.0)
    hold = _issue(swarm, "lead", "hold")
    land = _issue(swarm, "lead2", "land")
    assert hold == land
    swarm.run(3.0)
    ran = [("lead", hold), ("lead2", land)]
    assert sorted(r.origin or ("", 0) for r in swarm.requests("m01")) == ran
    _reboot(flight, "m01", state_kept=state_kept)
    swarm.run(1.0)
    for commander, kind in (("lead", CommandKind.HOLD), ("lead2", CommandKind.LAND)):
        plane = swarm.cores[commander].plane
        assert plane is not None
        echoes = plane.time_echoes(["m01"], swarm.net.now)
        again = Command(hold, kind, 0.0, ["m01"], 3000, echoes)
        swarm.call(commander, functools.partial(_send, plane, again))
    swarm.run(10.0)
    assert sorted(r.origin or ("", 0) for r in swarm.requests("m01")) == ran
    refused = swarm.cores["m01"].executor_counters
    plane = swarm.cores["m01"].plane
    assert plane is not None
    if state_kept:  # the executed pairs came back with the file: both copies duplicates
        assert plane.counters["command_duplicate"] >= 2
    else:  # the new life cannot date them into itself
        assert refused.get("refused_memory_lost") == 2
