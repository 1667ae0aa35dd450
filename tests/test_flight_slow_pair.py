"""``bench/flight_slow_pair.py`` on the fade at N = 20, run 2 (docs/flight-history.md,
"The fade's slow return at N = 20 (session 11)"), and ``--parts`` on two cut fly-out runs
(tests/fixtures/flight/README.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.flight_slow_pair import (
    co_losses,
    fine_crossings,
    main,
    observed,
    report,
    slow_returns,
    stages,
)

RUN = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-stagger-c294800/runs/flight-fade-swarmd-n20-r2.json"
)


def test_the_one_slow_pair_is_uav16_finding_uav20_after_a_closed_window() -> None:
    run = json.loads(RUN.read_text())
    (row,) = slow_returns(run, 2.0)
    assert (row["observer"], row["peer"], row["back"], row["found"]) == (15, 19, 93.5, 101.148)
    assert round(row["in_range_s"], 3) == 1.148  # 93.5-94.5 and 101.0-101.148
    assert fine_crossings(run, 15, 19, 93.0, 102.0) == [93.5, 94.45, 100.65, 101.65]


def test_the_others_that_lost_uav20_with_it_found_it_before_uav16_s_window() -> None:
    run = json.loads(RUN.read_text())
    lost = co_losses(run, 19, 93.055)
    assert len(lost) == 7
    others = [found for observer, _, found in lost if observer != 15]
    assert all(found is not None and found < 93.5 for found in others)


def test_a_lower_bar_lists_more_and_a_missing_file_is_one_line(tmp_path: Path) -> None:
    assert report(RUN, 2.0).splitlines()[0].endswith("1 re-discoveries over 2 s by the clock")
    assert len(slow_returns(json.loads(RUN.read_text()), 0.05)) > 1
    assert main([str(tmp_path / "none.json")]) == 66


CUT = Path(__file__).resolve().parent / "fixtures" / "flight"
ROS2_CUT = CUT / "fly-out-ros2-swarmd-n20-r4-cut.json"
SWARMD_CUT = CUT / "fly-out-swarmd-n20-r4-cut.json"


def test_parts_split_the_slowest_ros2_pair_into_the_channel_and_what_came_after() -> None:
    # ROS 2 on swarmd's fly-out at N = 20, run 4: uav16 of uav1, 2.881 s
    run = json.loads(ROS2_CUT.read_text())
    row = next(r for r in stages(run, 2.0) if (r["observer"], r["peer"]) == (15, 0))
    assert (row["back"], row["found"]) == (92.5, 95.381)
    # each side decoded the other within 1.3 s of the return: 1.58 s came after
    assert (row["heard_ij"], row["heard_ji"], row["both"]) == (92.8, 93.8, 93.8)
    assert "not in the run file" in observed(run)
    assert "swarmd's own" in observed(json.loads(SWARMD_CUT.read_text()))


def test_parts_reports_each_run_its_slow_pairs_and_each_cell(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["--parts", str(ROS2_CUT), str(SWARMD_CUT)]) == 0
    out = capsys.readouterr().out.splitlines()
    slow = [line for line in out if " of uav" in line and "re-discovered" in line]
    # the cut's three observers' pairs over 2 s, all in the ROS 2 run
    assert [line.split(":")[0].strip() for line in slow] == [
        "uav1 of uav13",
        "uav13 of uav1",
        "uav16 of uav1",
    ]
    cells = [line for line in out if "all runs" in line]
    assert [line.split(",")[0] for line in cells] == [
        "ros2-swarmd fly-out N = 20",
        "swarmd fly-out N = 20",
    ]
    # every re-discovery of the cut counted, in both
    assert all(" 49 re-discoveries" in line for line in cells)


def test_parts_read_swarmds_own_re_discovery_where_the_run_has_it() -> None:
    # runs flown after this change record swarmd's peer changes under the graph's
    # (flight_run.swarmd_under); here one made up for uav16's pair
    run = json.loads(ROS2_CUT.read_text())
    run["swarmd_changes"] = {"15": [[57.9, 0, "lost"], [94.9, 0, "regained"]]}
    rows = stages(run, 2.0)
    row = next(r for r in rows if (r["observer"], r["peer"]) == (15, 0))
    assert row["swarmd_found"] == 94.9
    assert all(r["swarmd_found"] is None for r in rows if r["observer"] != 15)
    assert "under it" in observed(run)
