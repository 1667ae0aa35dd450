"""Commands that never run late (issue 18, first Build bullet), on virtual time.

The swarm core's commander and members on ``MemNet`` (``tests.test_swarm_core.Swarm``): a
member cut off with ``MemNet.isolate`` while a command is valid never runs it after the
link returns, and the commander says ``unreachable``; a HOLD whose cut ends within its
validity still runs, once; the attacker who holds an authenticated datagram and releases
it later (delay: replays are already refused by the counters) gets it refused as
``expired``, reported back; copies after that never run; a copy released while still valid
runs once; an edited validity fails the MAC. Then the dating itself (``validity.judge``),
as a property over clock offsets, drift and delays: a member never grants more time than
the commander's validity, whatever the clocks read.
"""

from __future__ import annotations

import argparse
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.cli import takeoff_cmd
from swarmd.dataplane import Command, CommandKind, CommandResult
from swarmd.dataplane.types import MAX_VALID_MS, TimeEcho
from swarmd.dataplane.validity import (
    DRIFT_PPM,
    EXPIRED,
    STAMP_MODULUS,
    judge,
    stamp_ms,
    valid_ms_of,
)
from swarmd.px4.vehicle import TaskKind
from swarmd.swarm.commander import NOT_REACHED, UNREACHABLE, UNREACHABLE_GRACE_S, CommandTracker
from swarmd.swarm.core import DEFAULT_VALID_FOR_S, MAX_PENDING_WITHDRAWALS, RequestInvalid
from swarmd.swarm.events import CommandExpired
from tests.test_dataplane_swarm import address_of
from tests.test_swarm_core import Swarm

CUT_S = 8.0  # shorter than any lease; longer than every default validity but LAND/ABORT's


def _row(swarm: Swarm, cid: int, name: str) -> dict[str, Any]:
    snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
    row: dict[str, Any] = snap["nodes"][name]
    return row


def _counters(swarm: Swarm, name: str) -> dict[str, int]:
    counters: dict[str, int] = swarm.cores[name].executor_status()["counters"]
    return counters


def _plane_counters(swarm: Swarm, name: str) -> dict[str, int]:
    plane = swarm.cores[name].plane
    assert plane is not None
    return dict(plane.counters)


def _command_datagrams(swarm: Swarm, cid: int, to: str, since: float) -> list[bytes]:
    """Every datagram the commander handed the network for ``to`` carrying command ``cid``
    (MemNet records what an isolated node sends too: what a radio near it would hear)."""
    target = address_of(swarm.bundle, to)
    marker = cid.to_bytes(8, "little")
    return [
        t.payload
        for t in swarm.net.transmissions
        if t.node == swarm.ids["lead"] and t.target == target and t.time >= since
        if marker in t.payload
    ]


def _inject(swarm: Swarm, to: str, datagram: bytes) -> None:
    """The attacker releases a held datagram at ``to``: authentic bytes, late."""
    core = swarm.cores[to]
    source = address_of(swarm.bundle, "lead")
    swarm.call(to, lambda now: core.receive_datagram(datagram, source, now))


def _cut_takeoff(swarm: Swarm, valid_for_s: float | None = None) -> tuple[int, float]:
    """m01 is cut off; one second later the operator sends a TAKEOFF to every member (m01's
    last report is still fresh on the commander, as in the issue's run)."""
    swarm.run(3.0)
    swarm.net.isolate(swarm.ids["m01"])
    swarm.run(1.0)
    sent_at = swarm.net.now
    request: dict[str, Any] = {"alt_m": 5.0}
    if valid_for_s is not None:
        request["valid_for_s"] = valid_for_s
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff(request, now))
    assert sent["sent"] and "m01" in sent["ready"], sent
    default = DEFAULT_VALID_FOR_S[CommandKind.TAKEOFF]
    assert sent["valid_for_s"] == (default if valid_for_s is None else valid_for_s)
    return int(sent["command_id"]), sent_at


