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
from bench.wifi.flight_measures import Change, Timeline

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
    return flight_measures.readiness_delivery(Timeline(truth, {}, changes, polls, 3, end, started))


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


def _leaves_at(leave_s: float, n: int = 3, end: float = END) -> flight_measures.Truth:
    """Every drone in range of every other until ``leave_s``, the commander out of every
    member's range after it (the blackout's shape, without the return)."""
    rows = []
    t = 0.0
    while t <= end:
        near = t <= leave_s
        rows.append((t, [[i != j and near for j in range(n)] for i in range(n)]))
        t += 0.5
    return rows


def test_a_span_ending_between_two_polls_is_not_charged_for_the_samples_after_the_last() -> None:
    """A perfect 1 Hz stream (none lost) read by a commander polled once a second (the
    stock tallies) or every 0.25 s (swarmd) must come out at 100 % over the stream's
    phases (one span alone holds floor or ceil of its seconds) but for the per-span cap,
    whatever the polls' phase against the span's end. Before session 11 the span's time
    ran to its last in-range sample (30.0 s) while its count stopped at the last poll
    before it: the samples that arrived in between were expected and never counted, up
    to one per span-end with 1 s polls and a quarter of one with 0.25 s
    (docs/flight-history.md, "The stock stacks' readiness in the blackout at N = 20
    (session 11)")."""
    truth = _leaves_at(30.0)
    changes = _found({1: 4.0, 2: 4.0})
    for every in (1.0, 0.25):
        for poll_phase in (0.02, 0.25, 0.5, 0.9):
            expected = delivered = 0
            for tenth in range(10):
                sent = [k + 0.05 + tenth / 10 for k in range(4, 31)]

                def count(m: int, t: float, sent: list[float] = sent) -> int:
                    return sum(1 for s in sent if s <= min(t, 30.0))

                polls = _polls(count, every_s=every, first_s=poll_phase)
                r = flight_measures.readiness_delivery(Timeline(truth, {}, changes, polls, 3, END))
                assert isinstance(r["expected"], int) and isinstance(r["delivered"], int)
                expected += r["expected"]
                delivered += r["delivered"]
            # what is left is the per-span cap's (a span of 25.5 s holding 26 samples at
            # some phases is counted 25.5; docs/flight-history.md, "Where the blackout's
            # missing readiness goes"): 1 % here at worst, against 4 % before session 11
            assert delivered / expected >= 0.985, (every, poll_phase, delivered, expected)


def test_the_poll_bound_does_not_hide_a_lost_sample() -> None:
    """The same stream with the samples at 10.3 and 20.3 s lost: 2 of each member's
    samples missing in a span of 26 s read to its last poll, the same with 1 s and 0.25 s
    polls."""
    truth = _leaves_at(30.0)
    changes = _found({1: 4.0, 2: 4.0})

    def count(m: int, t: float) -> int:
        return sum(1 for k in range(4, 31) if k + 0.3 <= min(t, 30.0) and k not in (10, 20))

    for every in (1.0, 0.25):
        polls = _polls(count, every_s=every, first_s=0.0)
        r = flight_measures.readiness_delivery(Timeline(truth, {}, changes, polls, 3, END))
        # the span 4.0-30.0 s, its last poll at 30.0 s: 26 s, 24 samples each
        assert r["expected"] == 2 * 26 and r["delivered"] == 2 * 24, (every, r)
