"""An ``accepted`` row whose member restarted with nothing to re-report (session 15;
docs/dataplane.md, "Outcomes across a restart").

A member that accepted a command and restarted before the task ended never finishes it:
its new life does not run an earlier life's command (the executed ids, and "A life runs
only its own commands"), so no COMPLETED or FAILED will come. When the new life has the
earlier one's record it re-reports the ACCEPTED and the row says ``accepted``,
``restarted_before_finishing``, settled. When it has nothing to re-report (its state file
lost, or the write that would have kept the answer failed) the row stayed ``accepted``
and unsettled: ``swarmctl takeoff`` followed it until its own wait ran out. Now the
commander's discovery of the member's later boot epoch (authenticated SPDP) ends such a
row: ``restarted_before_finishing`` at once, settled ``UNREACHABLE_GRACE_S`` later (a
re-report under repair still fills it).

Virtual time on the swarm cores; real daemons: ``tests/test_cmd_life_ended_loopback.py``.
"""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.dataplane.types import CommandKind, CommandResult
from swarmd.swarm.commander import RESTARTED_RUNNING, UNREACHABLE_GRACE_S, CommandTracker
from swarmd.swarm.events import CommandLifeEnded
from tests.test_cmd_in_flight import Flight, _issue, _reboot
from tests.test_cmd_save_failed import KINDS, _row


def _snap(flight: Flight, cid: int) -> dict[str, object]:
    swarm = flight.swarm
    snap: dict[str, object] = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
    return snap


def _said(flight: Flight, cid: int) -> tuple[str, str, bool]:
    row = _row(flight, cid)
    return row["state"], row["reason"], row["after_restart"]


def _accepted_then_restarted(
    seed: int, kind: CommandKind, *, state_kept: bool, then_s: float
) -> tuple[Flight, int]:
    """m01 accepts a command of ``kind``; its daemon restarts while the task runs (the
    played vehicle takes 1 s), with its state dir or without; ``then_s`` later."""
    flight = Flight(1, seed=seed)
    swarm = flight.swarm
    swarm.run(3.0)
    cid = int(_issue(swarm, kind)["command_id"])
    swarm.run(0.3)
    assert (_row(flight, cid)["state"], _snap(flight, cid)["done"]) == ("accepted", False)
    _reboot(flight, "m01", state_kept=state_kept)
    swarm.run(then_s)
    return flight, cid


@pytest.mark.parametrize("kind", KINDS)
def test_an_accepted_row_whose_member_restarted_without_its_record_ends(
    kind: CommandKind,
) -> None:
    """m01 accepts, and its daemon restarts while the task runs, its state file lost: the
    new life has nothing to re-report. The row says ``restarted_before_finishing`` as
    soon as the commander sees the new epoch, and is settled after the grace; nothing is
    re-reported, nothing runs again. Before, it stayed ``accepted`` and never settled."""
    flight, cid = _accepted_then_restarted(90, kind, state_kept=False, then_s=0.1)
    swarm = flight.swarm
    assert _said(flight, cid) == ("accepted", RESTARTED_RUNNING, False)
    assert _snap(flight, cid)["done"] is False  # a re-report may still be under repair
    swarm.run(UNREACHABLE_GRACE_S)
    assert _snap(flight, cid)["done"] is True
    swarm.run(30.0)
    row = _row(flight, cid)
    assert (row["state"], row["reason"]) == ("accepted", RESTARTED_RUNNING)
    ended = [e for e in swarm.events["lead"] if isinstance(e, CommandLifeEnded)]
    assert [(e.member, e.command_id) for e in ended] == [("m01", cid)]
    assert len(flight.ran("m01", cid)) == 1
    assert swarm.cores["m01"].counters["outcomes_rereported"] == 0


def test_a_rereport_still_fills_the_row_after_it_ended() -> None:
    """The state file kept: the new life re-reports the ACCEPTED it holds, and the row
    reads as before this change (``after_restart``, settled); the life's end adds nothing
    to it but its log line."""
    flight, cid = _accepted_then_restarted(91, CommandKind.TAKEOFF, state_kept=True, then_s=1.0)
    swarm = flight.swarm
    assert _said(flight, cid) == ("accepted", RESTARTED_RUNNING, True)
    assert _snap(flight, cid)["done"] is True
    assert swarm.cores["m01"].counters["outcomes_rereported"] == 1


