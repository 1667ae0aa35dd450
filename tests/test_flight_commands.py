"""Commands in the flight scenarios of the ns-3 testbed (issue 20, "Command authority in
flight"): the command script of every scenario against its ground truth, the journals a
member writes, and the measures on hand-made records (a command run twice, run late,
reported unreachable while reachable, or unreached and not reported is counted).

The real run (N = 5, split) is ``bench/results/flight-cmd/runs/``; it is not part of the
suite (ns-3 and 150 s of flight: docs/benchmarks.md, "Flight").
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from bench.wifi import flight, flight_commands, flight_report
from swarmd.swarm.commander import UNREACHABLE_GRACE_S


@pytest.mark.parametrize("name", list(flight.SCENARIOS))
def test_every_scenario_commands_after_discovery_and_settles_them_within_the_run(
    name: str,
) -> None:
    s = flight.make(name, 10, 1)
    assert s.commands, name
    assert s.commands[0].kind == "takeoff"
    for cue in s.commands:
        assert cue.kind in ("takeoff", "land", "hold", "abort")
        assert all(0 <= i < s.n for i in cue.only)
        assert cue.t >= flight.TAKEOFF_AT_S  # discovery (Tmin 8 s, Tmax 20 s) done by then
        # swarmctl's verdict (validity + the commander's grace) is in before the run ends
        assert cue.t + cue.valid_for_s + UNREACHABLE_GRACE_S < s.duration_s, cue


def _reach(s: flight.Scenario, cue: flight.CommandCue, member: int) -> str:
    down: dict[int, list[tuple[float, float]]] = {e.node: [] for e in s.events}
    for e in s.events:
        if e.action == "kill":
            down[e.node].append((e.t, s.duration_s))
        else:
            a, _ = down[e.node][-1]
            down[e.node][-1] = (a, e.t)
    return flight_commands.reach(s.truth(), down, member, cue.t, cue.t + cue.valid_for_s)


def test_the_split_script_holds_the_far_half_unreachable_then_reachable_after_the_heal() -> None:
    s = flight.make("split", 6)
    takeoff, during, late, land = s.commands
    assert {_reach(s, takeoff, m) for m in range(6)} == {"reachable"}
    assert [_reach(s, during, m) for m in range(6)] == ["reachable"] * 3 + ["unreachable"] * 3
    # the late hold's validity outlasts the heal: the far half is back inside it
    assert {_reach(s, late, m) for m in range(6)} == {"reachable"}
    assert {_reach(s, land, m) for m in range(6)} == {"reachable"}


def test_the_reboot_script_reaches_the_down_drone_only_after_its_restart() -> None:
    s = flight.make("reboot", 5)
    _, kept, lost, _ = s.commands
    node = 5 // 2
    assert kept.only == lost.only == (node,)
    assert _reach(s, kept, node) == "reachable"  # restarted 4 s into a 10 s validity
    assert _reach(s, lost, node) == "unreachable"  # expired before its restart


def test_the_blackout_script_holds_during_the_blackout_with_every_member_unreachable() -> None:
    s = flight.make("blackout", 4)
    hold = s.commands[2]
    assert [_reach(s, hold, m) for m in range(4)] == ["reachable"] + ["unreachable"] * 3


# -- the journals ----------------------------------------------------------------------------


def _line(event: str, second: float, **fields: Any) -> str:
    stamp = f"2026-11-26T10:00:{second:09.6f}Z"
    return json.dumps({"event": event, "timestamp": stamp, "level": "info", **fields})


def test_a_journal_over_two_daemon_lives_keeps_every_command_line(tmp_path: Path) -> None:
    log = tmp_path / "uav2.log"
    log.write_text(
        "start_barrier: waiting\n"
        + _line("peer_discovered", 1.0, peer="uav1") + "\n"
        + _line("command_received", 10.5, command_id=7, commander="uav1", kind="HOLD") + "\n"
        + '{"event": "command_received", "timestamp": "2026-11-\n'  # torn by SIGKILL
        + _line("daemon_started", 12.0) + "\n"
        + _line("command_received", 13.25, command_id=7, commander="uav1", kind="HOLD") + "\n"
        + _line("command_expired", 14.0, command_id=8, commander="uav1", kind="HOLD") + "\n"
    )  # fmt: skip
    lines = flight_commands.journal(log)
    assert [(r["event"], r["command_id"]) for r in lines] == [
        ("command_received", 7),
        ("command_received", 7),
        ("command_expired", 8),
    ]
    assert lines[1]["wall"] - lines[0]["wall"] == pytest.approx(2.75)


def test_collect_dates_each_command_from_the_commanders_sent_line(tmp_path: Path) -> None:
    names = ["uav1", "uav2", "uav3"]
    go = flight_commands.journal_wall("2026-11-26T10:00:00Z")
    commander = [
        _line("command_sent", 10.0, command_id=7, kind="HOLD"),
        _line("command_received", 10.001, command_id=7, commander="uav1", kind="HOLD"),
    ]
    member = [_line("command_received", 10.2, command_id=7, commander="uav1", kind="HOLD")]
    for name, lines in (("uav1", commander), ("uav2", member), ("uav3", [])):
        (tmp_path / f"{name}.log").write_text("\n".join(lines) + "\n")
    report = {
        "t": 9.9, "kind": "hold", "valid_for_s": 5.0, "only": [], "why": "", "exit_code": 1,
        "report": {"command_id": 7, "nodes": {
            "uav1": {"state": "completed"}, "uav2": {"state": "completed"},
            "uav3": {"state": "unreachable"},
        }},
    }  # fmt: skip
    journals = [flight_commands.journal(tmp_path / f"{n}.log") for n in names]
    (rec,) = flight_commands.collect([report], journals, names, go)
    assert rec["command_id"] == 7 and rec["issued_s"] == pytest.approx(10.0)
    assert rec["targets"] == [0, 1, 2]
    assert rec["reported"] == {"0": "completed", "1": "completed", "2": "unreachable"}
    assert rec["executed"] == {"0": [pytest.approx(10.001)], "1": [pytest.approx(10.2)]}


# -- the measures ----------------------------------------------------------------------------


def _truth(n: int, out: set[int], cut: tuple[float, float], end: float = 100.0) -> Any:
    """Everyone in range, except ``out`` cut from the others during ``cut``."""
    rows = []
    t = 0.0
    while t <= end:
        away = cut[0] <= t < cut[1]
        rows.append(
            (
                t,
                [
                    [i != j and not (away and ((i in out) != (j in out))) for j in range(n)]
                    for i in range(n)
                ],
            )
        )
        t += 0.5
    return rows


def _command(
    issued: float,
    valid: float,
    reported: dict[int, str],
    executed: dict[int, list[float]],
    cid: int = 1,
) -> dict[str, Any]:
    return {
        "command_id": cid,
        "issued_s": issued,
        "valid_for_s": valid,
        "targets": sorted(reported),
        "reported": {str(k): v for k, v in reported.items()},
        "executed": {str(k): v for k, v in executed.items()},
        "expired": {},
    }


def test_a_clean_split_command_counts_nothing_wrong() -> None:
    truth = _truth(4, {2, 3}, (20.0, 60.0))
    during = _command(
        30.0, 10.0, {0: "completed", 1: "completed", 2: "unreachable", 3: "unreachable"},
        {0: [30.001], 1: [30.2]},
    )  # fmt: skip
    m = flight_commands.measure([during], truth, {})
    assert m["reach"] == {"reachable": 2, "marginal": 0, "unreachable": 2}
    for key in (
        "executed_twice", "executed_late", "reported_unreachable_but_reachable",
        "unreached_not_reported", "reported_ran_not_executed", "reachable_not_executed",
    ):  # fmt: skip
        assert m[key] == 0, key
    assert m["delivery_latency_s"]["count"] == 2
    assert m["delivery_latency_s"]["max"] == pytest.approx(0.2)


def test_a_command_run_twice_is_counted() -> None:
    truth = _truth(3, set(), (0.0, 0.0))
    twice = _command(10.0, 5.0, {1: "completed", 2: "completed"}, {1: [10.1], 2: [10.1, 12.0]})
    m = flight_commands.measure([twice], truth, {})
    assert m["executed_twice"] == 1
    assert m["examples"]["twice"] == [[1, 2, [10.1, 12.0]]]
    assert m["executed_late"] == 0


def test_a_command_run_after_its_validity_is_counted() -> None:
    """The far side runs the split's hold when it comes back, long after its validity."""
    truth = _truth(4, {2, 3}, (20.0, 60.0))
    late = _command(
        30.0, 10.0, {1: "completed", 2: "unreachable", 3: "completed"},
        {1: [30.1], 3: [61.0]},
    )  # fmt: skip
    m = flight_commands.measure([late], truth, {})
    assert m["executed_late"] == 1
    assert m["examples"]["late"] == [[1, 3, [61.0], 40.0]]
    # and uav4 was unreachable throughout and swarmctl said it ran: not reported
    assert m["unreached_not_reported"] == 1
    # a run within the tolerance of a journal line's stamp is not late
    edge = _command(30.0, 10.0, {1: "completed"}, {1: [40.0 + 0.01]})
    assert flight_commands.measure([edge], truth, {})["executed_late"] == 0


