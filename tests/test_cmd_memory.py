"""Exactly once across a lost state file (docs/dataplane.md, "A life runs only its own
commands"; docs/security.md).

A member whose state file is lost or corrupt (``statefile.py`` replaces a corrupt one and
starts with no executed ids) forgets which command ids it ran. Every path by which a
command id it may already have run can reach it again, each written as a test:

- *the operator's resend*: ``swarmctl`` and the control socket cannot resend an id (each
  ``takeoff``/``command`` request makes a new one, ``DataPlane.make_command``); only a
  caller of ``DataPlane.send_command`` can, in the same commander life (the resend of
  ``tests.test_cmd_in_flight``) or after the commander restarted (an old ``Command`` kept
  by its caller);
- *the commander's repairs, eager resends and hand-over to a member found again*: never to a
  later life (voided at its new epoch, ``tests/test_cmd_rejoin.py``; datagrams sealed to the
  earlier epoch are refused), pinned here again for a member without its state;
- *a commander that restarted without its own state*: its boot counter starts again, and
  with it the command ids (``incarnation << 32 | counter``), so a member that remembers the
  earlier life's id swallowed the new command as a duplicate;
- *captured datagrams*: bound to the member's earlier epoch, refused
  (``tests/test_dataplane_auth.py``).

The defence is the member's own: a life runs only a command whose copy proves, on the
member's own clock, that it was issued after this life began (``validity.issued_in_life``);
anything else is REJECTED ``memory_lost``. A resend carries the first issue's dating.
"""

from __future__ import annotations

from typing import Any

import pytest

from swarmd.dataplane import ForeignCommandId
from swarmd.dataplane.types import Command, CommandKind, CommandResult, TimeEcho
from swarmd.dataplane.validity import (
    MEMORY_LOST,
    STAMP_MODULUS,
    issued_in_life,
    stamp_ms,
)
from swarmd.swarm.commander import RESTARTED, RESTARTED_RUNNING, CommandTracker
from swarmd.swarm.core import SwarmCore, SwarmSettings
from swarmd.swarm.events import OutcomeReported
from swarmd.swarm.roles import Roles
from tests.test_cmd_in_flight import Flight, _issue, _reboot, _resend
from tests.test_cmd_validity import _follow_output
from tests.test_dataplane_swarm import address_of, make_plane
from tests.test_swarm_core import Swarm

# ---- the member's rule, pure ---------------------------------------------------------------


def _command(stamp: int, age_ms: int, valid_ms: int = 30_000) -> Command:
    return Command(
        7, CommandKind.TAKEOFF, 5.0, ["m01"], valid_ms, [TimeEcho("m01", stamp, age_ms, 1)]
    )


def test_a_copy_dated_before_the_life_began_is_refused() -> None:
    """Same clock (a daemon restart): the echoed report was sent 2 s before this life
    began, the command issued 0.5 s after that report: before the life, refused."""
    life = 100.0
    now = 101.0
    old = _command(stamp_ms(life - 2.0), 500)
    assert not issued_in_life(old, "m01", life, now).valid
    # issued 3 s after that report: after the life began, it runs
    assert issued_in_life(_command(stamp_ms(life - 2.0), 3_000), "m01", life, now).valid


@pytest.mark.parametrize("age_ms", [0, 1, 250, 20_000])
@pytest.mark.parametrize("after_s", [0.0, 0.0004, 0.001, 0.5, 60.0])
def test_a_command_issued_in_this_life_always_passes(age_ms: int, after_s: float) -> None:
    """Honest: the echoed report is this life's (sent at or after its start, the first at
    the start itself), the command issued ``age`` after it, received at once or later."""
    life = 1000.0003  # not on a millisecond: the stamps round down
    sent = life + after_s
    issued = sent + age_ms / 1000.0
    for delay_s in (0.0, 0.002, 1.0):
        judgement = issued_in_life(_command(stamp_ms(sent), age_ms), "m01", life, issued + delay_s)
        assert judgement.valid, (age_ms, after_s, delay_s, judgement)


