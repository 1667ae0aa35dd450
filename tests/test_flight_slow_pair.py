"""``bench/flight_slow_pair.py`` on the fade at N = 20, run 2 (docs/flight-history.md,
"The fade's slow return at N = 20 (session 11)")."""

from __future__ import annotations

import json
from pathlib import Path

from bench.flight_slow_pair import co_losses, fine_crossings, main, report, slow_returns

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