def test_unreachable_reports_are_judged_against_the_ground_truth() -> None:
    truth = _truth(4, {2, 3}, (20.0, 60.0))
    wrong = _command(30.0, 10.0, {1: "unreachable", 2: "pending", 3: "completed"}, {})
    m = flight_commands.measure([wrong], truth, {})
    assert m["reported_unreachable_but_reachable"] == 1  # uav2 was in range
    assert m["reachable_not_executed"] == 1
    assert m["unreached_not_reported"] == 2  # uav3 left pending, uav4 claimed completed
    assert m["reported_ran_not_executed"] == 1  # uav4's "completed" has no journal line


def test_a_member_whose_daemon_is_down_is_unreachable_and_the_commander_reaches_itself() -> None:
    truth = _truth(3, set(), (0.0, 0.0))
    down = {2: [(40.0, 45.0)], 0: []}
    assert flight_commands.reach(truth, down, 2, 41.0, 44.0) == "unreachable"
    assert flight_commands.reach(truth, down, 2, 41.0, 51.0) == "reachable"  # back at 45
    assert flight_commands.reach(truth, down, 2, 41.0, 46.0) == "marginal"  # back 1 s only
    assert flight_commands.reach(truth, down, 0, 41.0, 51.0) == "reachable"
    m = flight_commands.measure([_command(41.0, 3.0, {2: "refused"}, {})], truth, down)
    assert m["unreached_not_reported"] == 0  # the commander refused it: the operator knew


