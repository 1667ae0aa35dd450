"""Every contender against swarmd's targets, side by side (issue 20: "the targets judged
from the runs"; ``flight_verdicts.standings``, the block's first table), from synthetic run
records: the tallies per target, the costs' medians over cells with the runs they stand on,
and their ratio to swarmd's."""

from __future__ import annotations

from pathlib import Path

from bench.wifi import flight_matrix as fm
from bench.wifi import flight_verdicts as fv
from tests.test_flight_report_matrix import files, record


def standing(runs: list[fm.RunFile], contender: str, n: int = 10) -> fv.Standing:
    (st,) = [st for st in fv.standings(runs) if st.contender == contender and st.n == n]
    return st


def tally(st: fv.Standing, target: str) -> tuple[int, int, int]:
    t = st.tallies[fv.YARDSTICK.index(target)]
    return (t.met, t.not_met, t.not_known)


def row(runs: list[fm.RunFile], title: str, n: int = 10) -> list[str]:
    """The N table's row of the contender titled ``title``, cut into its cells."""
    lines = fv.standing_lines(fv.standings(runs))
    start = lines.index(f"**N = {n}**:")
    (line,) = [x for x in lines[start:] if x.startswith(f"| {title} |")][:1]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_every_contender_is_judged_per_target_not_only_swarmd() -> None:
    runs = files(
        *(record("split", run=k, red_max=1.0) for k in (1, 2, 3)),
        record("split", "cyclonedds", red_max=5.0, per_pair=120.0, ratio=0.97),
    )
    cyc = standing(runs, "cyclonedds")
    # split judged, the four other scenarios not run: not known, never "met"
    assert tally(cyc, "rediscovery") == (0, 1, 4)
    assert tally(cyc, "frames") == (0, 1, 2)  # the three heals only
    assert tally(cyc, "readiness") == (0, 1, 4)
    assert tally(cyc, "false") == (1, 0, 4)
    assert tally(standing(runs, "swarmd"), "rediscovery") == (1, 0, 4)
    # a contender with no run at all is not known everywhere
    assert tally(standing(runs, "zenoh"), "readiness") == (0, 0, 5)


def test_a_cell_is_met_only_when_every_valid_run_is_for_a_stock_stack_too() -> None:
    runs = files(
        record("split", "zenoh", run=1, red_max=1.0),
        record("split", "zenoh", run=2, red_max=2.5),
        record("blackout", "zenoh", run=1, red_max=9.0, valid=False),  # enters nothing
    )
    st = standing(runs, "zenoh")
    assert tally(st, "rediscovery") == (0, 1, 4)
    assert st.costs[0].cells == {"split": 1.75}
    assert st.costs[0].runs == 2


def test_costs_are_medians_over_cells_with_their_runs_and_ratio_to_swarmd() -> None:
    runs = files(
        *(record("split", run=k, red_max=v) for k, v in ((1, 1.0), (2, 2.0), (3, 3.0))),
        *(record("blackout", run=k, red_max=1.0) for k in (1, 2, 3)),
        record("split", "zenoh", red_max=6.0),
        record("blackout", "zenoh", red_max=3.0),
    )
    ours, theirs = standing(runs, "swarmd").costs[0], standing(runs, "zenoh").costs[0]
    assert ours.median() == 1.5 and ours.runs == 6
    assert theirs.median() == 4.5 and theirs.runs == 2
    assert fv.ratio(theirs, ours) == 3.0
    # one run per stock cell against three of swarmd's: the row says so
    assert row(runs, "zenoh")[6:8] == ["4.50 s (2 cells, 2 runs)", "3.0×"]
    assert row(runs, "swarmd")[6:8] == ["1.50 s (2 cells, 6 runs)", "1.0×"]


def test_the_ratio_compares_the_cells_both_have() -> None:
    runs = files(
        record("split", red_max=1.0),
        record("split", "fastdds", red_max=2.0),
        record("fly-out", "fastdds", red_max=50.0),  # swarmd has no fly-out run: not compared
    )
    theirs, ours = standing(runs, "fastdds").costs[0], standing(runs, "swarmd").costs[0]
    assert theirs.median() == 26.0
    assert fv.ratio(theirs, ours) == 2.0


def test_pairs_never_found_again_make_the_median_never_and_are_counted() -> None:
    runs = files(
        record("split", red_max=1.0),
        record("blackout", red_max=1.0),
        record("split", "ros2", red_p50=None, red_max=None, never=50),
        record("blackout", "ros2", red_p50=None, red_max=None, never=18),
    )
    cells = row(runs, "ROS 2")
    assert cells[6:8] == ["never (2 cells, 2 runs; 2 never)", "never"]


def test_frames_cost_only_the_heals_and_a_contender_without_runs_reads_dash() -> None:
    runs = files(
        record("split", per_pair=2.0),
        record("split", "cyclonedds", per_pair=100.0),
        record("fade", "cyclonedds", per_pair=1600.0),  # the whole fade's window: not a heal
    )
    assert row(runs, "Cyclone DDS")[8:10] == ["100.00 (1 cell, 1 run)", "50×"]
    assert row(runs, "Discovery Server")[6:10] == ["-", "-", "-", "-"]


def test_the_block_opens_with_the_side_by_side_and_says_the_targets_are_swarmds() -> None:
    text = fm.block(
        files(record(), record(contender="zenoh")),
        command="cmd", docs_dir=Path("/nowhere"), counts=None, since=None,
    )  # fmt: skip
    side = text.index("### Every contender against swarmd's targets, side by side")
    assert side < text.index("### The matrix, from the run files")
    header = text[side:].split("\n\n")[1]
    assert "the stock stacks were not built for them" in header
    assert "\n" not in header  # one line
    for _, title in fm.COLUMNS:
        assert f"\n| {title} | " in text[side : text.index("### Which code")]