def test_an_age_stretched_by_the_commanders_clock_cannot_pass_the_start() -> None:
    """The age is measured on the commander's clock, which may run fast: the bound is
    shortened by the drift allowance (200 ppm), so an age that reads just past the start
    on the commander's clock does not prove an issue after it."""
    life = 500.0
    report = life - 100.0  # 100 s before the life
    age_ms = 100_000 + 1  # 1 ms past the start as the commander's clock reads it
    assert not issued_in_life(_command(stamp_ms(report), age_ms), "m01", life, life + 1).valid


@pytest.mark.parametrize("old_uptime_s", [30.0, 3_600.0, 40 * 86_400.0])
def test_a_copy_dated_on_the_clock_of_an_earlier_os_boot_is_refused(old_uptime_s: float) -> None:
    """An OS reboot starts the monotonic clock again: a stamp of the earlier boot reads,
    modulo 2^32, as later than now (refused) or as before the life began (refused)."""
    life = 20.0  # the daemon started 20 s after the new boot
    for now in (life + 0.5, life + 5.0):
        old = _command(stamp_ms(old_uptime_s), 500)
        assert not issued_in_life(old, "m01", life, now).valid, (old_uptime_s, now)


def test_no_echo_or_another_members_echo_cannot_prove_anything() -> None:
    bare = Command(7, CommandKind.TAKEOFF, 5.0, ["m01"], 3000, [])
    assert not issued_in_life(bare, "m01", 0.0, 1.0).valid
    other = Command(7, CommandKind.TAKEOFF, 5.0, ["m01"], 3000, [TimeEcho("m02", 500, 0, 1)])
    assert not issued_in_life(other, "m01", 0.0, 1.0).valid


def test_the_wrap_of_the_stamps_is_handled() -> None:
    """A life that began just before the u32 millisecond stamps wrap (49.7 days)."""
    life = (STAMP_MODULUS - 500) / 1000.0
    now = life + 2.0
    fresh = _command(stamp_ms(life + 1.0), 100)  # after the wrap, in this life
    assert issued_in_life(fresh, "m01", life, now).valid
    stale = _command(stamp_ms(life - 1.0), 100)
    assert not issued_in_life(stale, "m01", life, now).valid


# ---- on the swarm ----------------------------------------------------------------------------


def _send_new(swarm: Swarm, kind: CommandKind, valid_ms: int, altitude_m: float = 0.0) -> Command:
    """A new command to m01, dated by its last report's echo, sent by the commander's plane."""
    plane = swarm.lead.plane
    assert plane is not None
    command = plane.make_command(
        kind,
        altitude_m=altitude_m,
        targets=["m01"],
        valid_ms=valid_ms,
        echoes=plane.time_echoes(["m01"], swarm.net.now),
    )
    swarm.call("lead", lambda now: plane.send_command(command, now))
    return command


def _outcomes(flight: Flight, name: str, cid: int) -> list[tuple[CommandResult, str]]:
    return [
        (e.result, e.reason)
        for e in flight.swarm.events[name]
        if isinstance(e, OutcomeReported) and e.command_id == cid
    ]


def _row(flight: Flight, cid: int) -> dict[str, Any]:
    swarm = flight.swarm
    return dict(swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"]["m01"])


def test_a_resent_id_never_runs_again_on_a_member_that_lost_its_memory() -> None:
    """m01 took the TAKEOFF, its daemon restarted without its state dir, and the same id
    is sent again by the commander while valid, freshly dated by its caller: m01's new life
    refuses it (REJECTED ``memory_lost``), its vehicle was told once; the commander's row
    keeps what the first life said (accepted)."""
    flight = Flight(1, seed=41)
    swarm = flight.swarm
    swarm.run(3.0)
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.3)
    core = _reboot(flight, "m01", state_kept=False)
    swarm.run(0.5)
    _resend(swarm, cid)
    swarm.run(5.0)
    assert len(flight.ran("m01", cid)) == 1
    assert core.executor_counters.get("refused_memory_lost") == 1
    assert (CommandResult.REJECTED, MEMORY_LOST) in _outcomes(flight, "m01", cid)
    assert _row(flight, cid)["state"] in ("accepted", "completed")


