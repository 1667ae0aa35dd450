"""The flight matrix's command and renewal tables and targets (issue 20: "Command authority
in flight", "the renewal/vouch rate following the link quality"), from synthetic run
records (``bench/wifi/flight_cells.py``, ``bench/wifi/flight_verdicts.py``)."""

from __future__ import annotations

from typing import Any

import pytest

from bench.wifi import flight_matrix as fm
from bench.wifi import flight_measures
from swarmd.discovery.config import EngineConfig
from tests.test_flight_report_matrix import files, record

CLEAN: dict[str, Any] = {
    "commands": 4,
    "not_issued": 0,
    "pairs": 40,
    "executed_twice": 0,
    "executed_late": 0,
    "reported_unreachable_but_reachable": 0,
    "unreached_not_reported": 0,
    "reported_ran_not_executed": 0,
    "reachable_not_executed": 0,
    "restarted_not_resent": 0,
}


def with_commands(run: dict[str, Any], **counts: int) -> dict[str, Any]:
    run["measures"]["commands"] = {**CLEAN, **counts}
    return run


def with_follows(run: dict[str, Any], follows: dict[str, Any]) -> dict[str, Any]:
    run["measures"]["renewal_follows_q"] = follows
    return run


def daemon(
    q: tuple[float, float], r: float | None, period: tuple[float, float] = (5.0, 9.0)
) -> dict[str, Any]:
    """One daemon's entry of ``renewal_follows_q``."""
    return {"q": list(q), "renewal_period_s": list(period), "corr_q_period": r}


def verdict(runs: list[fm.RunFile], target: str, contender: str = "swarmd") -> fm.Verdict:
    (v,) = [
        v
        for v in fm.verdicts(runs)
        if v.target == target and v.scenario == "split" and v.n == 10 and v.contender == contender
    ]
    return v


def table(runs: list[fm.RunFile], title: str) -> dict[str, list[str]]:
    """The N = 10 table whose title starts with ``title``: its cells per scenario."""
    lines = fm.tables(runs, 10)
    start = next(k for k, line in enumerate(lines) if line.startswith(f"**{title}"))
    rows = lines[start + 4 : start + 4 + len(fm.SCENARIOS)]
    return {row.split(" | ")[0].lstrip("| "): row.strip("| ").split(" | ")[1:] for row in rows}


# -- commands ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "fault",
    [
        "executed_twice",
        "executed_late",
        "unreached_not_reported",
        "reported_unreachable_but_reachable",
    ],
)
def test_a_command_run_twice_late_or_misreported_fails_the_target(fault: str) -> None:
    v = verdict(files(with_commands(record(), **{fault: 1})), "commands")
    assert v.met is False
    assert "**not met**" in v.text
    assert "0 of 1 valid run with none: 1" in v.text


def test_a_clean_command_run_meets_the_target_and_a_voided_copy_is_counted_apart() -> None:
    v = verdict(files(with_commands(record(), restarted_not_resent=2)), "commands")
    assert v.met is True
    assert "**met**, 1 of 1 valid run with none: 0; 4 commands, 40 pairs: twice 0" in v.text
    assert "voided by a restart 2" in v.text


def test_a_run_without_command_measures_is_not_known() -> None:
    v = verdict(files(record()), "commands")
    assert v.met is None
    assert "not measured in 1 valid run" in v.text


def test_one_bad_valid_run_fails_the_cell_an_invalid_one_does_not() -> None:
    ok = with_commands(record(run=1))
    bad = with_commands(record(run=2), executed_twice=1)
    assert verdict(files(ok, bad), "commands").met is False
    bad_invalid = with_commands(record(run=2, valid=False), executed_twice=1)
    assert verdict(files(ok, bad_invalid), "commands").met is True


def test_the_commands_table_sums_valid_runs_and_shows_a_dash_without_commands() -> None:
    runs = files(
        with_commands(record(run=1), executed_late=1),
        with_commands(record(run=2), reachable_not_executed=3),
        with_commands(record(run=3, valid=False), executed_twice=9),
        record(contender="cyclonedds"),  # a stock stack: no command path
    )
    cells = table(runs, "commands")
    assert cells["split"][0] == "8 / 80 / 0 / 1 / 0 / 0; 3 reachable, not run"
    assert cells["split"][1] == "-"
    assert cells["fade"][0] == "not run"


def test_ros2_on_swarmd_is_judged_only_where_its_runs_carry_commands() -> None:
    bare = files(record(), record(contender="ros2-swarmd"))
    assert not [v for v in fm.verdicts(bare) if v.contender == "ros2-swarmd"]
    carried = files(record(), with_commands(record(contender="ros2-swarmd"), executed_twice=1))
    v = verdict(carried, "commands", "ros2-swarmd")
    assert v.met is False
    assert v.text.startswith("ROS 2 on swarmd, N=10, split: **not met**")
    assert all(v.contender != "cyclonedds" for v in fm.verdicts(carried))


# -- the renewal period following Q -----------------------------------------------------------


def test_the_period_following_a_q_that_moved_meets_the_target() -> None:
    # measured as the harness does: Q rose 0.0 -> 0.8 and the period rose with it
    polls = [[float(t), 0, t, 0.2 * t, 5.0 + t, 20.0] for t in range(5)]
    polls += [[float(t), 1, t, 0.5 + 0.01 * (t % 2), 6.7, 20.0] for t in range(5)]
    follows = flight_measures.renewal_follows_q(polls)
    v = verdict(files(with_follows(record(), follows)), "renewal")
    assert v.met is True
    assert "1 of 1 daemons with Q moved ≥ 0.2 at r > 0, r 1.00" in v.text
    assert "1 with Q moved less (≤ 0.01) not judged" in v.text
    assert table(files(with_follows(record(), follows)), "renewal period")["split"][0] == (
        "r 1.00, 1 of 2"
    )


@pytest.mark.parametrize(
    ("entry", "met"),
    [
        (daemon((0.0, 0.8), 0.3), True),
        (daemon((0.0, 0.8), -0.3), False),  # the period moved against Q
        (daemon((0.0, 0.8), None, period=(5.0, 5.0)), False),  # Q moved, the period did not
        (daemon((0.3, 0.5), -0.1), False),  # exactly two steps: judged
    ],
)
def test_the_period_must_move_with_q_where_q_moved(entry: dict[str, Any], met: bool) -> None:
    v = verdict(files(with_follows(record(), {"0": entry})), "renewal")
    assert v.met is met


def test_a_q_that_did_not_move_is_not_known_and_shown_so() -> None:
    still = {"0": daemon((0.5, 0.6), -0.9), "1": daemon((0.4, 0.45), None, period=(6.0, 6.0))}
    runs = files(with_follows(record(), still))
    v = verdict(runs, "renewal")
    assert v.met is None
    assert "Q moved by less than 0.2 at each of the 2 daemons polled" in v.text
    assert "(at most 0.10)" in v.text
    assert table(runs, "renewal period")["split"][0] == "Q did not move (≤ 0.10)"


def test_a_stack_without_renewal_polls_shows_a_dash_and_is_not_judged() -> None:
    runs = files(with_follows(record(contender="cyclonedds"), {}), record())
    assert table(runs, "renewal period")["split"][1] == "-"
    assert verdict(runs, "renewal").text.endswith("not measured in 1 valid run")


def test_q_moved_is_two_of_the_engines_hysteresis_steps() -> None:
    """The threshold is derived from the engine's ``link_report_step``: if that changes,
    so must the judgement (flight_measures.Q_MOVED_MIN)."""
    assert flight_measures.Q_MOVED_MIN == pytest.approx(2 * EngineConfig().link_report_step)
