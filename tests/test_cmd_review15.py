"""Session 15's command-authority changes, red-teamed (docs/security-history.md, "Session
15's command authority reviewed").

What changed that day: one task per vehicle (``vehicle.RULES``: a LAND, HOLD or ABORT
supersedes the running task, a TAKEOFF meeting any task is refused ``busy``, REJECTED at the
swarm layer), and the commander's ``save_failed`` mark clears (``OUTCOME_NOW_SAVED``,
ordered by ``(epoch, save_gen)``). Each test below is one candidate attack or accident that
no earlier test pinned; virtual time against the simulated PX4 (``tests.test_px4_vehicle.
Bench``) or on the swarm cores (``tests.test_swarm_core.Swarm``).
"""

from __future__ import annotations

import argparse
import itertools
from typing import Any

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.dataplane import DataPlane
from swarmd.dataplane.types import Command, CommandResult
from swarmd.px4.constants import LandedState, MavCmd, MavState
from swarmd.px4.messages import MODE_LAND, Heartbeat, Observation, VehicleCommand
from swarmd.px4.vehicle import ON_GROUND_DISARMED, TaskKind
from swarmd.swarm.commander import RESTARTED_RUNNING, UNREACHABLE_GRACE_S, CommandTracker
from swarmd.swarm.member import MAX_SAVE_GEN
from tests.test_cmd_in_flight import Flight
from tests.test_cmd_life_ended import _Snaps
from tests.test_cmd_restart import _restart, _takeoff
from tests.test_cmd_supersede import RealVehicle
from tests.test_cmd_two_commanders import _row, _two_commanders
from tests.test_px4_supersede import _after, _arming, _lifting
from tests.test_swarm_core import VEHICLE_TASK_S

L, H, A = TaskKind.LAND, TaskKind.HOLD, TaskKind.ABORT


def _drop_first_disarm() -> Any:
    """Lose the first DISARM on its way down (a lossy PX4 link); everything else passes."""
    disarms = itertools.count()

    def drop(msg: Observation | VehicleCommand, direction: str) -> bool:
        if not (isinstance(msg, VehicleCommand) and direction == "down"):
            return False
        disarm = msg.command == MavCmd.COMPONENT_ARM_DISARM and msg.params[0] == 0.0
        return disarm and next(disarms) == 0

    return drop


@pytest.mark.parametrize("middle", [L, H, A], ids=str)
def test_an_abort_after_a_supersede_chain_from_an_arming_takeoff_disarms(
    middle: TaskKind,
) -> None:
    """A take-off's ARM is on its way (our state not armed yet); a LAND, HOLD or ABORT
    supersedes it, then an ABORT supersedes that. PX4 carries out the ARM after our state
    was sent, so the last ABORT must DISARM, as an ABORT straight after the take-off does.
    With ABORT in the middle its one DISARM is lost on the link (it sent nothing more once
    superseded). [main: the last ABORT saw "disarmed" in the stale state and finished at once,
    ok ``on_ground_disarmed`` with nothing sent; the vehicle armed a moment later and sat
    armed on the ground, in AUTO.LAND or AUTO.LOITER, until PX4's own pre-flight disarm]"""
    b = _arming()
    if middle is A:
        b.drop = _drop_first_disarm()
    b.request(2, middle)
    mark = len(b.sent)
    b.request(3, A)
    b.run(10.0, stop=lambda: b.finished(3) is not None)
    abort = b.finished(3)
    assert abort is not None, b.events[-5:]
    assert (abort.ok, abort.reason) != (True, ON_GROUND_DISARMED)
    assert (abort.ok, abort.reason) == (True, "COMPONENT_ARM_DISARM")
    assert {(c[0], c[1]) for c in _after(b, mark)} == {("COMPONENT_ARM_DISARM", 0.0)}
    # disarmed by the ABORT itself, well before PX4's pre-flight disarm (COM_DISARM_PRFLT)
    assert not b.sim.armed and b.sim.landed == LandedState.ON_GROUND
    assert b.now < 5.0 + 3.0  # the bench starts the take-off at 3 s