def test_a_command_without_its_sent_line_is_counted_not_measured() -> None:
    truth = _truth(3, set(), (0.0, 0.0))
    c = _command(10.0, 5.0, {1: "completed"}, {1: [10.1]})
    c["issued_s"] = None
    m = flight_commands.measure([c], truth, {})
    assert m["not_issued"] == 1 and m["pairs"] == 0


def test_remeasure_and_the_command_table_read_the_run_file_alone() -> None:
    s = flight.make("split", 4)
    commands = [
        _command(45.0, 10.0, {0: "completed", 1: "completed", 2: "unreachable",
                              3: "unreachable"}, {0: [45.0], 1: [45.3], 3: [101.0]}),
    ]  # fmt: skip
    run: dict[str, Any] = {
        "scenario": "split", "n": 4, "seed": 1, "lease_s": 20.0, "run": 1,
        "contender": "swarmd", "changes": {}, "readiness": [], "down": {},
        "waypoints": [[t, i, *p] for t, i, p in s.waypoints], "events": [],
        "discovery_fps": [1] * int(s.duration_s), "commands": commands, "measures": {},
    }  # fmt: skip
    flight_commands.attach(run, commands, s)
    again = flight_report.remeasure(json.loads(json.dumps(run)))
    assert again["commands"] == run["measures"]["commands"]
    assert again["commands"]["executed_late"] == 1
    lines = flight_report.command_table([run, {"scenario": "split", "measures": {}}])
    assert len(lines) == 3
    assert lines[2].startswith("| split | swarmd | 4 | 1 | 1 (2 / 0 / 2) | 0 | 1 | 0 | 0 |")
    assert all(line.count("|") == lines[0].count("|") for line in lines)


