"""A valid command reaches a member that comes back while it is valid (issue 20, "Command
authority in flight"; docs/dataplane.md, "Rejoining while a command is valid").

The defect the ns-3 split run found (docs/flight-history.md, "Commands in flight"): a HOLD
issued while three members were split off and lost by discovery, valid 30 s; they came
back and were re-discovered 15-18 s before its end, never got it, and the operator was told
``unreachable``. The command writer was volatile and ``peer_down`` dropped the lost
member's proxy with its unacknowledged copies.

The shapes, on virtual time (the swarm core on MemNet, discovery played as the flight
scenarios measured it: a member across a cut lost one lease after the cut, found again in
the same boot epoch after the heal):

- issued while the member is lost, back before the end of the validity: runs there once,
  before the end, and the operator is told ``completed``;
- back after the end: never runs, told ``unreachable`` (``not_reached_while_valid``);
- back, lost again, back (with its answers lost the first time, so the commander hands
  the copy over twice): runs once, the second copy refused as a duplicate, and its
  answer, kept by its outcome writer across the loss, still reaches the operator;
- restarted while lost (a new boot epoch, state dir kept or lost): the copy is dated for
  its earlier life, so it is not handed over (fail closed), and the operator is told at
  once ``unreachable`` (``restarted_before_acknowledging``), not at the end of the validity.
"""

from __future__ import annotations

import argparse

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.dataplane.types import CommandResult
from swarmd.discovery import EngineConfig
from swarmd.swarm.commander import (
    NOT_REACHED,
    RESTARTED,
    UNREACHABLE,
    UNREACHABLE_GRACE_S,
    CommandTracker,
)
from swarmd.swarm.core import SwarmCore
from swarmd.swarm.events import PersistExecuted
from tests.test_cmd_in_flight import Flight
from tests.test_cmd_validity import _command_datagrams, _inject, _Outcomes
from tests.test_dataplane_swarm import address_of

LEASE_S = EngineConfig().lease_s
VALID_S = 30.0  # the ns-3 run's HOLD
NEAR = ("lead", "m01", "m02")
FAR = ("m03", "m04")


def _split(seed: int) -> Flight:
    """Four members; m03 and m04 fly out of range at 3 s and are lost by discovery on
    both sides one lease later. Returns with the clock one second after the loss."""
    flight = Flight(4, seed)
    swarm = flight.swarm
    swarm.run(3.0)
    flight.cut = lambda a, b: (a in NEAR) != (b in NEAR)
    swarm.run(LEASE_S)
    _discovery(flight, up=False)
    swarm.run(1.0)
    return flight


def _discovery(flight: Flight, *, up: bool, far: tuple[str, ...] = FAR) -> None:
    for a in NEAR:
        for b in far:
            flight.discovery(a, b, up)
            flight.discovery(b, a, up)


def _hold(flight: Flight) -> tuple[int, float]:
    swarm = flight.swarm
    request = {"kind": "hold", "valid_for_s": VALID_S}
    sent = swarm.call("lead", lambda now: swarm.lead.request_command(request, now))
    assert sent["sent"], sent
    return int(sent["command_id"]), swarm.net.now


def _rows(flight: Flight, cid: int) -> dict[str, tuple[str, str]]:
    snap = flight.swarm.lead.request_outcomes({"command_id": cid}, flight.swarm.net.now)
    return {name: (row["state"], row["reason"]) for name, row in snap["nodes"].items()}


