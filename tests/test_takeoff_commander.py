"""The commander's bookkeeping and the node state file, on hand-set time (no I/O but files)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from swarmd.dataplane.types import CommandResult, Readiness
from swarmd.statefile import boot, load, state_path
from swarmd.swarm.commander import (
    MAX_TRACKED_COMMANDS,
    NO_REPORT,
    NOT_A_MEMBER,
    PEER_LOST,
    REPORT_STALE,
    CommandTracker,
    ReadinessTable,
)


def sample(node: str, seq: int, ready: bool, reason: str = "", landed: int = 1) -> Readiness:
    return Readiness(node, seq, ready, reason, False, landed, 3, 12, 80, 750)


def test_effective_readiness_order_no_report_lost_stale_then_own_reason() -> None:
    table = ReadinessTable(["a", "b"], stale_after_s=3.0)
    assert table.verdict("a", 0.0) == (False, NO_REPORT)
    table.on_report("a", sample("a", 1, True), 1, now=1.0)
    assert table.verdict("a", 1.0) == (False, PEER_LOST)  # heard, but discovery says gone
    table.on_peer("a", True)
    assert table.verdict("a", 1.0) == (True, None)
    assert table.verdict("a", 4.0) == (True, None)  # exactly at the bound: still fresh
    assert table.verdict("a", 4.01) == (False, REPORT_STALE)
    table.on_report("a", sample("a", 2, False, "no_3d_fix"), 2, now=5.0)
    assert table.verdict("a", 5.0) == (False, "no_3d_fix")
    assert table.verdict("zzz", 5.0) == (False, NOT_A_MEMBER)
    ready, refused = table.split(["b", "a"], 5.0)
    assert ready == [] and list(refused.items()) == [("b", NO_REPORT), ("a", "no_3d_fix")]


def test_rows_carry_count_age_and_change_time() -> None:
    table = ReadinessTable(["a"], stale_after_s=3.0)
    table.on_peer("a", True)
    table.on_report("a", sample("a", 1, False, "no_home"), 1, now=10.0)
    table.on_report("a", sample("a", 2, False, "no_home"), 2, now=11.0)
    table.on_report("a", sample("a", 3, True, landed=2), 3, now=12.0)
    row = table.rows(12.5)["a"]
    assert row["count"] == 3 and row["seq"] == 3 and row["ready"]
    assert row["age_s"] == 0.5 and row["since_s"] == 0.5  # changed at 12.0, not at 10.0
    assert row["landed_state"] == "IN_AIR" and row["battery_pct"] == 80 and row["link_q"] == 0.75


def test_local_row_counts_itself_and_is_always_up() -> None:
    table = ReadinessTable(["m"], stale_after_s=3.0)
    table.add_local("lead")
    table.on_report("lead", sample("lead", 1, True), None, now=1.0)
    table.on_report("lead", sample("lead", 2, True), None, now=2.0)
    table.on_peer("lead", False)  # discovery never reports ourselves; ignored anyway
    assert table.rows(2.0)["lead"]["count"] == 2 and table.verdict("lead", 2.0) == (True, None)
    assert table.names == ["m", "lead"]


def test_tracker_outcomes_accepted_then_final_once() -> None:
    tracker = CommandTracker()
    tracker.sent(7, "takeoff", ["a", "b"], 100.0, altitude_m=5.0, refused={"c": "no_home"})
    assert tracker.record(7, "a", CommandResult.ACCEPTED, "", 100.01)
    assert tracker.record(7, "a", CommandResult.COMPLETED, "IN_AIR", 101.0)
    assert tracker.record(7, "a", CommandResult.FAILED, "late", 102.0)  # a final is final
    assert not tracker.record(7, "x", CommandResult.ACCEPTED, "", 100.0)
    assert not tracker.record(8, "a", CommandResult.ACCEPTED, "", 100.0)
    snap = tracker.snapshot(7, 103.0)
    assert snap is not None and not snap["done"]
    assert snap["nodes"]["a"] == {
        "state": "completed",
        "reason": "IN_AIR",
        "latency_s": 0.01,
        "done_s": 1.0,
        "after_restart": False,
        "save_failed": False,
        "disarm_unconfirmed": False,
    }
    assert snap["nodes"]["b"]["state"] == "pending"
    assert snap["nodes"]["c"] == {
        "state": "refused",
        "reason": "no_home",
        "latency_s": None,
        "done_s": None,
        "after_restart": False,
        "save_failed": False,
        "disarm_unconfirmed": False,
    }
    tracker.record(7, "b", CommandResult.REJECTED, "armed", 100.5)
    done = tracker.snapshot(7, 103.0)
    assert done is not None and done["done"] and done["nodes"]["b"]["state"] == "rejected"
    assert tracker.unknown_outcomes == 2


def test_tracker_keeps_the_latest_commands_only() -> None:
    tracker = CommandTracker()
    for i in range(MAX_TRACKED_COMMANDS + 5):
        tracker.sent(i, "hold", ["a"], float(i))
    assert tracker.evicted == 5 and tracker.snapshot(0, 0.0) is None
    assert [c["command_id"] for c in tracker.recent(0.0, limit=2)] == [
        MAX_TRACKED_COMMANDS + 3,
        MAX_TRACKED_COMMANDS + 4,
    ]


@given(
    st.lists(
        st.tuples(st.sampled_from(["a", "b"]), st.sampled_from(list(CommandResult))), max_size=20
    )
)
def test_tracker_first_final_result_wins(events: list[tuple[str, CommandResult]]) -> None:
    tracker = CommandTracker()
    tracker.sent(1, "takeoff", ["a", "b"], 0.0)
    for node, result in events:
        tracker.record(1, node, result, result.name, 1.0)
    snap = tracker.snapshot(1, 2.0)
    assert snap is not None
    for node in ("a", "b"):
        finals = [r for n, r in events if n == node and r != CommandResult.ACCEPTED]
        expected = finals[0].name.lower() if finals else None
        state = snap["nodes"][node]["state"]
        assert state == expected or (expected is None and state in ("pending", "accepted"))


def test_state_file_counts_boots_and_keeps_executed_ids(tmp_path: Path) -> None:
    first = boot(tmp_path / "state", "uav 2/x")
    assert first.boot == 1 and first.executed == [] and first.recovered_from is None
    assert first.path.name == "dataplane-uav_2_x.json"
    first.executed = [("lead", 1 << 32 | 1)]
    first.save()
    second = boot(tmp_path / "state", "uav 2/x")
    assert second.boot == 2 and second.executed == [("lead", 1 << 32 | 1)]
    assert json.loads(second.path.read_text()) == {"boot": 2, "executed": [["lead", 4294967297]]}
    assert not list((tmp_path / "state").glob("*.tmp"))


@pytest.mark.parametrize(
    "content", ["", "{", '{"boot": -1, "executed": []}', '{"boot": 1}', "[1, 2]"]
)
def test_corrupt_state_file_is_replaced_and_reported(tmp_path: Path, content: str) -> None:
    path = state_path(tmp_path, "uav1")
    path.write_text(content)
    assert load(path).recovered_from is not None
    again = boot(tmp_path, "uav1")
    assert again.boot == 1 and again.recovered_from is not None
    assert load(path).recovered_from is None  # rewritten cleanly
