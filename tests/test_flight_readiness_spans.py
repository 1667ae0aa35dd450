"""``bench.wifi.flight_readiness`` on synthetic records: the missing readiness split per
member and span into the onset (nothing counted yet) and the steady part (samples lost
from a running stream), as docs/flight-history.md, "The stock stacks' readiness in the
blackout at N = 20 (session 11)", reads the runs."""

from __future__ import annotations

from typing import Any

from bench.wifi import flight_measures, flight_readiness
from bench.wifi.flight_measures import Change, Timeline

END_S = 100.0
PHASES = [("blackout", 30.0, 60.0)]


def _truth() -> flight_measures.Truth:
    """The commander (0) and two members: all in range to 30 s, the commander away from
    30.5 to 59.5 s, back from 60 s to the end."""
    rows = []
    for k in range(int(END_S / 0.5) + 1):
        t = k * 0.5
        near = not 30.0 < t < 60.0
        rows.append(
            (t, [[i != j and (near or 0 not in (i, j)) for j in range(3)] for i in range(3)])
        )
    return rows


def _changes() -> dict[int, list[Change]]:
    return {0: [(4.0, 1, "discovered"), (4.0, 2, "discovered")]}


def _sent() -> dict[int, list[float]]:
    """uav2 (member 1): nothing until 9.2 s (its writer not matched: a 5 s onset), its
    sample at 20.2 s lost, after the return nothing until 63.2 s (a 3 s onset). uav3
    (member 2): a sample every second from 4.2 s, and from 60.2 s after the return."""
    one = [t + 0.2 for t in range(9, 30) if t != 20] + [t + 0.2 for t in range(63, 100)]
    two = [t + 0.2 for t in range(4, 30)] + [t + 0.2 for t in range(60, 100)]
    return {1: one, 2: two}


def _polls(every_s: float = 1.0, phase_s: float = 0.5) -> list[tuple[float, dict[int, int]]]:
    sent = _sent()
    out = []
    t = phase_s
    while t <= END_S:
        table = {m: c for m, s in sent.items() if (c := sum(1 for x in s if x <= t))}
        out.append((t, table))
        t += every_s
    return out


def _rows(every_s: float = 1.0) -> list[dict[str, Any]]:
    return flight_readiness.readiness_spans(
        Timeline(_truth(), {}, _changes(), _polls(every_s), 3, END_S), PHASES
    )


def test_the_onset_and_the_lost_sample_are_told_apart() -> None:
    rows = _rows()
    one = [r for r in rows if r["member"] == 1]
    assert [r["phase"] for r in one] == ["start", "return after blackout"]
    start, back = one
    # from the discovery (4.0 s) to the poll that counted 9.2 s's sample (9.5 s)
    assert start["onset_s"] == 5.5
    assert start["onset_missing"] == 4.5
    assert start["steady_missing"] == 1.0  # the sample of 20.2 s
    assert back["onset_s"] == 3.5 and back["onset_missing"] == 2.5
    assert back["steady_missing"] == 0.0
    two = [r for r in rows if r["member"] == 2]
    assert all(r["missing"] == 0.0 for r in two)


def test_the_spans_add_up_to_the_run_measure() -> None:
    for every in (1.0, 0.25):
        rows = _rows(every)
        whole = flight_measures.readiness_delivery(
            Timeline(_truth(), {}, _changes(), _polls(every), 3, END_S)
        )
        assert round(sum(float(r["expected"]) for r in rows)) == whole["expected"]
        assert round(sum(float(r["delivered"]) for r in rows)) == whole["delivered"]
        phases = flight_readiness.by_phase(rows)
        assert set(phases) == {"start", "return after blackout"}
        assert phases["start"]["spans"] == 2


def test_nothing_counted_in_a_span_is_all_onset() -> None:
    """A member found but never heard: its whole span is the onset, nothing steady."""
    changes = _changes()
    polls = [(t, {2: c}) for t, table in _polls() if (c := table.get(2, 0))]
    rows = flight_readiness.readiness_spans(
        Timeline(_truth(), {}, changes, polls, 3, END_S), PHASES
    )
    silent = [r for r in rows if r["member"] == 1]
    assert silent and all(r["onset_missing"] == r["expected"] for r in silent)
    assert all(r["steady_missing"] == 0.0 and r["delivered"] == 0 for r in silent)


def test_per_second_holds_every_counted_sample_and_expected_second() -> None:
    rows = _rows()
    series = flight_readiness.per_second(rows, _polls())
    got = sum(g for _, g, _ in series)
    expected = sum(e for _, _, e in series)
    assert abs(expected - sum(float(r["expected"]) for r in rows)) < 1e-6
    # every sample counted inside a span, none from the blackout's seconds
    assert abs(got - sum(float(r["delivered"]) for r in rows)) < 1.0
    assert all(g == 0.0 and e == 0.0 for s, g, e in series if 31 <= s < 59)


def test_the_other_readings_give_back_the_onsets_and_only_them() -> None:
    """uav2's 5.5 s start-up onset (4.5 samples) and 3.5 s return onset (2.5): one sample
    back at each onset adds 2; without the start-up onset's missing samples 4.5 more, and
    nothing of its return or of uav3."""
    rows = _rows()
    expected = sum(float(r["expected"]) for r in rows)
    delivered = sum(float(r["delivered"]) for r in rows)
    other = flight_readiness.readings(rows)
    assert other["measured"] == round(delivered / expected, 4)
    assert other["one_back"] == round((delivered + 2) / expected, 4)
    assert other["no_start_onsets"] == round((delivered + 4.5) / expected, 4)
    assert flight_readiness.readings([]) == {
        "measured": None,
        "one_back": None,
        "no_start_onsets": None,
    }
