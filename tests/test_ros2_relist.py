"""Why stock ROS 2 never re-lists a returning drone (issue 20): ``bench/ros2_relist.py`` and
the ros2 peer's graph observer.

The unit tests pin the pieces the finding rests on: the observer's graph diff re-lists a
drone as soon as rmw's graph lists it again (so the observer is not the cause), the
capture summary reads an ACKNACK base past the writer's last sequence number as "nothing
resent", and the probe's listing times. With ``SWARMD_ROS2_RELIST=1`` (root, network
namespaces, the ROS 2 wheels, tshark, nft; about two minutes) the real reproduction runs
twice: stock, where the observer never re-lists the drone while a late-joining
participant does, and nudged, where a new ``ros_discovery_info`` sample re-lists it.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import sys
from contextlib import redirect_stdout
from pathlib import Path

import pytest
from swarmd_lab import netns

from bench import ros2_relist
from bench.ros2_relist import cut_rules, first_listing, parse_args, summarize_graph_rows
from bench.wifi.flight_events import PeerEvents
from bench.wifi.peers.common import FlightEvents
from bench.wifi.peers.ros2_peer import GraphWatch

A = ["10.0.0.1", "10.0.0.2", "10.0.0.3"]
OBSERVER, DRONE1, PROBE, FRESH = "p0", "p1", "p2", "p2new"
WRITER = "0x00000103"


def observe(updates: list[list[tuple[str, str]]]) -> list[tuple[float, int, str]]:
    """The observer's graph polls through FlightEvents into the flight measure's changes."""
    out = io.StringIO()
    with redirect_stdout(out):
        events = FlightEvents(True, 0)
        events.hello()
        watch = GraphWatch(events, 0)
        for names in updates:
            watch.update(names)
    measure = PeerEvents(3)
    measure.feed(0, out.getvalue().splitlines())
    return measure.changes[0]


def test_observer_relists_a_drone_as_soon_as_the_graph_lists_it_again() -> None:
    both = [("listener", "/drone0"), ("talker", "/drone1"), ("talker", "/drone2")]
    without_1 = [("listener", "/drone0"), ("talker", "/drone2")]
    changes = observe([both, without_1, without_1, both])
    assert [(peer, change) for _, peer, change in changes] == [
        (1, "discovered"),
        (2, "discovered"),
        (1, "lost"),
        (1, "regained"),
    ]


def test_observer_ignores_itself_and_nodes_outside_drone_namespaces() -> None:
    names = [("listener", "/drone0"), ("probe", "/"), ("x", "/dronex"), ("talker", "/drone2")]
    changes = observe([names, names])
    assert [(peer, change) for _, peer, change in changes] == [(2, "discovered")]


def row(t: float, src: str, dst: str, sp: str, dp: str, wr: str, kinds: str, seq: str) -> list[str]:
    return [str(t), src, dst, sp, dp, wr, "0x00000204", kinds, seq]


def returning_drone_rows() -> list[list[str]]:
    """What the capture showed (bench.ros2_relist, stock run): after the heal at t=35 the
    returning writer heartbeats seq 3..3; the old readers answer base 4 (nothing resent),
    a participant first seen at t=50 asks from 3 and gets the DATA."""
    return [
        row(1.0, A[0], A[1], OBSERVER, DRONE1, WRITER, "0x0e,0x06", "4"),
        row(1.0, A[2], A[1], PROBE, DRONE1, WRITER, "0x0e,0x06", "4"),
        row(1.0, A[1], A[0], DRONE1, OBSERVER, "0x000100c2", "0x09,0x15", "1"),
        row(37.9, A[1], A[0], DRONE1, OBSERVER, WRITER, "0x0e,0x07", "3,3"),
        row(37.9, A[0], A[1], OBSERVER, DRONE1, WRITER, "0x0e,0x06", "4"),
        row(38.0, A[1], A[2], DRONE1, PROBE, WRITER, "0x0e,0x07", "3,3"),
        row(38.0, A[2], A[1], PROBE, DRONE1, WRITER, "0x0e,0x06", "4"),
        row(38.1, A[1], "239.255.0.1", DRONE1, "", "0x000100c2", "0x09,0x15", "1"),
        row(50.4, A[2], A[1], FRESH, DRONE1, WRITER, "0x0e,0x06", "0"),
        row(50.4, A[1], A[2], DRONE1, FRESH, WRITER, "0x0e,0x07", "3,3"),
        row(50.4, A[2], A[1], FRESH, DRONE1, WRITER, "0x0e,0x06", "3"),
        row(50.5, A[1], A[2], DRONE1, FRESH, WRITER, "0x0e,0x09,0x15", "3"),
        row(50.5, A[2], A[1], FRESH, DRONE1, WRITER, "0x0e,0x06", "4"),
        row(65.1, A[1], A[0], DRONE1, OBSERVER, WRITER, "0x09,0x15", "4"),  # teardown
    ]


def test_capture_summary_old_readers_ack_past_the_writer_and_get_no_data() -> None:
    got = summarize_graph_rows(returning_drone_rows(), A, 1, WRITER, since=35.0, until=65.0)
    assert got["graph_acknack_bases_from"] == {
        "drone0": [4],
        "drone2": [4],
        "drone2-new": [0, 3, 4],
    }
    assert got["graph_data_to"] == {"drone2-new": 1}  # the teardown's DATA is past ``until``
    assert got["graph_heartbeats_to"] == {"drone0": 1, "drone2": 1, "drone2-new": 1}
    assert got["spdp"] == 1  # before the heal not counted


def test_capture_summary_without_a_graph_writer_counts_only_discovery() -> None:
    got = summarize_graph_rows(returning_drone_rows(), A, 1, None, since=35.0, until=65.0)
    assert got["graph_data_to"] == {} and got["graph_acknack_bases_from"] == {}
    assert got["spdp"] == 1


def test_first_listing_tells_an_unowned_publisher_from_a_listed_node() -> None:
    unknown = "_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_"
    lines = [
        {"probe": "probe", "t": 5.0, "nodes": ["/drone1"], "publishers": ["/drone1/talker"]},
        {"probe": "probe", "t": 30.0, "nodes": ["/drone0"], "publishers": []},
        {"probe": "probe", "t": 37.0, "nodes": ["/drone0"], "publishers": [unknown]},
        {"probe": "fresh", "t": 52.0, "nodes": ["/drone1"], "publishers": ["/drone1/talker"]},
    ]
    assert first_listing(lines, "probe", 35.0, 1) == {
        "node": None,
        "publisher": 2.0,
        "publisher_named": None,
    }
    assert first_listing(lines, "fresh", 35.0, 1) == {
        "node": 17.0,
        "publisher": 17.0,
        "publisher_named": 17.0,
    }


def test_cut_rules_drop_both_directions_of_one_port_only() -> None:
    rules = cut_rules("v1")
    assert 'iifname "v1" drop' in rules and 'oifname "v1" drop' in rules
    assert "hook forward" in rules and "policy accept" in rules
    assert "v0" not in rules and "v2" not in rules


@pytest.mark.parametrize(
    "argv",
    [
        ["--cut-s", "0"],
        ["--settle-s", "300", "--cut-s", "300", "--after-s", "30"],
        ["--fresh-after-s", "30"],
        ["--nudge-after-s", "-1"],
    ],
)
def test_parse_args_refuses_unbounded_or_inconsistent_runs(argv: list[str]) -> None:
    with pytest.raises(SystemExit), redirect_stdout(io.StringIO()):
        parse_args(argv)


def test_parse_args_defaults_outlast_the_lease() -> None:
    args = parse_args([])
    assert args.cut_s > 20.0  # Fast DDS 3.2's default participant lease
    assert args.fresh_after_s < args.after_s


def _live_reason() -> str | None:
    if os.environ.get("SWARMD_ROS2_RELIST") != "1":
        return "set SWARMD_ROS2_RELIST=1 to run the real reproduction (about two minutes)"
    if netns.unavailable_reason() is not None:
        return netns.unavailable_reason()
    for tool in ("tshark", "nft", "unshare"):
        if shutil.which(tool) is None:
            return f"{tool} not installed"
    try:
        import rclpy  # noqa: F401
    except ImportError:
        return "ROS 2 wheels not installed (scripts/setup.sh)"
    return None


LIVE = pytest.mark.skipif(_live_reason() is not None, reason=str(_live_reason()))
SHORT = ["--settle-s", "8", "--cut-s", "24", "--after-s", "16", "--fresh-after-s", "6"]


def _run(tmp_path: Path, *extra: str) -> dict[str, object]:
    out = tmp_path / "report.json"
    argv = [*SHORT, "--work", str(tmp_path / "work"), "--out", str(out), *extra]
    with redirect_stdout(io.StringIO()):
        assert ros2_relist.main(argv) == 0
    report: dict[str, object] = json.loads(out.read_text())
    print(json.dumps({k: v for k, v in report.items() if k != "probe_lines"}), file=sys.stderr)
    return report


@pytest.mark.netns
@pytest.mark.interop
@LIVE
def test_stock_ros2_loses_the_drone_and_never_lists_it_again(tmp_path: Path) -> None:
    report = _run(tmp_path)
    observer = report["observer"]
    assert isinstance(observer, dict)
    assert observer["lost_drone1_after_cut_s"] is not None
    assert observer["relisted_drone1_after_heal_s"] is None
    assert (observer["received_from_drone1"] or 0) > 0
    fresh = report["fresh_participant_after_heal_s"]
    assert isinstance(fresh, dict) and fresh["node"] is not None  # the late joiner does
    old = report["probe_drone2_after_heal_s"]
    assert isinstance(old, dict) and old["node"] is None and old["publisher"] is not None


@pytest.mark.netns
@pytest.mark.interop
@LIVE
def test_a_new_graph_sample_from_the_returning_drone_relists_it(tmp_path: Path) -> None:
    report = _run(tmp_path, "--nudge-after-s", "8")
    observer = report["observer"]
    assert isinstance(observer, dict)
    assert observer["lost_drone1_after_cut_s"] is not None
    relisted, nudge, timeline = (
        observer["relisted_drone1_after_heal_s"],
        report["nudge_s"],
        report["timeline_s"],
    )
    assert isinstance(relisted, float) and isinstance(nudge, float) and isinstance(timeline, dict)
    assert timeline["heal"] + relisted >= nudge  # listed again by the new sample, not before
