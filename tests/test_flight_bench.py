"""The flight scenarios of the ns-3 testbed (issue 20): scenario geometry and ground truth,
the measures on hand-made records, the timeline figure from a run file, and (only when
``SWARMD_FLIGHT_SMOKE=1``) one real run at N=3.

The real run cannot fit the default suite: ns-3's import and set-up take 10-25 s, the
shortest scenario (blackout) lasts 106 s of experiment time because swarmd's lease is the
paper's 20 s and the formation must first be discovered (Tmin 8 s, Tmax 20 s).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.wifi import flight, flight_measures, flight_report

LEASE = 20.0


def test_range_is_where_the_model_falls_to_the_detection_threshold() -> None:
    r = flight.range_m()
    assert flight.rx_dbm(r) == pytest.approx(flight.RANGE_DBM)
    assert flight.rx_dbm(r - 1) > flight.RANGE_DBM > flight.rx_dbm(r + 1)
    assert 50 < r < 53  # 16 dBm, 46.68 dB at 1 m, exponent 3


@pytest.mark.parametrize("name", list(flight.SCENARIOS))
def test_every_scenario_is_seeded_and_starts_with_everyone_in_range(name: str) -> None:
    a, b, c = flight.make(name, 10, 1), flight.make(name, 10, 1), flight.make(name, 10, 2)
    assert a.waypoint_lines() == b.waypoint_lines()
    assert a.waypoint_lines() != c.waypoint_lines()
    start = a.in_range(0.0)
    assert all(start[i][j] for i in range(10) for j in range(10) if i != j)
    end = a.in_range(a.duration_s)
    assert all(end[i][j] for i in range(10) for j in range(10) if i != j)
    # the initial discovery has time before anything moves
    moves = [t for t, _, _ in a.waypoints if t > 0] + [e.t for e in a.events]
    assert min(moves) >= flight.SETTLE_S


def test_split_cuts_exactly_the_two_halves_for_the_hold() -> None:
    s = flight.make("split", 6)
    mid = s.in_range(flight.SETTLE_S + flight.MOVE_S + flight.SPLIT_HOLD_S / 2)
    for i in range(6):
        for j in range(6):
            if i != j:
                assert mid[i][j] == ((i < 3) == (j < 3)), (i, j)


def test_fade_swings_by_more_than_15_db_across_the_edge() -> None:
    s = flight.make("fade", 5)
    assert flight.rx_dbm(flight.FADE_NEAR_M) - flight.rx_dbm(flight.FADE_FAR_M) >= 15
    seen = {s.in_range(t)[4][0] for t in range(31, 60)}
    assert seen == {True, False}  # it crosses the edge back and forth
    assert all(s.in_range(t)[1][0] for t in range(0, int(s.duration_s)))  # others stay


def test_blackout_isolates_the_commander_only() -> None:
    s = flight.make("blackout", 5)
    m = s.in_range(flight.SETTLE_S + 15)
    assert not any(m[0][j] for j in range(1, 5))
    assert all(m[i][j] for i in range(1, 5) for j in range(1, 5) if i != j)


def test_reboot_kills_and_restarts_with_state_kept_then_lost() -> None:
    s = flight.make("reboot", 6)
    assert [(e.action, e.state) for e in s.events] == [
        ("kill", "kept"),
        ("start", "kept"),
        ("kill", "kept"),
        ("start", "lost"),
    ]
    assert {e.node for e in s.events} == {3}


def _truth(out: tuple[float, float], n: int = 3, end: float = 100.0) -> flight_measures.Truth:
    """Node 2 out of everyone's range during ``out``; 0 and 1 always in range."""
    rows = []
    t = 0.0
    while t <= end:
        gone = out[0] <= t < out[1]
        rows.append(
            (t, [[i != j and not (gone and 2 in (i, j)) for j in range(n)] for i in range(n)])
        )
        t += 0.5
    return rows