def _heal(flight: Flight, at: float, *, member_lag_s: float = 0.0) -> None:
    """The far side flies back in range at ``at``; the near side's discovery finds it
    (same boot epoch) 1 s later, the far side's finds the near side ``member_lag_s``
    after that (discovery is asymmetric: until then it drops the commander's datagrams as
    ``peer_not_up`` and the writer keeps repairing)."""
    swarm = flight.swarm

    def back(now: float) -> None:
        flight.cut = lambda a, b: False

    def found_by_near(now: float) -> None:
        for a in NEAR:
            for b in FAR:
                flight.discovery(a, b, True)

    def found_by_far(now: float) -> None:
        for a in NEAR:
            for b in FAR:
                flight.discovery(b, a, True)

    swarm.net.call_at(at, back)
    swarm.net.call_at(at + 1.0, found_by_near)
    swarm.net.call_at(at + 1.0 + member_lag_s, found_by_far)


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("member_lag_s", [0.0, 1.5])
@pytest.mark.parametrize("back_after_s", [2.0, 12.0, 25.0])
def test_a_command_issued_while_a_member_is_lost_runs_there_once_when_it_is_back_in_time(
    back_after_s: float, member_lag_s: float, seed: int
) -> None:
    """The ns-3 split's shape: issued while the far side is lost, the far side back and
    re-discovered before the validity ends (25 s: back 4 s before the end, as in the run),
    the far side finding the commander at the same time or 1.5 s after it was found."""
    flight = _split(seed)
    swarm = flight.swarm
    cid, issued = _hold(flight)
    swarm.run(1.0)
    rows = _rows(flight, cid)
    assert {rows[m] for m in FAR} == {("pending", "")}, rows  # still valid: not yet unreachable
    _heal(flight, issued + back_after_s, member_lag_s=member_lag_s)
    swarm.run(VALID_S + 10.0)
    for name in NEAR[1:] + FAR:
        ran = flight.ran(name, cid)
        assert len(ran) == 1, (name, ran)
        assert ran[0] < issued + VALID_S, (name, ran, issued)
    rows = _rows(flight, cid)
    assert {name: state for name, (state, _) in rows.items()} == dict.fromkeys(
        NEAR[1:] + FAR, "completed"
    ), rows


@pytest.mark.parametrize("seed", [1, 2])
def test_a_member_back_after_the_validity_never_runs_it_and_the_operator_is_told(
    seed: int,
) -> None:
    flight = _split(seed)
    swarm = flight.swarm
    cid, issued = _hold(flight)
    _heal(flight, issued + VALID_S + 3.0)
    swarm.run(VALID_S + 20.0)
    for name in FAR:
        assert flight.ran(name, cid) == [], name
        plane = swarm.cores[name].plane
        assert plane is not None and plane.counters.get("commands_received", 0) == 0
    rows = _rows(flight, cid)
    assert {m: rows[m] for m in FAR} == dict.fromkeys(FAR, (UNREACHABLE, NOT_REACHED)), rows
    assert {rows[m][0] for m in NEAR[1:]} == {"completed"}, rows


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("answers_lost", [False, True])
def test_back_then_lost_again_then_back_runs_once(answers_lost: bool, seed: int) -> None:
    """Back in time, lost again, back again, all within the validity. With
    ``answers_lost`` everything the far side sends is lost during its first return (its
    ACKNACK and its ACCEPTED/COMPLETED): the commander hands the copy over again on the
    second return, and the member refuses that second copy as a duplicate."""
    flight = _split(seed)
    swarm = flight.swarm
    cid, issued = _hold(flight)
    swarm.run(2.0)
    if answers_lost:
        flight.cut = lambda a, b: a in FAR and b in NEAR  # only the way back is cut
    else:
        flight.cut = lambda a, b: False
    _discovery(flight, up=True)
    swarm.run(2.0)
    for name in FAR:
        assert len(flight.ran(name, cid)) == 1, name
    if answers_lost:
        assert {_rows(flight, cid)[m][0] for m in FAR} == {"pending"}
    # out of range again, lost again, then back and found again, still inside the validity
    flight.cut = lambda a, b: (a in NEAR) != (b in NEAR)
    swarm.run(1.0)
    _discovery(flight, up=False)
    swarm.run(2.0)
    flight.cut = lambda a, b: False
    _discovery(flight, up=True)
    swarm.run(VALID_S + 10.0)
    assert swarm.net.now > issued + VALID_S + 2.0
    for name in FAR:
        assert len(flight.ran(name, cid)) == 1, name
        plane = swarm.cores[name].plane
        assert plane is not None
        assert plane.counters.get("commands_received", 0) == 1
        if answers_lost:  # the commander's second hand-over reached it: refused by id
            assert plane.counters["command_duplicate"] >= 1, name
    rows = _rows(flight, cid)
    assert {rows[m][0] for m in FAR} == {"completed"}, rows


def _restart_while_lost(flight: Flight, name: str, *, state_kept: bool) -> SwarmCore:
    """``name``'s daemon restarts while it is cut off: a new boot epoch (2) and
    incarnation, the executed ids of its last ``PersistExecuted`` if its state dir is
    kept. Discovery is left to the caller (it is still lost on both sides)."""
    swarm = flight.swarm
    core = flight.restart(
        name, epoch=2, kept=flight.kept(name) if state_kept else PersistExecuted(())
    )
    bundle = swarm.bundle
    for other in swarm.cores:  # its own side of the cut: m03 and m04 see each other
        if other != name and other in FAR:
            core.peer_up(other, address_of(bundle, other), 1, swarm.net.now)
            swarm.cores[other].peer_up(name, address_of(bundle, name), 2, swarm.net.now)
            swarm.net.poke(swarm.ids[other])
    swarm.net.poke(swarm.ids[name])
    return core