def test_takeoff_sent_during_a_cut_never_runs_after_the_link_returns() -> None:
    swarm = Swarm(3, seed=18)
    cid, sent_at = _cut_takeoff(swarm)
    swarm.run(1.0)
    assert _row(swarm, cid, "m01")["state"] == "pending"  # still valid: may yet arrive
    swarm.run(CUT_S - 1.0)
    # validity + grace over: the commander says which drone it did not reach, and that the
    # command can no longer run there; the others flew
    snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
    assert snap["done"] and snap["valid_left_s"] == 0.0
    assert (snap["nodes"]["m01"]["state"], snap["nodes"]["m01"]["reason"]) == (
        UNREACHABLE,
        NOT_REACHED,
    )
    assert snap["nodes"]["m02"]["state"] == snap["nodes"]["m03"]["state"] == "completed"
    lead_plane = swarm.lead.plane
    assert lead_plane is not None
    writer = lead_plane.status(swarm.net.now)["writers"]["swarm/command"]
    assert writer["withdrawn"] == 1
    # the commander stopped sending the command itself once its validity ended
    last_copy = max(
        t.time
        for t in swarm.net.transmissions
        if t.node == swarm.ids["lead"] and cid.to_bytes(8, "little") in t.payload
    )
    assert last_copy <= sent_at + 3.0
    # the link returns: repair resumes (heartbeats, GAP), the TAKEOFF never runs
    swarm.net.isolate(swarm.ids["m01"], False)
    swarm.run(10.0)
    assert swarm.requests("m01") == []
    assert "received_takeoff" not in _counters(swarm, "m01")
    assert _row(swarm, cid, "m01")["state"] == UNREACHABLE
    assert _plane_counters(swarm, "m01").get("commands_received", 0) == 0
    for m in ("m02", "m03"):
        assert [r.kind for r in swarm.requests(m)] == [TaskKind.TAKEOFF]
    # the members and the commander are in step again: a fresh command reaches m01
    hold = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
    assert swarm.run_until_done(hold["command_id"])["nodes"]["m01"]["state"] == "completed"


def test_hold_arriving_within_its_validity_still_runs_once() -> None:
    swarm = Swarm(2, seed=19)
    swarm.run(3.0)
    swarm.net.isolate(swarm.ids["m01"])
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
    assert sent["valid_for_s"] == 5.0
    swarm.run(2.0)  # a cut shorter than the HOLD's validity
    swarm.net.isolate(swarm.ids["m01"], False)
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert nodes["m01"]["state"] == "completed", nodes
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.HOLD]
    swarm.run(10.0)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.HOLD]
    assert "refused_expired" not in _counters(swarm, "m01")


def test_a_command_held_back_past_its_validity_is_refused_and_reported() -> None:
    """The delay attack: every copy of the TAKEOFF towards m01 is held (m01 is cut off)
    and one is released after the validity. m01 refuses it as expired, says so to the
    commander, and no later copy (released again, or the operator resending the id) runs."""
    swarm = Swarm(2, seed=20)
    cid, sent_at = _cut_takeoff(swarm)
    held = _command_datagrams(swarm, cid, "m01", sent_at)
    assert held, "the commander sent the TAKEOFF towards m01"
    swarm.run(3.5)  # past the 3 s validity, before the link returns
    swarm.net.isolate(swarm.ids["m01"], False)  # so m01's answer can travel
    _inject(swarm, "m01", held[0])
    assert swarm.requests("m01") == []
    assert _counters(swarm, "m01")["refused_expired"] == 1
    expired = [e for e in swarm.events["m01"] if isinstance(e, CommandExpired)]
    assert [e.command_id for e in expired] == [cid]
    swarm.run(3.0)
    row = _row(swarm, cid, "m01")
    assert (row["state"], row["reason"]) == ("rejected", EXPIRED)
    # later copies: a held retransmission, and the operator resending the same id
    for copy in held[1:]:
        _inject(swarm, "m01", copy)
    plane = swarm.lead.plane
    assert plane is not None
    again = Command(cid, CommandKind.TAKEOFF, 5.0, ["m01"], 3000, plane.time_echoes(["m01"], 0))
    swarm.call("lead", lambda now: plane.send_command(again, now))
    swarm.run(5.0)
    assert swarm.requests("m01") == []
    assert _counters(swarm, "m01")["refused_expired"] == 1
    assert "received_takeoff" in _counters(swarm, "m01")  # counted once, as received
    assert _plane_counters(swarm, "m01")["command_duplicate"] >= 1