def test_measures_of_a_clean_split_and_heal() -> None:
    truth = _truth((20.0, 60.0))
    changes = {
        0: [(1.0, 1, "discovered"), (1.0, 2, "discovered"), (41.0, 2, "lost"),
            (61.5, 2, "regained")],
        1: [(1.0, 0, "discovered"), (1.0, 2, "discovered"), (40.0, 2, "lost"),
            (62.0, 2, "regained")],
        2: [(1.0, 0, "discovered"), (1.0, 1, "discovered"), (40.5, 0, "lost"), (41.0, 1, "lost"),
            (61.0, 0, "regained"), (61.0, 1, "regained")],
    }  # fmt: skip
    readiness = [(float(t), {1: t, 2: t if t < 20 else 20 + max(0, t - 62)}) for t in range(100)]
    fps = [2] * 100
    for s in range(60, 63):
        fps[s] = 10
    m = flight_measures.measure(
        truth, changes, {}, n=3, lease_s=LEASE, readiness=readiness, discovery_fps=fps,
        first_move_s=20.0,
    )  # fmt: skip
    assert m["loss_latency_s"] == {"count": 4, "p50": 21.0, "p90": 21.0, "max": 21.0}
    assert m["false_losses"] == 0
    assert m["lost_reports"] == {"real": 4, "intermittent": 0, "dropout": 0, "false": 0}
    assert m["missed_losses"] == 0 and m["not_rediscovered"] == 0
    assert m["rediscovery_s"]["max"] == 2.0 and m["rediscovery_s"]["count"] == 4
    frames = m["frames_per_rejoining_pair"]
    assert frames["pairs"] == 2 and frames["window_s"] == [60, 64]
    assert frames["frames"] == 10 + 10 + 10 + 2 and frames["per_pair"] == 16.0
    assert frames["steady_fps"] == 2.0 and frames["excess_per_pair"] == 12.0
    # uav2 delivered nothing between its return (60) and its regain (61.5): below 100 %
    r = m["readiness_delivery"]
    assert 0.9 < r["ratio"] < 1.0


def test_a_loss_of_a_peer_that_stayed_in_range_is_false_and_a_short_gap_a_dropout() -> None:
    truth = _truth((30.0, 34.0))  # a 4 s gap: shorter than the lease
    changes = {
        0: [(1.0, 1, "discovered"), (1.0, 2, "discovered"), (25.0, 1, "lost"),
            (26.0, 1, "regained"), (36.0, 2, "lost"), (40.0, 2, "regained")],
    }  # fmt: skip
    m = flight_measures.measure(truth, changes, {}, n=3, lease_s=LEASE)
    assert m["lost_reports"] == {"real": 0, "intermittent": 0, "dropout": 1, "false": 1}
    assert m["false_loss_examples"] == [[0, 1, 25.0]]
    assert m["loss_latency_s"]["count"] == 0  # no real loss: the gap is shorter than a lease


def test_a_loss_inside_a_gap_shorter_than_the_lease_is_intermittent() -> None:
    truth = _truth((30.0, 38.0))  # out 8 s: the peer flickers at the edge
    changes = {0: [(1.0, 2, "discovered"), (37.0, 2, "lost"), (39.0, 2, "regained")]}
    m = flight_measures.measure(truth, changes, {}, n=3, lease_s=LEASE)
    assert m["lost_reports"]["intermittent"] == 1 and m["lost_reports"]["real"] == 0
    assert m["rediscovery_s"]["max"] == 1.0


def test_a_real_loss_never_reported_is_missed() -> None:
    m = flight_measures.measure(
        _truth((20.0, 60.0)), {0: [(1.0, 2, "discovered")]}, {}, n=3, lease_s=LEASE
    )
    assert m["missed_losses"] == 4  # (0,2), (1,2), (2,0), (2,1)


def test_a_reboot_is_seen_by_peers_and_its_own_stack_is_not_blamed() -> None:
    truth = _truth((-1.0, -1.0))
    down = {2: [(40.0, 45.0)]}
    changes = {
        0: [(1.0, 2, "discovered"), (46.0, 2, "restarted")],
        1: [(1.0, 2, "discovered"), (47.0, 2, "restarted")],
        2: [(1.0, 0, "discovered"), (1.0, 1, "discovered"), (45.5, 0, "discovered"),
            (46.5, 1, "discovered")],
    }  # fmt: skip
    m = flight_measures.measure(truth, changes, down, n=3, lease_s=LEASE, restarts=[(45.0, 2)])
    assert m["reboot_seen_by_peers_s"]["max"] == 2.0
    assert m["reboot_finds_peers_s"]["max"] == 1.5
    assert m["false_losses"] == 0 and m["missed_losses"] == 0