@pytest.mark.parametrize("state_kept", [True, False])
def test_a_member_restarted_while_lost_is_not_handed_its_earlier_lifes_copy(
    state_kept: bool,
) -> None:
    """m03 restarts while it is lost; it comes back (new epoch) while the HOLD is valid.
    Its copy carries an echo of its earlier life's clock, which its new life cannot date
    (after a reboot its monotonic clock starts again: the elapsed time would read short):
    the commander does not hand it over, whether or not the state dir survived (without
    it nothing else would stop a second run of a command that might have run), and tells
    the operator ``unreachable`` (``restarted_before_acknowledging``) as soon as it sees the new
    epoch. m04, back in its own life, runs it."""
    flight = _split(seed=5)
    swarm = flight.swarm
    cid, issued = _hold(flight)
    swarm.run(2.0)
    _restart_while_lost(flight, "m03", state_kept=state_kept)
    swarm.run(3.0)
    flight.cut = lambda a, b: False
    bundle = swarm.bundle
    now = swarm.net.now
    for a in NEAR:  # found again, the commander's side seeing the new epoch
        swarm.cores[a].peer_up("m03", address_of(bundle, "m03"), 2, now)
        swarm.cores["m03"].peer_up(a, address_of(bundle, a), 1, now)
        swarm.net.poke(swarm.ids[a])
    swarm.net.poke(swarm.ids["m03"])
    _discovery(flight, up=True, far=("m04",))
    swarm.run(0.5)
    assert swarm.net.now < issued + VALID_S
    assert _rows(flight, cid)["m03"] == (UNREACHABLE, RESTARTED)  # told now, not at the end
    swarm.run(VALID_S + 10.0)
    assert flight.ran("m03", cid) == []
    plane = swarm.cores["m03"].plane
    assert plane is not None and plane.counters.get("commands_received", 0) == 0
    rows = _rows(flight, cid)
    assert rows["m03"] == (UNREACHABLE, RESTARTED), rows
    assert rows["m04"][0] == "completed" and len(flight.ran("m04", cid)) == 1, rows
    # the swarm is whole: a new command reaches the restarted member's new life
    after = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "land"}, now))
    swarm.run(3.0)
    assert len(flight.ran("m03", int(after["command_id"]))) == 1


def test_no_echo_of_an_earlier_life_dates_a_new_command() -> None:
    """Right after m01 restarts, before its new life's first readiness report reaches the
    commander, the last report the commander holds is of its earlier life: a command then
    carries no echo for m01 (it refuses it, fail closed) rather than a stamp of a clock that
    may have started again. Once a report of the new life is in, the echo is back."""
    flight = Flight(2, seed=7)
    swarm = flight.swarm
    swarm.run(3.0)
    plane = swarm.lead.plane
    assert plane is not None
    assert [e.node for e in plane.time_echoes(["m01", "m02"], swarm.net.now)] == ["m01", "m02"]
    flight.cut = lambda a, b: "m01" in (a, b)
    swarm.run(1.0)
    _restart_while_lost(flight, "m01", state_kept=True)
    bundle = swarm.bundle
    swarm.lead.peer_up("m01", address_of(bundle, "m01"), 2, swarm.net.now)
    assert [e.node for e in plane.time_echoes(["m01", "m02"], swarm.net.now)] == ["m02"]
    flight.cut = lambda a, b: False
    reborn = swarm.cores["m01"]
    swarm.call("m01", lambda now: reborn.peer_up("lead", address_of(bundle, "lead"), 1, now))
    swarm.run(2.0)
    assert [e.node for e in plane.time_echoes(["m01"], swarm.net.now)] == ["m01"]


def test_the_tracker_says_restarted_at_once_and_a_real_answer_still_wins() -> None:
    tracker = CommandTracker()
    tracker.sent(3, "hold", ["uav2", "uav3", "uav4"], 0.0, valid_for_s=30.0)
    tracker.record(3, "uav4", CommandResult.ACCEPTED, "", 0.1)
    assert tracker.not_delivered(3, "uav3", RESTARTED, 0.5)
    assert tracker.not_delivered(3, "uav4", RESTARTED, 0.5)
    assert not tracker.not_delivered(3, "uav9", RESTARTED, 0.5)  # not a target
    assert not tracker.not_delivered(4, "uav3", RESTARTED, 0.5)  # not a command we track
    snap = tracker.snapshot(3, 1.0)
    assert snap is not None
    nodes = snap["nodes"]
    assert (nodes["uav3"]["state"], nodes["uav3"]["reason"]) == (UNREACHABLE, RESTARTED)
    assert nodes["uav4"]["state"] == "accepted"  # it answered before its restart: the truth
    assert nodes["uav2"]["state"] == "pending"  # still valid, still deliverable
    tracker.record(3, "uav3", CommandResult.COMPLETED, "", 2.0)  # whatever said so, wins
    again = tracker.snapshot(3, 2.0)
    assert again is not None and again["nodes"]["uav3"]["state"] == "completed"


