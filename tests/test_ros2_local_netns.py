"""Several stock rclpy nodes on one drone, on the relay route (issue 19, docs/ros2.md
"Several nodes on one drone").

Two drones in network namespaces, each with swarmd (``ros2.relay: true``); drone-1 runs two
rclpy nodes (a talker that serves ``/trigger``, and a monitor that subscribes and calls it),
the lead runs one (a listener that also publishes on the same topic and calls the service).
Each node is in its own mount namespace with its drone's machine id and ``/dev/shm``, so the
two nodes of drone-1 share a host as a companion computer's processes do. Checked:

1. the two local nodes find each other (their profiles name each other's [::1] discovery
   port) and exchange messages and a service call; the lead's node talks to both;
2. each node's ROS 2 graph lists the other node of its drone (rmw's ``ros_discovery_info``
   between local nodes) and the other drone's nodes (swarmd's graph preloading);
3. stopping drone-1's talker marks only it: drone-1's alive bitmap drops its bit only, the
   lead's relay shows it stopped and the monitor still relayed, both remaining subscribers
   lose exactly that publisher, and both graphs drop only ``/talker``;

and the link carries no ROS 2 SPDP, SEDP or graph datagram. Bounded waits; no assertion on
elapsed time.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab import netns, ros2_lab
from swarmd_lab.ros2_lab import discovery_counts

from swarmd.bundle.ros2 import bundle_ros2_participants
from tests.conftest import LanFactory
from tests.daemon_support import daemon_status, matched_counts, until
from tests.ros2_relay_support import (
    NETNS_MARKS,
    WAIT_S,
    start_relay_swarm,
    write_chatter_bundle,
)

pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = NETNS_MARKS

RUN_S = 30.0  # the lead's listener and drone-1's monitor
TALKER_S = 12.0  # drone-1's talker, then it stops (DATA(p[UD])) while the others run
CAPTURE_START_S = 10.0

DRONES = ("lead", "drone-1")
# the lead's listener also publishes on the topic it listens to
LEAD_LISTENER = (
    "{name: listener, drones: commander, publishes: [/chatter], subscribes: [/chatter],"
    " calls: [/trigger]}"
)


def _until(cond: Callable[[], bool], what: Callable[[], str]) -> None:
    until(cond, what, WAIT_S)


def test_two_nodes_on_one_drone_find_each_other_and_the_other_drone(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(2)
    ros2_nodes = (ros2_lab.TALKER_NODE, ros2_lab.MONITOR_NODE, LEAD_LISTENER)
    files = write_chatter_bundle(
        workdir, "ros2-local", [lan[i].address for i in range(2)], ros2_nodes
    )
    participants = bundle_ros2_participants(files.bundle)
    relay = start_relay_swarm(lan, workdir, files, DRONES)
    daemons, socks, nodes = relay.daemons, relay.socks, relay.nodes

    def start_node(i: int, node: str, role: str, seconds: float, *extra: str) -> Any:
        argv = ros2_lab.node_argv(role, seconds, "--graph-every", "1", *extra, name=node)
        return nodes.start(i, node, argv)

    def output(proc: Any, seconds: float) -> list[dict[str, Any]]:
        stdout, _ = proc.communicate(timeout=seconds + 30)
        assert proc.returncode == 0
        return [json.loads(x) for x in stdout.decode().splitlines() if x.startswith("{")]

    lead_log = workdir / "lead-matched.jsonl"
    monitor_log = workdir / "monitor-matched.jsonl"
    pcap = workdir / "link.pcapng"
    capture = ros2_lab.start_capture(lan.hub, netns.BRIDGE, pcap, CAPTURE_START_S)
    try:
        listener = start_node(
            0,
            "listener",
            "listener",
            RUN_S,
            "--tag",
            "lead",
            "--also-publish",
            "/chatter",
            "--matched-log",
            str(lead_log),
        )
        monitor = start_node(1, "monitor", "listener", RUN_S, "--matched-log", str(monitor_log))
        talker = start_node(1, "talker", "talker", TALKER_S, "--tag", "drone-1")
        # the monitor matches the lead's publisher and its own drone's talker; the lead's
        # listener its own publisher and drone-1's talker
        _until(lambda: 2 in matched_counts(monitor_log), lambda: str(matched_counts(monitor_log)))
        _until(lambda: 2 in matched_counts(lead_log), lambda: str(matched_counts(lead_log)))
        talker_out = output(talker, TALKER_S)
        # the talker has stopped: only it is marked, at home and at the lead
        _until(
            lambda: matched_counts(monitor_log)[-1:] == matched_counts(lead_log)[-1:] == [1],
            lambda: f"monitor {matched_counts(monitor_log)} lead {matched_counts(lead_log)}",
        )
        _until(
            lambda: (
                {r["node"]: r["state"] for r in daemon_status(socks[0])["ros2"]["remote"]}
                == {"talker": "node stopped", "monitor": "relayed"}
            ),
            lambda: str(daemon_status(socks[0])["ros2"]["remote"]),
        )
        drone1_status = daemon_status(socks[1])["ros2"]
        listener_out = output(listener, RUN_S)
        monitor_out = output(monitor, RUN_S)
    finally:
        capture.terminate()
        capture.wait(timeout=10)
    drones = frozenset(lan[i].address for i in range(2))
    counts = discovery_counts(pcap, drones)
    graph_on_air = ros2_lab.graph_datagrams(
        pcap,
        ros2_lab.graph_entity_ids(participants),
        drones,
        ros2_lab.ros2_ports(participants),
    )
    lead_result, monitor_result = listener_out[-1], monitor_out[-1]
    lead_graph = [x for x in listener_out if "graph" in x]
    monitor_graph = [x for x in monitor_out if "graph" in x]
    print(
        f"\nlead: {lead_result}\nmonitor: {monitor_result}\ntalker: {talker_out[-1]}"
        f"\nlead graph: {[s['nodes'] for s in lead_graph]}"
        f"\nmonitor graph: {[s['nodes'] for s in monitor_graph]}"
        f"\nmatched: monitor {matched_counts(monitor_log)} lead {matched_counts(lead_log)}"
        f"\ndrone-1 relay: {drone1_status['alive_bitmap']} {drone1_status['local']}"
        f"\nlink from the drones: {counts}; graph datagrams {graph_on_air}"
    )
    # 1. the local pair exchange messages and a service call; the lead talks to both
    assert {"drone-1", "lead"} <= set(monitor_result["senders"]), monitor_result
    assert monitor_result["answers"], monitor_result  # drone-1's own talker answered
    assert "drone-1" in lead_result["senders"], lead_result
    assert lead_result["answers"], lead_result  # across drones
    # 2. each graph lists the other node of its drone and the other drone's nodes
    assert any({"/talker", "/listener"} <= set(s["nodes"]) for s in monitor_graph), monitor_graph
    assert any({"/talker", "/monitor"} <= set(s["nodes"]) for s in lead_graph), lead_graph
    # 3. the talker's stop marks only it: drone-1's bitmap keeps the monitor's bit (bundle
    # order on drone-1: talker = bit 0, monitor = bit 1), and both graphs drop only /talker
    # (the snapshots after the last one with /talker: the nodes' runs end together, so the
    # very last may already miss the other drone's node)
    assert drone1_status["alive_bitmap"] == "02", drone1_status
    # the node that started second got the first one's own DATA(p) from the relay too
    assert drone1_status["counters"]["tx_sibling_spdp"] >= 1, drone1_status["counters"]
    for graph, other in ((monitor_graph, "/listener"), (lead_graph, "/monitor")):
        last_with = max(i for i, s in enumerate(graph) if "/talker" in s["nodes"])
        after = graph[last_with + 1 :]
        assert any(other in s["nodes"] for s in after), graph
    # nothing of ROS 2's discovery or graph on the air
    assert counts.ros2_spdp == 0 and counts.ros2_sedp == 0
    assert graph_on_air == 0
    for daemon in daemons:
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(timeout=WAIT_S) == 0