def test_a_loss_logged_just_before_the_recorded_kill_is_not_false() -> None:
    """zenoh's peers report a killed drone lost at once (its session closes), 42 ms before
    the harness's record of the kill: that is the kill's loss (intermittent: 5 s down,
    shorter than a lease), not a false loss; a report 10 s before the kill still is."""
    truth = _truth((-1.0, -1.0))
    down = {2: [(40.045, 45.055), (80.01, 85.02)]}
    changes = {
        0: [(1.0, 2, "discovered"), (40.003, 2, "lost"), (45.14, 2, "regained"),
            (79.97, 2, "lost"), (85.1, 2, "regained")],
        1: [(1.0, 2, "discovered"), (30.0, 2, "lost"), (45.14, 2, "regained")],
        2: [(1.0, 0, "discovered"), (1.0, 1, "discovered")],
    }  # fmt: skip
    m = flight_measures.measure(
        truth, changes, down, n=3, lease_s=LEASE, restarts=[(45.06, 2), (85.02, 2)]
    )
    assert m["lost_reports"]["intermittent"] == 2
    assert m["false_losses"] == 1  # node 1's, 10 s before the kill


def test_each_restart_is_measured_within_its_own_life() -> None:
    """A stock peer logs its new life's first discoveries on its own clock, a few ms before
    the harness records the start (Fast DDS's reboot run: -0.02 s). Those count as found at
    once; before, they were skipped and the next life's finds, 40 s on, were credited to
    this restart (Fast DDS, N = 10: finds p50 39.9 s)."""
    truth = _truth((-1.0, -1.0))
    down = {2: [(40.0, 45.0), (80.0, 85.0)]}
    changes = {
        0: [(1.0, 2, "discovered")],
        1: [(1.0, 2, "discovered")],
        2: [(1.0, 0, "discovered"), (1.0, 1, "discovered"),
            (44.98, 0, "discovered"), (44.99, 1, "discovered"),   # life 2, logged early
            (84.99, 0, "discovered"), (85.2, 1, "discovered")],   # life 3
    }  # fmt: skip
    m = flight_measures.measure(
        truth, changes, down, n=3, lease_s=LEASE, restarts=[(45.0, 2), (85.0, 2)]
    )
    assert m["reboot_finds_peers_s"]["count"] == 4
    assert m["reboot_finds_peers_s"]["max"] == 0.2


def test_the_timeline_figure_is_drawn_from_the_run_file_alone(tmp_path: Path) -> None:
    s = flight.make("split", 4)
    run = {
        "scenario": "split", "n": 4, "seed": 1, "run": 1, "contender": "swarmd", "valid": True,
        "description": s.description, "duration_s": s.duration_s, "phases": s.phases,
        "changes": {"0": [[1.0, 1, "discovered"], [1.0, 2, "discovered"], [60.0, 2, "lost"]]},
        "heard": [{"t": float(t), "rx": [{"1": -60.0}, {}, {"0": -61.0}, {}]} for t in range(20)],
        "measures": {"false_losses": 0, "rediscovery_s": {"p50": 1.0}},
    }  # fmt: skip
    labels, rows = flight_report.grid(json.loads(json.dumps(run)))
    assert len(labels) == 12 and labels[0] == "1>2"
    at = int((flight.SETTLE_S + flight.MOVE_S + 5) / 0.5)  # split, before uav1 noticed
    assert rows[1][at] == 3  # 1 still lists 3 though it is out of range
    assert rows[0][at] == 2  # 1 lists 2, in range
    assert rows[3][at] == 1  # row 3 is 2>1: in range, never listed by 2
    out = flight_report.timeline(run, tmp_path / "t.png")
    assert out.stat().st_size > 10_000