def test_an_abort_at_lift_off_whose_disarm_is_refused_in_the_air_lands() -> None:
    """A take-off's motors lift the vehicle; the ABORT comes while our state still says
    "on the ground" (PX4's landed state not reported yet), so it sends a plain DISARM,
    which PX4 refuses in the air. The ABORT then lands, under the same task: never a forced
    disarm. [main: the ABORT FAILED ``TEMPORARILY_REJECTED``, the superseded take-off sent
    nothing more, and PX4 climbed on to the take-off altitude (10 m) and loitered there;
    the take-off's operator had been told it "stopped there"]"""
    b = _lifting()
    b.run(20.0, stop=lambda: b.sim.landed != LandedState.ON_GROUND)
    assert b.core.state.landed_state == LandedState.ON_GROUND  # ours: not yet
    mark = len(b.sent)
    b.request(2, A)
    b.run(20.0, stop=lambda: b.finished(2) is not None)
    abort = b.finished(2)
    assert abort is not None
    assert (abort.ok, abort.reason) == (True, "NAV_LAND"), abort
    assert {c[0] for c in _after(b, mark)} == {"COMPONENT_ARM_DISARM", "NAV_LAND"}
    disarms = [c for c in b.sent[mark:] if c.command == MavCmd.COMPONENT_ARM_DISARM]
    assert disarms and all(c.params[0] == 0.0 for c in disarms)  # a disarm each
    assert all(c.params[1] != 21196.0 for c in disarms)  # never forced (MAV_CMD 400's magic)
    b.run(20.0)
    assert (b.sim.landed, b.sim.alt_m, b.sim.armed) == (LandedState.ON_GROUND, 0.0, False)


def test_a_busy_takeoffs_copy_resent_after_the_land_ends_never_runs(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Commander B's LAND runs on m01; commander A's TAKEOFF meets it and is REJECTED
    ``busy``. The LAND then completes, and A's plane sends the very same command again (a
    retransmission, or A's operator's client re-sending), still within its validity. The
    vehicle is free now, but the take-off must not run late: its id was persisted as
    executed when it arrived (write-ahead), so the copy is a duplicate. Holds; before, no
    test resent a ``busy`` take-off once the vehicle was free."""
    swarm = _two_commanders(monkeypatch)
    vehicle = RealVehicle(swarm, "m01")
    sent: list[tuple[str, Command]] = []
    original = DataPlane.send_command

    def spy(plane: DataPlane, command: Command, now: float) -> int:
        sent.append((plane.local.name, command))
        return original(plane, command, now)

    monkeypatch.setattr(DataPlane, "send_command", spy)
    lead, lead2 = swarm.cores["lead"], swarm.cores["lead2"]
    swarm.call("lead2", lambda now: lead2.request_command({"kind": "land", "only": ["m01"]}, now))
    swarm.run(0.3)
    reply = swarm.call(
        "lead", lambda now: lead.request_takeoff({"alt_m": 5.0, "only": ["m01"]}, now)
    )
    takeoff = int(reply["command_id"])
    swarm.run(0.5)
    refused = _row(swarm, "lead", takeoff)
    assert (refused["state"], refused["reason"]) == ("rejected", "busy")
    # PX4 switches to AUTO.LAND (armed, custom mode): the LAND completes, the vehicle is free
    landing = Heartbeat(12, 2, 1 | 128, MODE_LAND.custom_mode, MavState.ACTIVE)
    vehicle.observe(landing, 0.1)
    swarm.run(0.5)
    assert not vehicle.core.busy()
    # the two commanders make the same ids (docs/dataplane.md, "Exactly once" 4): A's own
    (command,) = [c for name, c in sent if name == "lead" and c.command_id == takeoff]
    snap = lead.request_outcomes({"command_id": takeoff}, swarm.net.now)
    assert snap["valid_left_s"] > 0  # still valid: only the executed record stops it
    plane = lead.plane
    assert plane is not None
    m01 = swarm.cores["m01"].plane
    assert m01 is not None
    duplicates = m01.counters["command_duplicate"]
    swarm.call("lead", lambda now: original(plane, command, now))
    swarm.run(3.0)
    assert m01.counters["command_duplicate"] == duplicates + 1  # it arrived, and was one
    assert vehicle.core.last_takeoff is None  # no take-off sequence was ever made
    # the vehicle was asked once, while the LAND ran (and refused it busy); never again
    assert [r.kind for r in swarm.requests("m01")] == [L, TaskKind.TAKEOFF]
    assert _row(swarm, "lead", takeoff)["reason"] == "busy"


def test_the_record_word_is_ordered_by_life_first_and_sticks_marked_at_the_cap() -> None:
    """Unit, ``CommandTracker``: the member's words on its record are ordered by (boot
    epoch, ``save_gen``) lexicographically, so a later life's word wins at any generation
    (its count starts again at 1) and an earlier life's word never beats it, whatever its
    generation. At the cap (``save_gen`` stuck at 2^32 - 1, ``member.MAX_SAVE_GEN``) a mark
    still marks and a clear no longer clears: the alarm side. Holds; no test had two
    epochs' words or the cap."""
    tracker = CommandTracker()
    tracker.sent(1, "hold", ["m01"], 0.0, valid_for_s=5.0, epochs={"m01": 1})

    def word(epoch: int, mark: bool, gen: int) -> bool:
        tracker.record(
            1,
            "m01",
            CommandResult.ACCEPTED,
            "",
            0.1,
            epoch=epoch,
            not_saved=mark,
            now_saved=not mark,
            save_gen=gen,
        )
        marked: bool = tracker.snapshot(1, 0.2)["nodes"]["m01"]["save_failed"]  # type: ignore[index]
        return marked

    assert word(1, True, 1000) is True
    assert word(2, False, 1) is False  # a later life's clear, at a lower generation
    assert word(1, True, 5000) is False  # the earlier life's mark, late: older
    assert word(2, True, 2) is True
    assert word(2, False, MAX_SAVE_GEN) is False
    assert word(2, True, MAX_SAVE_GEN) is True  # the cap: a mark at the same word marks
    assert word(2, False, MAX_SAVE_GEN) is True  # and a clear no longer clears