def test_a_command_held_back_but_still_valid_runs_once() -> None:
    swarm = Swarm(2, seed=21)
    cid, sent_at = _cut_takeoff(swarm)
    held = _command_datagrams(swarm, cid, "m01", sent_at)
    swarm.run(1.0)  # delayed by a second of a 3 s validity
    swarm.net.isolate(swarm.ids["m01"], False)
    _inject(swarm, "m01", held[0])
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]
    nodes = swarm.run_until_done(cid)["nodes"]
    assert nodes["m01"]["state"] == "completed"
    for copy in held[1:]:
        _inject(swarm, "m01", copy)
    swarm.run(5.0)
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]


def test_an_edited_validity_or_echo_is_refused_by_the_mac() -> None:
    """Lengthening the validity (or moving the echoed stamp) of an authentic command
    breaks its tag: the member drops it as ``auth_failed`` and runs nothing."""
    swarm = Swarm(1, seed=22)
    cid, sent_at = _cut_takeoff(swarm, valid_for_s=2.999)  # 2999 ms: one place in the bytes
    original = _command_datagrams(swarm, cid, "m01", sent_at)[0]
    valid = (2999).to_bytes(4, "little")
    assert original.count(valid) == 1
    longer = original.replace(valid, MAX_VALID_MS.to_bytes(4, "little"))
    lead_plane = swarm.lead.plane
    assert lead_plane is not None
    report = lead_plane.readiness_received("m01")
    assert report is not None and report.last is not None
    stamp = report.last.stamp_ms.to_bytes(4, "little")
    assert original.count(stamp) == 1
    later = original.replace(stamp, (report.last.stamp_ms + 5000).to_bytes(4, "little"))
    swarm.run(4.0)  # expired as sent; either edit would make it "valid" again
    swarm.net.isolate(swarm.ids["m01"], False)
    before = _plane_counters(swarm, "m01").get("dropped_auth_failed", 0)
    _inject(swarm, "m01", longer)
    _inject(swarm, "m01", later)
    assert _plane_counters(swarm, "m01")["dropped_auth_failed"] == before + 2
    assert swarm.requests("m01") == []
    assert "refused_expired" not in _counters(swarm, "m01")  # never even decoded
    # the untouched datagram, released as late, is refused as expired instead
    _inject(swarm, "m01", original)
    assert _counters(swarm, "m01")["refused_expired"] == 1
    assert swarm.requests("m01") == []


def test_a_late_answer_replaces_unreachable() -> None:
    """``unreachable`` is what the commander knows at validity + grace; a member's answer
    arriving later still wins (the tracker records the truth)."""
    swarm = Swarm(1, seed=23)
    cid, sent_at = _cut_takeoff(swarm)
    swarm.run(3.0 + UNREACHABLE_GRACE_S)
    assert _row(swarm, cid, "m01")["state"] == UNREACHABLE
    swarm.lead.tracker.record(cid, "m01", CommandResult.REJECTED, EXPIRED, swarm.net.now)
    assert (_row(swarm, cid, "m01")["state"], _row(swarm, cid, "m01")["reason"]) == (
        "rejected",
        EXPIRED,
    )


@pytest.mark.parametrize(
    "value", [0, -1, 0.0001, MAX_VALID_MS / 1000 + 1, float("nan"), float("inf"), True, "3"]
)
def test_a_bad_validity_is_refused_by_the_commander(value: object) -> None:
    swarm = Swarm(1)
    swarm.run(2.0)
    with pytest.raises(RequestInvalid, match="valid_for_s"):
        swarm.lead.request_command({"kind": "land", "valid_for_s": value}, swarm.net.now)
    assert swarm.lead.tracker.recent(swarm.net.now) == []


def test_the_operator_sets_the_validity() -> None:
    swarm = Swarm(1)
    swarm.run(2.0)
    sent = swarm.call(
        "lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5, "valid_for_s": 1.5}, now)
    )
    assert sent["valid_for_s"] == 1.5
    snap = swarm.lead.request_outcomes({"command_id": sent["command_id"]}, swarm.net.now)
    assert snap["valid_for_s"] == 1.5 and snap["valid_left_s"] == 1.5