def test_a_member_that_lost_its_memory_and_its_answer_tells_the_operator() -> None:
    """Everything m01 said after the TAKEOFF was lost, then it restarted without its state
    dir; the same id is sent again: its new life refuses it and the operator's row says
    ``memory_lost`` (after restart): the drone may have run it before, and will not now."""
    flight = Flight(1, seed=42)
    swarm = flight.swarm
    swarm.run(3.0)
    flight.cut = lambda a, b: a == "m01"
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.3)
    assert len(flight.ran("m01", cid)) == 1
    _reboot(flight, "m01", state_kept=False)
    flight.cut = lambda a, b: False
    swarm.run(0.5)
    _resend(swarm, cid)
    swarm.run(5.0)
    assert len(flight.ran("m01", cid)) == 1
    row = _row(flight, cid)
    assert (row["state"], row["reason"], row["after_restart"]) == ("rejected", MEMORY_LOST, True)


def test_a_resend_carries_the_dating_of_the_first_issue() -> None:
    """The commander's plane dates an id once: a later ``send_command`` of the same id
    carries the first issue's echo and validity, whatever its caller put in (so a resend
    can neither outlive the first validity nor pass as issued later)."""
    flight = Flight(1, seed=43)
    swarm = flight.swarm
    swarm.run(3.0)
    first = _send_new(swarm, CommandKind.HOLD, 2000)
    plane = swarm.lead.plane
    assert plane is not None
    swarm.run(1.0)
    redated = Command(
        first.command_id,
        CommandKind.HOLD,
        0.0,
        ["m01"],
        600_000,
        plane.time_echoes(["m01"], swarm.net.now),
    )
    assert plane.dated(redated) == Command(
        first.command_id, CommandKind.HOLD, 0.0, ["m01"], 2000, list(first.echoes)
    )


def _restart_commander(
    flight: Flight,
    *,
    epoch: int,
    incarnation: int,
    m01_epoch: int = 1,
    members_hear_it: bool = True,
) -> SwarmCore:
    """The commander's daemon restarts in boot ``epoch`` with boot counter ``incarnation``
    (the state file's: the first life's again when it was lost) and discovery on both sides
    reports it (m01 in its boot ``m01_epoch``); with ``members_hear_it`` False only the
    commander's side does (the members still know its earlier epoch)."""
    swarm = flight.swarm
    bundle = swarm.bundle
    core = SwarmCore(
        Roles.of(bundle, bundle.participant("lead")),
        make_plane(bundle, "lead", epoch=epoch, incarnation=incarnation),
        verdict=None,
        link_q=lambda: 0.8,
        settings=SwarmSettings(readiness_period_s=0.5, stale_after_s=3.0),
    )
    swarm.cores["lead"] = core
    core.start(swarm.net.now)
    swarm.net.replace(swarm.ids["lead"], core)
    now = swarm.net.now
    for other in swarm.cores:
        if other != "lead":
            core.peer_up(other, address_of(bundle, other), m01_epoch, now)
            if members_hear_it:
                swarm.cores[other].peer_up("lead", address_of(bundle, "lead"), epoch, now)
            swarm.net.poke(swarm.ids[other])
    swarm.net.poke(swarm.ids["lead"])
    return core


def test_a_commander_restarted_without_its_state_never_reuses_a_command_id() -> None:
    """The commander's first life (boot 1) sends a TAKEOFF; m01 runs it and keeps its id.
    The commander's state file is lost: its next life counts boot 1 again (a higher epoch,
    from the epoch file or the wall clock). Its first command, a LAND, must get a new id,
    or m01 drops it as a duplicate and the operator is told it was not reached."""
    flight = Flight(1, seed=44)
    swarm = flight.swarm
    swarm.run(3.0)  # the commander's first life: boot counter 0, epoch 1
    takeoff = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(2.0)
    assert len(flight.ran("m01", takeoff)) == 1
    lead = _restart_commander(flight, epoch=2, incarnation=0)  # the counter starts again
    swarm.run(3.0)
    land = int(_issue(swarm, CommandKind.LAND)["command_id"])
    assert land != takeoff
    swarm.run(5.0)
    assert len(flight.ran("m01", land)) == 1
    row = lead.request_outcomes({"command_id": land}, swarm.net.now)["nodes"]["m01"]
    assert row["state"] in ("accepted", "completed"), row


