"""The stock contenders' flight observers (issue 20): event lines to per-pair changes.

Unit tests of ``bench/wifi/flight_events.py`` (the peers' lines are untrusted: a foreign drone
index or junk is counted and dropped), of the peers' shared ``FlightEvents`` writer, and, when
``SWARMD_FLIGHT_SMOKE=1`` asks for it, one real short flight run per stock contender at N=3
and one of ``ros2-swarmd`` (the same rclpy node, its discovery from swarmd's relay).
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from bench.wifi import flight, flight_events, flight_measures, flight_report, flight_run
from bench.wifi.flight_events import PeerEvents, Rejected, parse_line
from bench.wifi.peers.common import FlightEvents, Tally, drone_index


def line(kind: str, t: float, **fields: object) -> str:
    return json.dumps({"flight": kind, "t": t, **fields})


def test_up_and_down_become_discovered_lost_regained() -> None:
    ev = PeerEvents(3)
    ev.feed(
        0,
        [
            line("hello", 0.1, self=0),
            line("up", 1.0, peer=1, key="g1"),
            line("up", 1.5, peer=2, key="g2"),
            line("down", 40.0, peer=1, key="g1"),
            line("up", 62.0, peer=1, key="g1"),
        ],
    )
    assert ev.changes[0] == [
        (1.0, 1, "discovered"),
        (1.5, 2, "discovered"),
        (40.0, 1, "lost"),
        (62.0, 1, "regained"),
    ]
    assert ev.summary()["events"] == 5
    assert ev.rejected == Rejected()


def test_a_reboots_late_removal_of_the_old_instance_is_not_a_loss() -> None:
    ev = PeerEvents(3)
    ev.feed(
        0,
        [
            line("up", 1.0, peer=2, key="old"),
            line("up", 45.0, peer=2, key="new"),  # the new life, old lease still running
            line("down", 58.0, peer=2, key="old"),  # the old one's lease expires
        ],
    )
    # the new life seen is a restart (as swarmd's observer reports a new epoch), so the
    # reboot measure "seen by peers" has it; the old instance's end is no loss
    assert ev.changes[0] == [(1.0, 2, "discovered"), (45.0, 2, "restarted")]
    restarts = [(44.0, 2)]
    seen = [t - r for r, node in restarts for t, p, c in ev.changes[0] if p == node and t >= r]
    assert seen == [1.0]


def test_a_new_life_of_the_observer_starts_from_nobody() -> None:
    ev = PeerEvents(3)
    ev.feed(
        1,
        [
            line("hello", 0.0, self=1),
            line("up", 1.0, peer=0, key="a"),
            line("hello", 50.0, self=1),  # restarted: its stack knows nobody
            line("up", 51.0, peer=0, key="a"),
        ],
    )
    assert ev.changes[1] == [(1.0, 0, "discovered"), (51.0, 0, "discovered")]


def test_readiness_snapshots_come_from_the_commander_only() -> None:
    ev = PeerEvents(3)
    ev.feed(0, [line("readiness", 5.0, counts={"1": 4, "2": 3})])
    ev.feed(1, [line("readiness", 5.0, counts={"2": 9})])
    assert ev.readiness == [(5.0, {1: 4, 2: 3})]
    assert ev.rejected.junk == 1


@pytest.mark.parametrize(
    "bad",
    [
        line("up", 1.0, peer=7, key="x"),  # no drone 7 in a run of 3
        line("up", 1.0, peer=-1, key="x"),
        line("up", 1.0, peer=0, key="x"),  # the observer itself
        line("hello", 1.0, self=2),  # another drone's hello in observer 0's log
        line("readiness", 1.0, counts={"0": 3}),  # the commander is no member
        line("readiness", 1.0, counts={"9": 3}),
    ],
)
def test_a_foreign_drone_index_is_counted_and_dropped(bad: str) -> None:
    ev = PeerEvents(3)
    ev.feed(0, [line("up", 1.0, peer=1, key="k"), bad])
    assert ev.rejected.foreign == 1
    assert ev.changes[0] == [(1.0, 1, "discovered")]
    assert ev.readiness == []


@pytest.mark.parametrize(
    "junk",
    [
        '{"flight": "up", "t": 1.0, "peer": 1, "key": "k"',  # cut by a SIGKILL
        '{"flight": "up", "t": "soon", "peer": 1, "key": "k"}',
        '{"flight": "up", "t": NaN, "peer": 1, "key": "k"}',
        '{"flight": "up", "t": 1.0, "peer": "1", "key": "k"}',
        '{"flight": "up", "t": 1.0, "peer": true, "key": "k"}',
        '{"flight": "up", "t": 1.0, "peer": 1, "key": ""}',
        '{"flight": "up", "t": 1.0, "peer": 1, "key": 5}',
        '{"flight": "teleported", "t": 1.0, "peer": 1, "key": "k"}',
        '{"flight": "readiness", "t": 1.0, "counts": {"1": -4}}',
        '{"flight": "readiness", "t": 1.0, "counts": [1, 2]}',
        '{"flight": "up"}',
        '{"flight": "readiness", "t": 1.0, "counts": {"\u0661": 4}}',
        '{"flight": "up", "t": 1.0, "peer": 1, "key": "' + "k" * 5000 + '"}',
    ],
)
def test_junk_event_lines_are_counted_and_dropped(junk: str) -> None:
    rejected = Rejected()
    assert parse_line(junk, 0, 3, rejected) is None
    assert rejected.junk == 1
    ev = PeerEvents(3)
    ev.feed(0, [junk])
    assert ev.changes[0] == [] and ev.readiness == [] and ev.events == 0


def test_a_stacks_own_log_lines_are_other_not_junk() -> None:
    ev = PeerEvents(3)
    ev.feed(0, ["1795715240.1 [cyclonedds] warning: something", "", "{}"])
    assert ev.rejected.other == 3 and ev.rejected.junk == 0


def test_a_down_never_up_is_unmatched_and_moves_nothing() -> None:
    ev = PeerEvents(3)
    ev.feed(0, [line("down", 3.0, peer=1, key="ghost")])
    assert ev.changes[0] == [] and ev.rejected.unmatched == 1


def test_instances_per_pair_are_capped() -> None:
    ev = PeerEvents(3)
    cap = flight_events.MAX_KEYS_PER_PAIR
    ev.feed(0, [line("up", float(k), peer=1, key=f"k{k}") for k in range(cap + 10)])
    assert ev.rejected.unmatched == 10
    # each instance past the first is a new life seen (bounded by the cap too)
    assert ev.changes[0] == [(0.0, 1, "discovered")] + [
        (float(k), 1, "restarted") for k in range(1, cap)
    ]


def test_changes_from_events_measure_like_swarmds() -> None:
    """A split of 4 drones seen through event lines: the same measures module, unchanged."""
    n, lease = 4, 10.0
    truth = [
        (k * 0.5, [[i != j and (k * 0.5 < 40 or k * 0.5 >= 80 or (i < 2) == (j < 2))
                    for j in range(n)] for i in range(n)])
        for k in range(240)
    ]  # fmt: skip
    ev = PeerEvents(n)
    for i in range(n):
        lines = [line("up", 1.0, peer=j, key=f"{j}") for j in range(n) if j != i]
        for j in range(n):
            if j != i and (i < 2) != (j < 2):
                lines += [line("down", 49.0, peer=j, key=f"{j}")]
                lines += [line("up", 81.0, peer=j, key=f"{j}")]
        ev.feed(i, lines)
    m = flight_measures.measure(truth, ev.changes, {}, n=n, lease_s=lease)
    assert m["loss_latency_s"]["count"] == 8 and m["loss_latency_s"]["max"] == 9.0
    assert m["false_losses"] == 0 and m["missed_losses"] == 0
    assert m["rediscovery_s"]["max"] == 1.0


def test_the_peer_writer_emits_parseable_lines_and_remembers_keys(
    capsys: pytest.CaptureFixture[str],
) -> None:
    events = FlightEvents(True, 0)
    events.hello()
    events.up("guid-a", 2)
    events.up("guid-a", 2)  # a repeated sample of the same instance: once
    events.up("guid-b", None)  # a participant without a drone index: not reported
    events.up("guid-c", 0)  # itself
    events.down("guid-b")
    events.down("guid-a")
    tally = Tally(20)
    tally.add(1)
    events.readiness(tally)
    out = capsys.readouterr().out.splitlines()
    ev = PeerEvents(3)
    ev.feed(0, out)
    assert [c for _, _, c in ev.changes[0]] == ["discovered", "lost"]
    assert ev.readiness[0][1] == {1: 1}
    assert ev.rejected == Rejected()


def test_the_peer_writer_is_silent_unless_asked() -> None:
    buf = io.StringIO()
    with redirect_stdout(buf):
        events = FlightEvents(False, 0)
        events.hello()
        events.up("g", 1)
    assert buf.getvalue() == ""


@pytest.mark.parametrize(
    ("raw", "want"),
    [(b"3", 3), ("12", 12), (b"3\x00", 3), (b"", None), (b"uav3", None), (b"-1", None),
     (b"1234567", None), ("\u0663", None)],
)  # fmt: skip
def test_drone_index_takes_ascii_decimals_only(raw: bytes | str, want: int | None) -> None:
    assert drone_index(raw) == want


def test_every_stock_flight_contender_has_a_stated_loss_timer() -> None:
    for name in flight_run.FLIGHT_CONTENDERS:
        assert flight_run.LOSS_TIMER_S[name] > 0


def test_the_table_puts_stock_rows_beside_swarmds_with_their_loss_timer() -> None:
    m = flight_measures.measure(flight.make("split", 3).truth(), {}, {}, n=3, lease_s=10.0)
    base = {"scenario": "split", "n": 3, "run": 1, "valid": True, "rt_lag_p99_ms": 0.5}
    runs = [
        {**base, "contender": c, "lease_s": flight_run.LOSS_TIMER_S[c], "measures": m,
         "setup": {"dilation": 2.0}}
        for c in ("zenoh", "swarmd", "cyclonedds")
    ]  # fmt: skip
    rows = flight_report.table(runs)[2:]
    assert [r.split(" | ")[1] for r in rows] == ["swarmd", "cyclonedds", "zenoh"]
    assert "| 2, 20 s |" in rows[0] and "| 2, 10 s |" in rows[1]


def test_flight_run_refuses_a_contender_without_observer() -> None:
    with pytest.raises(SystemExit):
        flight_run.main(["--contenders", "ros2-static", "--n", "3"])


@pytest.mark.netns
@pytest.mark.interop
@pytest.mark.timeout(900)
@pytest.mark.skipif(
    os.environ.get("SWARMD_FLIGHT_SMOKE") != "1",
    reason="real flight runs, about 4 min per contender (ns-3, a 150 s split, undilated, at "
    "N=3); set SWARMD_FLIGHT_SMOKE=1 to run them",
)
@pytest.mark.parametrize("contender", flight_run.PEER_OBSERVED)
def test_smoke_split_at_n3_per_stock_contender(tmp_path: Path, contender: str) -> None:
    from bench.wifi.contenders import unavailable
    from bench.wifi.ns3_loader import unavailable_reason

    reason = unavailable_reason() or unavailable(contender)
    if reason is not None or os.geteuid() != 0:
        pytest.skip(reason or "needs root")
    proc = subprocess.run(  # noqa: S603 - our own module, fixed argv
        [sys.executable, "-m", "bench.wifi.flight_run", "--scenarios", "split", "--n", "3",
         "--contenders", contender, "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = json.loads(next((tmp_path / "runs").glob("*.json")).read_text())
    assert run["observer"]["events"] > 0
    # every drone discovered every other at least once (Discovery Server clients: the members
    # only the commander, whose reader alone matches their writers), the tally was read
    for i in range(3):
        found = {p for _, p, c in run["changes"][str(i)] if c == "discovered"}
        expected = {0} if contender == "fastdds-server" and i > 0 else set(range(3)) - {i}
        assert found == expected
    assert run["readiness"]
    if contender in flight_run.ROS2_ON_SWARMD:
        # the point of the relay route in flight: swarmd re-announces a returning drone to
        # the node, so its graph lists it again (stock ROS 2 never does: docs/benchmarks.md)
        assert run["measures"]["not_rediscovered"] == 0
        assert run["measures"]["rediscovery_s"]["count"] > 0