def test_lost_and_found_in_the_same_life_or_restarted_after_the_end_changes_nothing() -> None:
    """Guards: a member lost and found again in the same boot epoch is the same life (its
    task still runs: the row waits for its COMPLETED); a restart after the row completed
    leaves it completed."""
    flight = Flight(1, seed=92)
    swarm = flight.swarm
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.3)
    flight.discovery("lead", "m01", False)
    flight.discovery("lead", "m01", True)
    swarm.run(0.1)
    assert (_row(flight, cid)["state"], _row(flight, cid)["reason"]) == ("accepted", "")
    assert _snap(flight, cid)["done"] is False
    swarm.run(5.0)
    assert _row(flight, cid)["state"] == "completed"
    _reboot(flight, "m01", state_kept=False)
    swarm.run(3.0)
    row = _row(flight, cid)
    assert (row["state"], row["after_restart"]) == ("completed", False)
    assert not [e for e in swarm.events["lead"] if isinstance(e, CommandLifeEnded)]


def test_the_tracker_ends_only_accepted_rows_of_an_earlier_epoch() -> None:
    """Unit: ``member_restarted`` against each row's epoch at issue: a pending row is the
    voided copy's (``unreachable``), a final one keeps its answer, an epoch not higher
    than the one at issue is the same life (or an old one) and ends nothing."""
    tracker = CommandTracker()
    epochs = {"m01": 5, "m02": 5, "m03": 5}
    tracker.sent(1, "takeoff", ["m01", "m02", "m03"], 0.0, valid_for_s=3.0, epochs=epochs)
    tracker.record(1, "m01", CommandResult.ACCEPTED, "", 0.1, epoch=5)
    tracker.record(1, "m02", CommandResult.COMPLETED, "IN_AIR", 0.2, epoch=5)
    assert tracker.member_restarted("m01", 5, 0.3) == []
    assert tracker.member_restarted("m01", 4, 0.3) == []
    assert tracker.member_restarted("m02", 6, 0.3) == []
    assert tracker.member_restarted("m03", 6, 0.3) == []
    assert tracker.member_restarted("m01", 6, 0.4) == [1]
    assert tracker.member_restarted("m01", 7, 0.5) == []  # ended once
    nodes = tracker.snapshot(1, 0.5)["nodes"]  # type: ignore[index]
    assert (nodes["m01"]["state"], nodes["m01"]["reason"]) == ("accepted", RESTARTED_RUNNING)
    assert (nodes["m02"]["state"], nodes["m03"]["state"]) == ("completed", "pending")


class _Snaps:
    """A control client that answers ``outcomes`` with each snapshot in turn, then the last."""

    def __init__(self, snaps: list[dict[str, Any]]) -> None:
        self.snaps = snaps

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        assert cmd == "outcomes"
        return self.snaps.pop(0) if len(self.snaps) > 1 else self.snaps[0]


def test_swarmctl_says_the_life_ended_and_that_the_record_was_saved_after_all(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``swarmctl takeoff`` still following: uav2's answer is marked unsaved, then saved
    after all; uav3 accepted and its life ended with nothing to re-report. Each is said
    once, and the end is reached (uav3's row is settled)."""
    monkeypatch.setattr(takeoff_cmd, "POLL_S", 0.0)
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2", "uav3"], 0.0, valid_for_s=3.0, epochs={"uav3": 1})
    tracker.record(2, "uav2", CommandResult.ACCEPTED, "", 0.1, epoch=1, not_saved=True, save_gen=1)
    tracker.record(2, "uav3", CommandResult.ACCEPTED, "", 0.1, epoch=1)
    first = tracker.snapshot(2, 0.2)
    tracker.record(2, "uav2", CommandResult.COMPLETED, "IN_AIR", 1.0, epoch=1)
    tracker.record(
        2, "uav2", CommandResult.COMPLETED, "IN_AIR", 1.1, epoch=1, now_saved=True, save_gen=2
    )
    tracker.member_restarted("uav3", 2, 1.2)
    second = tracker.snapshot(2, 1.3)
    third = tracker.snapshot(2, 1.2 + UNREACHABLE_GRACE_S)
    assert first is not None and second is not None and third is not None
    assert third["done"] is True
    args = argparse.Namespace(json=False, timeout=30.0)
    reply = {"command_id": 2, "ready": ["uav2", "uav3"], "valid_for_s": 3.0}
    run = takeoff_cmd._Run(args)
    client = _Snaps([first, second, third])
    code = takeoff_cmd._follow(client, run, reply, "takeoff")  # type: ignore[arg-type]
    out = capsys.readouterr().out
    assert code == 1  # uav3 is not confirmed airborne
    assert out.count("uav2: its daemon could not write its record") == 1
    assert out.count("uav2: its daemon wrote its record of this command after all") == 1
    assert out.count("uav3: its daemon restarted before the task ended") == 1
    assert "[not saved on drone]" not in out
    assert f"{RESTARTED_RUNNING}" in out