def test_an_old_command_resent_by_a_restarted_commander_is_refused() -> None:
    """The commander restarts and sends again an old ``Command`` its caller kept: its plane
    refuses to send an id of an earlier life (``ForeignCommandId``, nothing on the air,
    tests/test_cmd_id_of_life.py). Were it sent anyway (a commander without that check:
    here its ledger is handed the first issue's dating by hand), with the echo of its first
    issue, m01, which restarted without its state dir meanwhile, refuses it
    (``memory_lost``) by its own clock, whatever the commander does."""
    flight = Flight(1, seed=45)
    swarm = flight.swarm
    swarm.run(3.0)
    old = _send_new(swarm, CommandKind.TAKEOFF, 30_000, altitude_m=5.0)
    swarm.run(0.5)
    assert len(flight.ran("m01", old.command_id)) == 1
    core = _reboot(flight, "m01", state_kept=False)
    lead = _restart_commander(flight, epoch=2, incarnation=1, m01_epoch=2)
    swarm.run(1.0)
    new_plane = lead.plane
    assert new_plane is not None
    with pytest.raises(ForeignCommandId):
        new_plane.send_command(old, swarm.net.now)
    assert new_plane.datagrams_to_send() == []
    new_plane._ledger.dated(old, made_here=False)  # the check bypassed: the member's rule
    swarm.call("lead", lambda now: new_plane.send_command(old, now))
    swarm.run(3.0)
    assert len(flight.ran("m01", old.command_id)) == 1
    assert core.executor_counters.get("refused_memory_lost") == 1
    assert (CommandResult.REJECTED, MEMORY_LOST) in _outcomes(flight, "m01", old.command_id)


def test_the_commanders_own_repair_never_reaches_a_member_without_its_memory() -> None:
    """m01 took the TAKEOFF with every answer lost (the commander keeps repairing), then
    restarted without its state dir: the commander's repairs, eager resends and the
    hand-over at its new epoch never give it the copy (voided), so it runs once."""
    flight = Flight(1, seed=46)
    swarm = flight.swarm
    swarm.run(3.0)
    flight.cut = lambda a, b: a == "m01"
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(0.3)
    _reboot(flight, "m01", state_kept=False)
    flight.cut = lambda a, b: False
    swarm.run(10.0)
    assert len(flight.ran("m01", cid)) == 1
    assert _row(flight, cid)["reason"] != RESTARTED_RUNNING  # nothing kept to re-report


def test_a_new_command_after_a_lost_memory_runs() -> None:
    """The rule refuses nothing honest: a command issued after the restart runs."""
    flight = Flight(1, seed=47)
    swarm = flight.swarm
    swarm.run(3.0)
    _reboot(flight, "m01", state_kept=False)
    swarm.run(2.0)
    cid = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(2.0)
    assert len(flight.ran("m01", cid)) == 1
    kept = flight.kept("m01")
    assert ("lead", cid) in kept.executed


def test_swarmctl_tells_the_operator_to_issue_a_new_command(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The row of the test above as ``swarmctl`` follows it: the reason, what it means and
    what to do; the drone's refusal counts as not confirmed (exit 1)."""
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2", "uav3"], 0.0, valid_for_s=3.0, epochs={"uav3": 1})
    tracker.record(2, "uav2", CommandResult.COMPLETED, "IN_AIR", 1.0)
    tracker.not_delivered(2, "uav3", RESTARTED, 1.2)
    tracker.record(2, "uav3", CommandResult.REJECTED, MEMORY_LOST, 1.5, epoch=2)
    snap = tracker.snapshot(2, 10.0)
    assert snap is not None
    row = snap["nodes"]["uav3"]
    assert (row["state"], row["reason"], row["after_restart"]) == ("rejected", MEMORY_LOST, True)
    code, out = _follow_output(snap, capsys)
    assert code == 1
    assert "uav3: refused (memory_lost)" in out and "Issue a new command" in out


def test_a_later_lifes_memory_lost_does_not_hide_an_earlier_acceptance() -> None:
    """uav3 accepted in its first life; its next life refused a resend (``memory_lost``):
    the row stays ``accepted``, what the first life said."""
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav3"], 0.0, valid_for_s=3.0, epochs={"uav3": 1})
    tracker.record(2, "uav3", CommandResult.ACCEPTED, "", 0.1, epoch=1)
    tracker.record(2, "uav3", CommandResult.REJECTED, MEMORY_LOST, 1.5, epoch=2)
    snap = tracker.snapshot(2, 1.6)
    assert snap is not None and snap["nodes"]["uav3"]["state"] == "accepted"
