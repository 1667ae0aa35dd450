"""bench/wifi/metrics.py: the validity rule both the 802.11 bench and the flight runs apply."""

from __future__ import annotations

import math

from bench.wifi import metrics


def test_a_run_whose_lag_p99_passes_the_bound_is_invalid_and_says_by_how_much() -> None:
    assert metrics.lag_validity({"rt_lag_p99_ms": 50.0}, 20.0) == {
        "valid": False,
        "invalid_reason": "real-time lag p99 50.0 ms > 20.0 ms",
    }


def test_a_run_at_the_bound_or_without_lag_samples_is_valid() -> None:
    for p99 in (20.0, 3.5, math.nan):
        assert metrics.lag_validity({"rt_lag_p99_ms": p99}, 20.0) == {
            "valid": True,
            "invalid_reason": None,
        }
