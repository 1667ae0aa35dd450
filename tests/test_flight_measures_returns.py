"""``flight_measures.readiness_after_returns`` on synthetic records: where the readiness a
member sends after coming back into the commander's range goes (docs/flight-history.md,
"Where the blackout's missing readiness goes")."""

from __future__ import annotations

from bench.wifi.flight_measures import (
    Timeline,
    first_report_lost,
    poll_gap,
    readiness_after_returns,
)

STEP_S = 0.5
END_S = 40.0


def _truth() -> list[tuple[float, list[list[bool]]]]:
    """Two drones: in range 0-10 s, apart 10.5-19.5 s, back from 20 s to the end."""
    out = []
    for k in range(int(END_S / STEP_S) + 1):
        t = k * STEP_S
        near = not 10.0 < t < 20.0
        out.append((t, [[False, near], [near, False]]))
    return out


def _polls(counted_at: list[float]) -> list[tuple[float, dict[int, int]]]:
    """The commander's table every 0.25 s: member 1's count of reports taken by then."""
    return [
        (k * 0.25, {1: sum(1 for c in counted_at if c <= k * 0.25)})
        for k in range(int(END_S / 0.25) + 1)
    ]


def _changes(member_finds: float, lead_finds: float) -> dict[int, list[tuple[float, int, str]]]:
    return {
        0: [(0.1, 1, "discovered"), (15.0, 1, "lost"), (lead_finds, 1, "regained")],
        1: [(0.1, 0, "discovered"), (15.0, 0, "lost"), (member_finds, 0, "regained")],
    }


def test_a_first_report_that_reached_a_commander_without_the_member_is_lost() -> None:
    """The member finds the commander 0.5 s after the return, the commander finds the
    member 0.2 s after that; the member's report at its find is not counted, its stream
    from then on is: one missing report besides the 0.5 s wait."""
    before = [0.1 + k for k in range(10)]
    after = [20.5 + k for k in range(1, 20)]  # 20.5 itself never counted
    rows = readiness_after_returns(
        Timeline(_truth(), {}, _changes(20.5, 20.7), _polls(before + after), 2, END_S)
    )
    assert len(rows) == 1
    row = rows[0]
    assert row["member"] == 1 and row["return_s"] == 20.0
    assert row["wait_s"] == 0.5 and row["member_first_s"] == 0.2
    assert row["first_counted_s"] == 1.5  # the poll after 21.5 s
    assert first_report_lost(row)
    assert row["expected"] == 20.0 and row["sendable"] == 20 and row["delivered"] == 19


def test_a_first_report_counted_at_once_is_not_lost() -> None:
    before = [0.1 + k for k in range(10)]
    after = [20.71 + k for k in range(20)]  # taken as the commander finds the member
    rows = readiness_after_returns(
        Timeline(_truth(), {}, _changes(20.5, 20.7), _polls(before + after), 2, END_S)
    )
    assert not first_report_lost(rows[0])
    assert rows[0]["delivered"] == 20.0


def test_polls_a_period_apart_cannot_tell_a_lost_first_report() -> None:
    """The stock contenders' tallies are written 1 s apart: a report taken at once and one
    lost whose successor came a period later both show at the poll after: not known."""
    before = [0.1 + k for k in range(10)]
    after = [20.5 + k for k in range(1, 20)]
    rows = readiness_after_returns(
        Timeline(_truth(), {}, _changes(20.5, 20.7), _polls(before + after), 2, END_S)
    )
    assert first_report_lost(rows[0], poll_gap_s=0.25) is True
    assert first_report_lost(rows[0], poll_gap_s=1.0) is None


def test_the_poll_gap_is_the_median_spacing() -> None:
    assert poll_gap(_polls([])) == 0.25
    assert poll_gap([(0.0, {}), (1.0, {}), (2.0, {}), (7.0, {})]) == 1.0
    assert poll_gap([(0.0, {})]) == 0.0
