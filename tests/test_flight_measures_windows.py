"""``flight_measures.measure``'s re-discovery when the return's window closes first
(docs/flight-history.md, "The fade's slow return at N = 20 (session 11)"): the fading drone
came back into a peer's range for about a second, left again for six, and was re-discovered
in the next window; the seconds out of range are not the protocol's to spend, so the
re-discovery latency counts the time in range from the return on, and the windows that
closed first are counted beside it."""

from __future__ import annotations

from typing import Any

from bench.wifi import flight_measures

STEP_S = 0.5
LEASE_S = 20.0


def _truth(
    windows: list[tuple[float, float]], end: float = 60.0
) -> list[tuple[float, list[list[bool]]]]:
    """Two drones in range outside [20, end) and inside each ``[a, b)`` of ``windows``."""
    out = []
    for k in range(int(end / STEP_S) + 1):
        t = k * STEP_S
        near = t < 20.0 or any(a <= t < b for a, b in windows)
        out.append((t, [[False, near], [near, False]]))
    return out


def _measure(windows: list[tuple[float, float]], lost: float, found: float) -> dict[str, Any]:
    changes = {0: [(1.0, 1, "discovered"), (lost, 1, "lost"), (found, 1, "regained")]}
    return flight_measures.measure(_truth(windows), changes, {}, n=2, lease_s=LEASE_S)


def test_a_return_whose_window_closed_counts_only_the_time_in_range() -> None:
    """Back at 28 s for 1 s, out 29-35.5 s, found at 36 s: 1 s + 0.5 s in range (8 s by
    the clock), and one window closed before the re-discovery."""
    m = _measure([(28.0, 29.0), (35.5, 60.0)], lost=27.5, found=36.0)
    assert m["rediscovery_s"]["max"] == 1.5 and m["rediscovery_s"]["count"] == 1
    assert m["rediscovery_wall_s"]["max"] == 8.0
    assert m["rediscovery_windows_closed"] == 1
    assert m["not_rediscovered"] == 0


def test_a_long_window_missed_still_counts_whole() -> None:
    """Back at 28 s for 3 s with nothing found in it: the 3 s in range count, so the
    re-discovery is slow (over 2 s) however soon it came in the next window."""
    m = _measure([(28.0, 31.0), (35.5, 60.0)], lost=27.5, found=35.6)
    assert m["rediscovery_s"]["max"] == 3.1
    assert m["rediscovery_windows_closed"] == 1


def test_a_rediscovery_inside_the_first_window_is_the_clock_time() -> None:
    m = _measure([(28.0, 60.0)], lost=27.5, found=29.5)
    assert m["rediscovery_s"]["max"] == 1.5 and m["rediscovery_wall_s"]["max"] == 1.5
    assert m["rediscovery_windows_closed"] == 0


def test_a_rediscovery_dated_just_before_the_sample_is_zero() -> None:
    """The stacks' times are dated by a poll: up to the truth's step before the return's
    sample counts as 0, as before."""
    m = _measure([(28.0, 60.0)], lost=27.0, found=27.8)
    assert m["rediscovery_s"]["max"] == 0.0 and m["rediscovery_windows_closed"] == 0


def test_a_pair_listed_again_just_before_the_truths_return_took_no_time() -> None:
    """Lost at 27.5 s, listed again at 33.8 s, the truth's return at 35.5 s: a frame got
    through at the range's edge first. The pair is listed at the return: 0 s, counted
    apart, not "never re-discovered" (session 13's split at N = 20, run 2: 9 such pairs)."""
    m = _measure([(35.5, 60.0)], lost=27.5, found=33.8)
    assert m["not_rediscovered"] == 0
    assert m["rediscovered_before_return"] == 1
    assert m["rediscovery_s"]["count"] == 1 and m["rediscovery_s"]["max"] == 0.0


def test_a_pair_listed_early_but_lost_again_before_the_return_counts_from_its_next_find() -> None:
    changes = {
        0: [
            (1.0, 1, "discovered"), (27.5, 1, "lost"), (31.0, 1, "regained"),
            (33.0, 1, "lost"), (37.0, 1, "regained"),
        ]
    }  # fmt: skip
    m = flight_measures.measure(_truth([(35.5, 60.0)]), changes, {}, n=2, lease_s=LEASE_S)
    assert m["rediscovered_before_return"] == 0
    assert m["rediscovery_s"]["max"] == 1.5 and m["not_rediscovered"] == 0


def test_a_pair_never_listed_again_is_still_never_rediscovered() -> None:
    changes = {0: [(1.0, 1, "discovered"), (27.5, 1, "lost")]}
    m = flight_measures.measure(_truth([(35.5, 60.0)]), changes, {}, n=2, lease_s=LEASE_S)
    assert m["not_rediscovered"] == 1 and m["rediscovered_before_return"] == 0
