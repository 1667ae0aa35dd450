"""bench/wifi/report.py: which runs reach the main table and how swarmd is paired."""

from __future__ import annotations

from typing import Any

from bench.wifi import report


def _row(contender: str, n: int, k: float, valid_runs: int) -> dict[str, Any]:
    return {"contender": contender, "n": n, "k": k, "valid_runs": valid_runs}


def _run(
    contender: str,
    n: int,
    k: float,
    run: int,
    peak: int,
    *,
    valid: bool = True,
    commit: str = "abc",
) -> dict[str, Any]:
    return {
        "contender": contender,
        "n": n,
        "run": run,
        "valid": valid,
        "peak_pps": peak,
        "setup": {"dilation": k, "commit": commit},
    }


def test_main_k_is_the_k_with_most_valid_runs_ties_to_the_larger() -> None:
    ks = report.main_k(
        [
            _row("fastdds", 5, 1.0, 3),  # the undilated repeats
            _row("fastdds", 5, 3.0, 1),  # the method's check beside them
            _row("fastdds", 20, 4.0, 0),  # lagged: never main
            _row("fastdds", 20, 6.0, 2),
            _row("zenoh", 10, 2.0, 1),
            _row("zenoh", 10, 3.0, 1),
            _row("cyclonedds", 20, 4.0, 0),
            _row("cyclonedds", 20, 6.0, 0),
        ]
    )
    assert ks[("fastdds", 5)] == 1.0
    assert ks[("fastdds", 20)] == 6.0
    assert ks[("zenoh", 10)] == 3.0
    assert ks[("cyclonedds", 20)] == 6.0  # nothing valid: the largest k, shown as 0/N


def test_pairs_only_valid_runs_of_the_same_repeat_and_k() -> None:
    runs = [
        _run("swarmd", 10, 3.0, 1, 40),
        _run("fastdds", 10, 3.0, 1, 800),
        _run("swarmd", 10, 3.0, 2, 50),
        _run("fastdds", 10, 3.0, 2, 1000, valid=False),  # lagged: no pair
        _run("fastdds", 10, 6.0, 3, 900),  # another k: no pair
        _run("swarmd", 10, 3.0, 3, 45),
    ]
    assert report.paired_ratios(runs, "fastdds", "peak_pps") == {(10, 3.0): [0.05]}
    both = report.paired_ratios(runs, "fastdds", "peak_pps", include_invalid=True)
    assert both == {(10, 3.0): [0.05, 0.05]}


def test_runs_of_different_code_never_pair() -> None:
    runs = [
        _run("swarmd", 20, 6.0, 1, 60, commit="today"),
        _run("zenoh", 20, 6.0, 1, 10000, commit="yesterday"),  # kept from an earlier campaign
        _run("cyclonedds", 20, 6.0, 1, 6000, commit="today"),
    ]
    assert report.paired_ratios(runs, "zenoh", "peak_pps") == {}
    assert report.paired_ratios(runs, "cyclonedds", "peak_pps") == {(20, 6.0): [0.01]}
