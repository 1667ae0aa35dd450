"""Readiness delivery (``flight_measures.readiness_delivery``) on synthetic records shaped
like the three observers' tables (docs/flight-history.md, "ROS 2 on swarmd's readiness
(session 9)"): every span of a member in the commander's range counts, whether the
commander's table lists the member before its first sample (swarmd) or only from it (the
stock stacks' and ROS 2's tallies), whether the commander found the member before its first
poll, and whether the commander's graph listed the member before its stack was released.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from bench.wifi import flight_measures
from bench.wifi.flight_measures import Change

END = 100.0


def _all_in_range(n: int = 3, end: float = END) -> flight_measures.Truth:
    rows = []
    t = 0.0
    while t <= end:
        rows.append((t, [[i != j for j in range(n)] for i in range(n)]))
        t += 0.5
    return rows


def _found(at: Mapping[int, float]) -> dict[int, list[Change]]:
    return {0: [(t, m, "discovered") for m, t in sorted(at.items())]}


def _polls(
    count: Callable[[int, float], int | None], every_s: float = 1.0, first_s: float = 0.0
) -> list[tuple[float, dict[int, int]]]:
    """The commander's table every ``every_s``; ``count`` None: the member not listed."""
    out = []
    t = first_s
    while t <= END:
        table = {m: c for m in (1, 2) if (c := count(m, t)) is not None}
        out.append((t, table))
        t += every_s
    return out


def _delivery(
    polls: list[tuple[float, dict[int, int]]],
    found: Mapping[int, float],
    started: tuple[float, ...] = (),
) -> dict[str, object]:
    truth = _all_in_range()
    changes, end = _found(found), truth[-1][0]
    if started:  # the argument is new in session 9: without it the calls read as before
        return flight_measures.readiness_delivery(truth, {}, changes, polls, 3, end, started)
    return flight_measures.readiness_delivery(truth, {}, changes, polls, 3, end)


def test_a_member_listed_only_from_its_first_sample_is_counted_from_its_discovery() -> None:
    """The stock tallies (bench/wifi/peers/common.py) list a member once a sample of it
    arrived. uav3's first 10 s after its discovery at 5 s are lost (matching), uav2 loses
    nothing: the 10 missing samples must show. Before, uav3's only span was dropped (no
    count at its start) and uav2's 94 s of 1 Hz alone gave 100 %."""

    def count(m: int, t: float) -> int | None:
        if t < 5.0:
            return None
        if m == 1:
            return int(t - 5.0)
        return None if t < 15.0 else int(t - 15.0)

    r = _delivery(_polls(count), {1: 5.0, 2: 5.0})
    assert r["expected"] == 2 * 95
    assert r["delivered"] == 95 + 85
    assert r["ratio"] == round(180 / 190, 4)


def test_a_member_found_before_the_first_poll_is_counted_from_that_poll() -> None:
    """swarmd's table lists every member from the start, but the harness's first poll may
    come after the commander found a member (swarmd alone, split at N = 10: 3 of 9 members'
    first spans dropped whole). What arrived before the first poll is not known: count from
    it. uav3 loses its samples 40-50 s: that must show."""

    def count(m: int, t: float) -> int:
        got = int(t - 4.0)
        return got if m == 1 or t < 40.0 else got - min(10, int(t - 40.0))

    r = _delivery(_polls(count, first_s=4.5), {1: 4.0, 2: 4.2})
    # from the first poll (4.5 s) to the last (99.5 s): 95 s each
    assert r["expected"] == 2 * 95
    assert r["delivered"] == 95 + 85


def test_nothing_is_expected_of_a_member_before_its_stack_is_released() -> None:
    """On the relay route the commander's graph lists every node the bundle declares once
    its swarmd found the drone: uav3 is listed at 1 s but its node is released at 6 s
    (``setup.started_s``) and sends from 6 s on. Nothing could be sent before 6 s."""

    def count(m: int, t: float) -> int | None:
        if m == 1:
            return int(t - 1.0) if t >= 1.0 else None
        return int(t - 6.0) if t >= 6.0 else None

    polls = _polls(count)
    assert _delivery(polls, {1: 1.0, 2: 1.0}, started=(0.0, 0.0, 6.0))["ratio"] == 1.0
    unstaggered = _delivery(polls, {1: 1.0, 2: 1.0})
    assert unstaggered["expected"] == 2 * 99 and unstaggered["delivered"] == 99 + 94


def test_a_member_never_heard_is_all_missing_not_left_out() -> None:
    """A member the commander found but never received from (the stock tallies: never
    listed) is 0 %, not a member without a measure."""

    def count(m: int, t: float) -> int | None:
        return int(t) if m == 1 else None

    r = _delivery(_polls(count), {1: 0.0, 2: 0.0})
    assert r["expected"] == 2 * 100 and r["delivered"] == 100