# ---- the dating, without a network ---------------------------------------------------------


def _cmd(valid_ms: int, echoes: list[TimeEcho]) -> Command:
    return Command(1, CommandKind.TAKEOFF, 5.0, [], valid_ms, echoes)


def test_no_validity_or_no_echo_fails_closed() -> None:
    assert not judge(_cmd(0, [TimeEcho("m", 0, 0, 1)]), "m", 0.0).valid
    assert not judge(_cmd(3000, []), "m", 0.0).valid
    assert not judge(_cmd(3000, [TimeEcho("other", 0, 0, 1)]), "m", 0.0).valid
    assert judge(_cmd(3000, [TimeEcho("m", 0, 0, 1)]), "m", 0.0).valid


def test_a_stamp_from_the_future_reads_as_long_ago() -> None:
    """A stamp ahead of the member's clock (another boot of it, or garbage) wraps to an
    elapsed time of about 2^32 ms: refused."""
    now = 100.0
    ahead = TimeEcho("m", stamp_ms(now) + 5, 0, 1)
    assert not judge(_cmd(MAX_VALID_MS, [ahead]), "m", now).valid


def test_the_millisecond_stamp_wraps_without_losing_time() -> None:
    wrap_s = STAMP_MODULUS / 1000.0
    echo = TimeEcho("m", stamp_ms(wrap_s - 0.5), 0, 1)  # sent 0.5 s before the wrap
    assert judge(_cmd(3000, [echo]), "m", wrap_s + 2.0).valid  # 2.5 s later
    assert not judge(_cmd(3000, [echo]), "m", wrap_s + 2.6).valid  # 3.1 s later


def test_valid_ms_of_rounds_down_and_caps() -> None:
    assert valid_ms_of(3.0) == 3000 and valid_ms_of(0.0001) == 1
    assert valid_ms_of(1e9) == MAX_VALID_MS


@settings(max_examples=300, deadline=None)
@given(
    member_offset_s=st.floats(-1e6, 1e6),
    commander_offset_s=st.floats(-1e6, 1e6),
    member_ppm=st.integers(-100, 100),
    commander_ppm=st.integers(-100, 100),
    report_delay_s=st.floats(0.0, 30.0),
    issue_after_s=st.floats(0.0, 60.0),
    command_delay_s=st.floats(0.0, 30.0),
    valid_ms=st.integers(1, MAX_VALID_MS),
)
def test_a_member_never_runs_a_command_after_the_commanders_deadline(
    member_offset_s: float,
    commander_offset_s: float,
    member_ppm: int,
    commander_ppm: int,
    report_delay_s: float,
    issue_after_s: float,
    command_delay_s: float,
    valid_ms: int,
) -> None:
    """Real time t; each clock reads offset + t * (1 + ppm). The member's report leaves at
    t=0, is held ``report_delay_s``, the command is issued ``issue_after_s`` after its
    arrival and held ``command_delay_s``. Whatever the offsets, rates (within the drift
    bound) and delays, the member runs it only if it arrived before the commander's own
    deadline (issue + validity on the commander's clock, in real time)."""
    assert DRIFT_PPM >= 200

    def member_clock(t: float) -> float:
        return member_offset_s + t * (1 + member_ppm * 1e-6)

    def commander_clock(t: float) -> float:
        return commander_offset_s + t * (1 + commander_ppm * 1e-6)

    received_at = report_delay_s
    issued_at = received_at + issue_after_s
    arrives_at = issued_at + command_delay_s
    echo = TimeEcho(
        "m",
        stamp_ms(member_clock(0.0)),
        int((commander_clock(issued_at) - commander_clock(received_at)) * 1000),
        1,
    )
    if echo.age_ms > MAX_VALID_MS * 10:
        return  # the commander does not echo reports that old (MAX_ECHO_AGE_MS)
    verdict = judge(_cmd(valid_ms, [echo]), "m", member_clock(arrives_at))
    # the commander's deadline, in real time: its clock advances valid_ms after the issue
    deadline = issued_at + (valid_ms / 1000.0) / (1 + commander_ppm * 1e-6)
    if verdict.valid:
        assert arrives_at < deadline, (verdict, arrives_at, deadline)