def test_a_vehicle_log_gives_its_arms_and_mode_changes(tmp_path: Path) -> None:
    log = tmp_path / "uav3-vehicle.log"
    go = flight_commands.journal_wall("2026-11-26T10:00:00Z")
    log.write_text(
        _line("vehicle_sim_started", 0.5) + "\n"
        + _line("armed", 25.5, t=27.44) + "\n"
        + _line("mode", 25.6, old="AUTO.LOITER", new="AUTO.TAKEOFF") + "\n"
        + "not json\n"
        + _line("disarmed", 40.0, why="landing") + "\n"
    )  # fmt: skip
    events = flight_commands.vehicle_events(log, go)
    assert [e[1:] for e in events] == [
        ["armed", None],
        ["mode", "AUTO.TAKEOFF"],
        ["disarmed", None],
    ]
    assert events[0][0] == pytest.approx(25.5)


def test_a_member_that_restarted_while_the_command_was_valid_is_counted_apart() -> None:
    """The reboot scenario's hold: sent while uav3's daemon is down, valid past its restart.
    The new life is not handed the earlier life's copy (it may have run there) and swarmctl
    says ``unreachable``: by design, not a false report; a restart that is not followed by
    that report still counts."""
    truth = _truth(3, set(), (0.0, 0.0))
    down = {2: [(40.0, 45.0)]}
    hold = _command(41.0, 10.0, {2: "unreachable"}, {})
    assert flight_commands.reach(truth, down, 2, 41.0, 51.0) == "reachable"
    m = flight_commands.measure([hold], truth, down)
    assert m["restarted_not_resent"] == 1
    assert m["reported_unreachable_but_reachable"] == 0
    assert m["reachable_not_executed"] == 0
    # without the restart the same report is false
    m = flight_commands.measure([hold], truth, {})
    assert m["reported_unreachable_but_reachable"] == 1 and m["restarted_not_resent"] == 0


def test_a_member_out_of_range_by_the_truth_that_ran_in_time_was_reached() -> None:
    """The fading drone is in range 2.2 s of every 8 s: a hold can reach it in a window the
    truth's 0.5 s step does not show. Ran in time and reported completed: right; ran late
    is still counted (test above)."""
    truth = _truth(3, {2}, (20.0, 60.0))
    hold = _command(30.0, 10.0, {1: "completed", 2: "completed"}, {1: [30.1], 2: [33.0]})
    m = flight_commands.measure([hold], truth, {})
    assert m["unreached_not_reported"] == 0
    assert m["ran_while_truth_out_of_range"] == 1


def test_a_copy_refused_as_too_late_and_reported_rejected_is_reported() -> None:
    """The fade N = 10 r5 case: a HOLD reached the fading drone after its validity; the member
    refused it (its journal: ``command_expired``) and swarmctl said ``rejected``. The operator
    was told it did not run; a ``rejected`` with no late refusal on record is not that report."""
    truth = _truth(3, {2}, (20.0, 60.0))
    late = _command(30.0, 3.0, {2: "rejected"}, {})
    late["expired"] = {"2": [34.0]}
    assert flight_commands.measure([late], truth, {})["unreached_not_reported"] == 0
    unexplained = _command(30.0, 3.0, {2: "rejected"}, {})
    assert flight_commands.measure([unexplained], truth, {})["unreached_not_reported"] == 1
