"""The flight runs' staggered start (docs/testbed.md, "Staggered start"): each drone's stack
starts U(0, ``--stagger-s``) after the release, seeded, recorded in the run file; 0 is the
lockstep start of the boot benchmark (``bench/wifi/run.py``, which never staggers)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from bench.wifi import flight, flight_run
from bench.wifi.barrier import Process


def test_offsets_are_seeded_and_within_the_stagger() -> None:
    a = flight.start_offsets(20, 1, 8.0)
    assert a == flight.start_offsets(20, 1, 8.0)  # the same seed, the same offsets
    assert a != flight.start_offsets(20, 2, 8.0)
    assert len(a) == 20 and all(0.0 <= o <= 8.0 for o in a)
    assert max(a) - min(a) > 4.0  # spread over the interval, not bunched at one end
    assert len(set(a)) == 20
    assert all(o <= 3.0 for o in flight.start_offsets(20, 1, 3.0))


def test_the_scenario_is_the_same_with_or_without_a_stagger() -> None:
    # the offsets have their own rng: the scenario's draws (placement, fade) stay as they were
    before = flight.make("fade", 10, 1)
    flight.start_offsets(10, 1, 8.0)
    assert flight.make("fade", 10, 1) == before


def test_zero_stagger_is_the_lockstep_start_and_bounds_are_enforced() -> None:
    assert flight.start_offsets(5, 1, 0.0) == (0.0,) * 5
    for bad in (-1.0, flight.MAX_STAGGER_S + 0.1, float("nan")):
        with pytest.raises(ValueError, match="stagger"):
            flight.start_offsets(5, 1, bad)
    # every stack runs before the first command cue and the first move of any scenario
    for name in flight.SCENARIOS:
        s = flight.make(name, 5)
        first = min([c.t for c in s.commands] + [t for t, _, _ in s.waypoints if t > 0])
        assert flight.MAX_STAGGER_S < first, name


class FakeBarrier:
    def __init__(self) -> None:
        self.calls: list[tuple[str, list[float]]] = []

    def release(self) -> None:
        self.calls.append(("at once", []))

    def release_staggered(self, procs: Sequence[Process], delays_s: Sequence[float]) -> None:
        self.calls.append(("staggered", list(delays_s)))


def test_the_harness_releases_at_once_without_stagger_and_on_the_experiment_clock_with() -> None:
    b = FakeBarrier()
    flight_run.release(b, [], (0.0, 0.0, 0.0), 3.0)  # type: ignore[arg-type]
    flight_run.release(b, [], (0.0, 1.5, 2.0), 3.0)  # type: ignore[arg-type]
    # dilated by k = 3: an experiment second is three real ones
    assert b.calls == [("at once", []), ("staggered", [0.0, 4.5, 6.0])]


def test_the_run_file_records_the_stagger() -> None:
    got = flight_run.stagger_setup(8.0, (0.5, 7.25, 3.0), (0.51, 7.26, 3.0), 3)
    assert got == {
        "stagger_s": 8.0,
        "start_offsets_s": [0.5, 7.25, 3.0],
        "started_s": [0.51, 7.26, 3.0],
    }
    # assemble's default (a caller that knows of no stagger): everyone at the release
    assert flight_run.stagger_setup(0.0, (), (), 2)["start_offsets_s"] == [0.0, 0.0]


def test_lockstep_counts_changes_near_one_phase_of_the_period() -> None:
    from bench import flight_lockstep

    run = {
        "changes": {
            "0": [[8.1, 1, "discovered"], [15.9, 2, "regained"], [20.0, 1, "lost"]],
            "1": [[3.0, 0, "discovered"], [24.05, 2, "regained"]],
        },
        "heard": [
            {"t": 1.45, "rx": [{"1": -60.0}, {"0": -60.0, "2": -80.0}, {}]},
            {"t": 2.45, "rx": [{}, {}, {"1": -81.0}]},
        ],
    }
    ph = flight_lockstep.phases(run, 8.0)
    assert sorted(round(v, 2) for v in ph) == [0.05, 0.1, 3.0, 7.9]  # "lost" is not counted
    assert flight_lockstep.near_phase(ph, 8.0, 0.0, 0.25) == 3  # 7.9 is 0.1 before 0
    assert flight_lockstep.near_phase(ph, 8.0, 3.0, 0.25) == 1
    assert flight_lockstep.densest_bin(ph) == (0.0, 2)
    # node 2: heard by node 1 in the first second; itself hears node 1 in the second
    assert flight_lockstep.fade_hearing(run, 2, 0.0, 10.0, 8.0) == ([1.45], [2.45])