# ---- the commander's rows and swarmctl's words ---------------------------------------------


def test_tracker_calls_silent_targets_unreachable_only_after_validity_and_grace() -> None:
    tracker = CommandTracker()
    tracker.sent(1, "takeoff", ["a", "b", "c"], 10.0, valid_for_s=3.0)
    tracker.record(1, "a", CommandResult.ACCEPTED, "", 10.1)
    tracker.record(1, "b", CommandResult.COMPLETED, "IN_AIR", 11.0)
    end = 10.0 + 3.0 + UNREACHABLE_GRACE_S
    before = tracker.snapshot(1, end - 0.001)
    assert before is not None
    assert before["nodes"]["c"]["state"] == "pending" and not before["done"]
    assert before["valid_left_s"] == 0.0 and before["valid_for_s"] == 3.0
    after = tracker.snapshot(1, end)
    assert after is not None
    # a drone that accepted is running it: never "unreachable", and the command not done
    assert after["nodes"]["a"]["state"] == "accepted"
    assert (after["nodes"]["c"]["state"], after["nodes"]["c"]["reason"]) == (
        UNREACHABLE,
        NOT_REACHED,
    )
    assert not after["done"]
    tracker.record(1, "a", CommandResult.COMPLETED, "IN_AIR", end + 1)
    done = tracker.snapshot(1, end + 1)
    assert done is not None and done["done"]
    # without a validity (a command tracked by hand) nobody is ever called unreachable
    tracker.sent(2, "land", ["c"], 0.0)
    untimed = tracker.snapshot(2, 1e6)
    assert untimed is not None and untimed["nodes"]["c"]["state"] == "pending"


class _Outcomes:
    """A control client that answers ``outcomes`` with one snapshot."""

    def __init__(self, snap: dict[str, Any]) -> None:
        self.snap = snap

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        assert cmd == "outcomes"
        return self.snap


def _follow_output(
    snap: dict[str, Any], capsys: pytest.CaptureFixture[str], *, timeout: float = 30.0
) -> tuple[int, str]:
    args = argparse.Namespace(json=False, timeout=timeout)
    reply = {"command_id": 2, "ready": list(snap["nodes"]), "valid_for_s": snap["valid_for_s"]}
    code = takeoff_cmd._follow(_Outcomes(snap), takeoff_cmd._Run(args), reply, "takeoff")  # type: ignore[arg-type]
    return code, capsys.readouterr().out


def test_swarmctl_says_unreachable_and_that_it_can_no_longer_start(
    capsys: pytest.CaptureFixture[str],
) -> None:
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2", "uav3"], 0.0, valid_for_s=3.0)
    tracker.record(2, "uav2", CommandResult.COMPLETED, "IN_AIR", 1.0)
    snap = tracker.snapshot(2, 5.0)
    assert snap is not None
    code, out = _follow_output(snap, capsys)
    assert code == 1  # as for any drone that did not confirm (docs/operations.md)
    assert "uav3: unreachable: no answer while the command was valid (3 s)" in out
    assert "can no longer start there" in out
    assert "timeout" not in out and "timed out" not in out
    assert out.splitlines()[-1].endswith("can no longer start there: uav3")


def test_swarmctl_timing_out_within_the_validity_says_it_may_still_run(
    capsys: pytest.CaptureFixture[str],
) -> None:
    tracker = CommandTracker()
    tracker.sent(2, "land", ["uav3"], 0.0, valid_for_s=10.0)
    snap = tracker.snapshot(2, 4.0)
    assert snap is not None
    code, out = _follow_output(snap, capsys, timeout=0.0)
    assert code == 1
    assert "still valid for 6 s: it may yet run on uav3" in out


def test_pending_withdrawals_are_capped() -> None:
    """A script issuing commands with long validities cannot grow the commander's timers
    past the writer's history bound; the earliest is withdrawn at once instead."""
    swarm = Swarm(1)
    swarm.run(2.0)
    for _ in range(MAX_PENDING_WITHDRAWALS + 3):
        swarm.lead.request_command({"kind": "land", "valid_for_s": 600}, swarm.net.now)
    assert len(swarm.lead._expiries) == MAX_PENDING_WITHDRAWALS