def test_swarmctl_says_a_restarted_member_will_not_be_sent_the_command(
    capsys: pytest.CaptureFixture[str],
) -> None:
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2", "uav3"], 0.0, valid_for_s=3.0)
    tracker.record(2, "uav2", CommandResult.COMPLETED, "IN_AIR", 1.0)
    tracker.not_delivered(2, "uav3", RESTARTED, 1.0)
    snap = tracker.snapshot(2, 1.0 + UNREACHABLE_GRACE_S)
    assert snap is not None and snap["done"]  # the grace for a re-report over: nothing left
    args = argparse.Namespace(json=False, timeout=30.0)
    reply = {"command_id": 2, "ready": ["uav2", "uav3"], "valid_for_s": 3.0}
    code = takeoff_cmd._follow(_Outcomes(snap), takeoff_cmd._Run(args), reply, "takeoff")  # type: ignore[arg-type]
    out = capsys.readouterr().out
    assert code == 1
    assert "uav3: unreachable: it restarted before it acknowledged the command" in out
    assert "can no longer run there" in out
    assert out.splitlines()[-1].endswith("can no longer start there: uav3")


def rejoin_delays(seed: int, loss: float) -> list[float]:
    """Seconds from re-discovery (both sides at once, 12 s after the issue) to each far
    member's vehicle request, with ``loss`` on every link after the heal."""
    flight = _split(seed)
    swarm = flight.swarm
    cid, issued = _hold(flight)
    swarm.run(12.0)
    names = flight.names
    swarm.net.link_loss = lambda s, d: loss if names[s] != names[d] else 0.0
    found = swarm.net.now
    _discovery(flight, up=True)
    swarm.run(VALID_S)
    return [flight.ran(name, cid)[0] - found for name in FAR]


if __name__ == "__main__":  # python -m tests.test_cmd_rejoin
    import statistics

    print("| loss after the heal | re-discovery -> executed: median | p95 | max | runs |")
    for loss in (0.0, 0.1, 0.3):
        delays = [d for s in range(1, 51) for d in rejoin_delays(s, loss)]
        p95 = statistics.quantiles(delays, n=20)[18]
        print(
            f"| {loss:.0%} | {statistics.median(delays) * 1e3:.0f} ms | {p95 * 1e3:.0f} ms "
            f"| {max(delays) * 1e3:.0f} ms | {len(delays)} |"
        )


def test_a_handed_over_copy_held_back_past_the_validity_is_refused() -> None:
    """The delay attack on the hand-over: discovery on both sides finds the far side again
    while its radio is still jammed, so the copies the commander hands over are heard only
    by an attacker, who releases one after the validity. m03 refuses it as expired (its
    own deadline from the echo), says so, and nothing later runs it."""
    flight = _split(seed=9)
    swarm = flight.swarm
    request = {"kind": "hold", "valid_for_s": 5.0}
    sent = swarm.call("lead", lambda now: swarm.lead.request_command(request, now))
    cid, issued = int(sent["command_id"]), swarm.net.now
    swarm.run(1.0)
    _discovery(flight, up=True)  # found again; the cut (the jammer) still holds
    swarm.run(5.0)
    held = _command_datagrams(swarm, cid, "m03", issued)
    assert held, "the commander handed the HOLD over towards m03"
    assert swarm.net.now > issued + 5.0
    flight.cut = lambda a, b: False  # the jammer stops; its capture is released late
    _inject(swarm, "m03", held[0])
    assert flight.ran("m03", cid) == []
    executor = swarm.cores["m03"].executor_status()["counters"]
    assert executor["refused_expired"] == 1
    for copy in held[1:]:
        _inject(swarm, "m03", copy)
    swarm.run(5.0)
    assert flight.ran("m03", cid) == [] and flight.ran("m04", cid) == []
    rows = _rows(flight, cid)
    assert rows["m03"] == ("rejected", "expired"), rows