@pytest.mark.skipif(
    os.environ.get("SWARMD_FLIGHT_SMOKE") != "1",
    reason="one real flight run takes 2-3 min (ns-3 set-up, a 106 s scenario at the "
    "paper's 20 s lease); set SWARMD_FLIGHT_SMOKE=1 to run it",
)
def test_smoke_one_blackout_run_at_n3(tmp_path: Path) -> None:
    from bench.wifi.ns3_loader import unavailable_reason

    reason = unavailable_reason()
    if reason is not None or os.geteuid() != 0:
        pytest.skip(reason or "needs root")
    proc = subprocess.run(  # noqa: S603 - our own module, fixed argv
        [sys.executable, "-m", "bench.wifi.flight_run", "--scenarios", "blackout", "--n", "3",
         "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = json.loads(next((tmp_path / "runs").glob("*.json")).read_text())
    m = run["measures"]
    assert m["rediscovery_s"]["count"] >= 1
    assert any((tmp_path / "runs").glob("*.png"))


def test_renewal_following_q_is_a_correlation_per_daemon() -> None:
    polls = [[float(t), 0, t, 0.9 - 0.1 * t, 2.0 + t, 20.0] for t in range(5)]
    polls += [[float(t), 1, t, 0.5, 3.0, 20.0] for t in range(5)]  # Q never moved
    got = flight_measures.renewal_follows_q(polls)
    assert got["0"]["corr_q_period"] == -1.0  # Q fell as the period grew, step for step
    assert got["0"]["q"] == [0.5, 0.9] and got["0"]["renewal_period_s"] == [2.0, 6.0]
    assert got["1"]["corr_q_period"] is None
    # the start-up polls (Q 0 before any frame) are left out from ``since_s`` on
    late = flight_measures.renewal_follows_q([[0.0, 2, 0, 0.0, 5.0, 20.0], *polls], 0.5)
    assert "2" not in late and late["0"]["q"] == [0.5, 0.8]


def test_remeasure_reads_everything_it_needs_from_the_run_file() -> None:
    """A run file holds its records: the measures can be recomputed from it alone and equal
    those computed from the same records directly."""
    s = flight.make("blackout", 3)
    back = flight.SETTLE_S + 3.0 + flight.BLACKOUT_S
    changes = {
        0: [(1.0, 1, "discovered"), (1.0, 2, "discovered"), (50.0, 1, "lost"),
            (back + 4.0, 1, "regained")],
    }  # fmt: skip
    readiness = [(float(t), {1: t, 2: t}) for t in range(int(s.duration_s))]
    direct = flight_measures.measure(
        s.truth(), changes, {}, n=3, lease_s=LEASE, readiness=readiness,
        discovery_fps=[1] * int(s.duration_s), first_move_s=flight.SETTLE_S,
    )  # fmt: skip
    run = {
        "scenario": "blackout", "n": 3, "seed": 1, "lease_s": LEASE,
        "changes": {str(k): [list(c) for c in v] for k, v in changes.items()},
        "readiness": [[t, {str(k): v for k, v in table.items()}] for t, table in readiness],
        "waypoints": [[t, i, *p] for t, i, p in s.waypoints], "events": [],
        "discovery_fps": [1] * int(s.duration_s),
    }  # fmt: skip
    again = flight_report.remeasure(json.loads(json.dumps(run)))
    assert {k: v for k, v in again.items() if k != "renewal_follows_q"} == direct
    assert direct["lost_reports"]["real"] == 1 and direct["missed_losses"] == 3


def test_the_markdown_table_has_a_row_per_run_in_scenario_order() -> None:
    s = flight.make("split", 3)
    m = flight_measures.measure(s.truth(), {}, {}, n=3, lease_s=LEASE)
    base = {"contender": "swarmd", "n": 3, "valid": True, "rt_lag_p99_ms": 0.5, "measures": m}
    runs = [
        {**base, "scenario": "split", "run": 2},
        {**base, "scenario": "fly-out", "run": 1, "valid": False},
    ]
    lines = flight_report.table(runs)
    assert len(lines) == 4 and lines[1].startswith("|---|")
    assert lines[2].startswith("| fly-out | swarmd | 3 | 1 | NO (0.50 ms)")
    assert lines[3].startswith("| split | swarmd | 3 | 2 | yes")
    assert all(line.count("|") == lines[0].count("|") for line in lines)


def test_renewal_and_vouch_rates_are_correlated_with_q_when_polled() -> None:
    """Polls with the status ``rates`` (renewals sent, vouches sent, vouches received per
    s): the renewal rate rises as Q falls (correlation -1 here); the commander's vouch rate
    is the one it sent, a member's the one it received. Polls without them (older run
    files) give the period alone."""
    polls = [[float(t), 0, t, 1.0 - 0.2 * t, 3.0, 20.0, 0.1 + 0.02 * t, 0.2 + 0.01 * t, 0.0]
             for t in range(5)]  # fmt: skip
    polls += [[float(t), 1, t, 1.0 - 0.2 * t, 5.0, 20.0, 0.1, 0.0, 0.3 - 0.05 * t]
              for t in range(5)]  # fmt: skip
    polls += [[float(t), 2, t, 0.5, 3.0, 20.0] for t in range(5)]
    got = flight_measures.renewal_follows_q(polls)
    assert got["0"]["corr_q_renewal_rate"] == -1.0 and got["0"]["renewals_per_s"] == [0.1, 0.18]
    assert got["0"]["vouch_rate"] == "sent" and got["0"]["corr_q_vouch_rate"] == -1.0
    assert got["1"]["vouch_rate"] == "received" and got["1"]["corr_q_vouch_rate"] == 1.0
    assert got["1"]["corr_q_renewal_rate"] is None  # the rate never moved
    assert "renewals_per_s" not in got["2"] and got["2"]["corr_q_period"] is None


def test_readiness_counts_only_the_time_in_range_never_the_blackout() -> None:
    """uav2 is out of the commander's range from 30 s to 60 s (truth samples every 0.5 s:
    the last in range at 29.5, the first back at 60.0). Every sample it could send in range
    arrived (1 Hz, up to 29.5 s and from the return on): nothing is expected during the
    outage nor in the half step after its last sample in range (counted to 30.0 s, the
    first sample out of range, before)."""
    truth = _truth((30.0, 60.0), end=99.5)
    changes = {0: [(0.0, 1, "discovered"), (0.0, 2, "discovered"), (50.0, 2, "lost"),
                   (60.0, 2, "regained")]}  # fmt: skip

    def sent(t: float) -> int:  # samples of uav2 received by t: one a second while in range
        return int(min(t, 29.5)) + (int(t - 60.0) if t >= 60.0 else 0)

    readiness = [(t / 2, {1: int(t / 2), 2: sent(t / 2)}) for t in range(200)]
    m = flight_measures.measure(truth, changes, {}, n=3, lease_s=LEASE, readiness=readiness)
    r = m["readiness_delivery"]
    # expected: uav1 0-99.5 s, uav2 0-29.5 s and 60-99.5 s (168.5 s at 1 Hz)
    assert r["expected"] == round(99.5 + 29.5 + 39.5) == 168
    assert r["delivered"] == 99 + 29 + 39  # whole seconds of each span
    assert r["ratio"] >= 0.99


def test_an_extra_sample_at_re_discovery_does_not_hide_a_missing_one() -> None:
    """uav2 sends one extra sample when the commander finds it again (the swarm core reports
    at once to a reader that comes back), and loses 10 s of samples in its first span: the
    extra one must not fill that hole (delivery is capped per span)."""
    truth = _truth((30.0, 60.0), end=99.5)
    changes = {0: [(0.0, 1, "discovered"), (0.0, 2, "discovered"), (50.0, 2, "lost"),
                   (60.0, 2, "regained")]}  # fmt: skip

    def sent(t: float) -> int:  # 0-29.5 s: 10 s missing; from 60.5 s: 3 extra (re-sent)
        first = max(0, int(min(t, 29.5)) - 10) if t >= 10.0 else 0
        second = (int(t - 60.0) + (3 if t >= 60.5 else 0)) if t >= 60.0 else 0
        return first + second

    readiness = [(t / 2, {1: int(t / 2), 2: sent(t / 2)}) for t in range(200)]
    m = flight_measures.measure(truth, changes, {}, n=3, lease_s=LEASE, readiness=readiness)
    r = m["readiness_delivery"]
    # the 60-99.5 s span counts at most its 39.5 s (42 samples arrived in it)
    assert r["delivered"] == round(99 + 19 + 39.5)
    assert r["ratio"] == round(157.5 / 168.5, 4)