def test_swarmctl_says_no_completion_will_come_only_once_the_row_is_settled(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """m01 accepts a TAKEOFF (the ACCEPTED gets through), completes it while what it sends
    is lost, and its daemon restarts with its state file. The commander sees the new life
    before the re-report of the COMPLETED gets through: the row says
    ``restarted_before_finishing`` at once, unsettled for the grace a re-report under repair
    gets, and then COMPLETED, after the restart. ``swarmctl takeoff`` following it must not
    tell the operator "no completion will come" on the unsettled row: a completion did come.
    [main: it said so at the first poll after the new life was seen, then "completed"]"""
    monkeypatch.setattr(takeoff_cmd, "POLL_S", 0.0)
    flight = Flight(1, seed=7)
    swarm = flight.swarm
    swarm.run(3.0)
    cid, _ = _takeoff(flight, valid_for_s=30.0)

    def snap() -> dict[str, Any]:
        s: dict[str, Any] = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
        return s

    swarm.run(0.3)
    accepted = snap()
    assert accepted["nodes"]["m01"]["state"] == "accepted"
    flight.cut = lambda a, b: a == "m01"  # what m01 sends from now on is lost
    swarm.run(VEHICLE_TASK_S + 0.5)
    assert len(flight.ran("m01", cid)) == 1
    _restart(flight, "m01", epoch=2, discovered=True)  # the re-report: into the cut
    swarm.run(0.5)
    ended = snap()
    row = ended["nodes"]["m01"]
    assert (row["state"], row["reason"], ended["done"]) == ("accepted", RESTARTED_RUNNING, False)
    flight.cut = lambda a, b: False
    swarm.run(UNREACHABLE_GRACE_S)
    final = snap()
    row = final["nodes"]["m01"]
    assert (row["state"], row["after_restart"], final["done"]) == ("completed", True, True)
    args = argparse.Namespace(json=False, timeout=30.0)
    reply = {"command_id": cid, "ready": ["m01"], "valid_for_s": 30.0}
    client = _Snaps([accepted, ended, final])
    code = takeoff_cmd._follow(client, takeoff_cmd._Run(args), reply, "takeoff")  # type: ignore[arg-type]
    out = capsys.readouterr().out
    assert code == 0, out
    assert "no completion will come" not in out, out
    assert "m01: completed" in out
