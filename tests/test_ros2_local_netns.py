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
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab import netns, ros2_lab
from swarmd_lab.ros2_lab import discovery_counts, host_argv, write_machine_id

from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.cli.swarmctl import main as swarmctl
from tests.conftest import LanFactory
from tests.daemon_support import (
    BundleFiles,
    daemon_status,
    matched_counts,
    run_domain,
    until,
    write_config,
    write_mission_bundle,
)

pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = [
    pytest.mark.netns,
    pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark not installed"),
    pytest.mark.skipif(shutil.which("unshare") is None, reason="unshare not installed"),
]

BIN = Path(sys.executable).parent
WAIT_S = 30.0
RUN_S = 30.0  # the lead's listener and drone-1's monitor
TALKER_S = 12.0  # drone-1's talker, then it stops (DATA(p[UD])) while the others run
CAPTURE_START_S = 10.0
ROS2_DOMAIN = 7

MISSION = """
swarm: ros2-local
domain_id: {domain}
discovery: {{t_min_s: 0.2, t_max_s: 0.5, lease_s: 4}}
participants:
  - {{name: lead, index: 0, role: commander, mavlink_sysid: 1, ipv4: {a0}}}
  - {{name: drone-1, index: 1, role: member, mavlink_sysid: 2, ipv4: {a1}}}
topics:
  - {{name: swarm/ready, type: "swarmd::Readiness", writers: member, readers: commander}}
ros2:
  domain_id: {ros2_domain}
  topics:
    - {{name: /chatter, type: std_msgs/msg/String, reliability: reliable, history_depth: 10}}
  services:
    - {{name: /trigger, type: std_srvs/srv/Trigger}}
  nodes:
    - {{name: talker, drones: member, publishes: [/chatter], serves: [/trigger]}}
    - {{name: monitor, drones: member, subscribes: [/chatter], calls: [/trigger]}}
    - {{name: listener, drones: commander, publishes: [/chatter], subscribes: [/chatter],
       calls: [/trigger]}}
"""
DRONES = ("lead", "drone-1")
RELAY_CONFIG = "ros2:\n  relay: true\n  lease_s: 6\n"


def _write_bundle(workdir: Path, addresses: list[str]) -> BundleFiles:
    text = MISSION.format(
        domain=run_domain(),
        ros2_domain=ROS2_DOMAIN,
        **{f"a{i}": a for i, a in enumerate(addresses)},
    )
    return write_mission_bundle(workdir, text, "ros2-local", "ros2-local.yaml")


def _until(cond: Callable[[], bool], what: Callable[[], str]) -> None:
    until(cond, what, WAIT_S)


def test_two_nodes_on_one_drone_find_each_other_and_the_other_drone(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(2)
    files = _write_bundle(workdir, [lan[i].address for i in range(2)])
    participants = bundle_ros2_participants(files.bundle)
    profiles = workdir / "profiles"
    code = swarmctl(
        ["ros2", "profile", str(files.path), "--trusted-key", str(files.trusted_key)]
        + ["--allow-dev", "--out", str(profiles), "--via-swarmd"]
    )
    assert code == 0
    socks = [workdir / f"{d}.sock" for d in DRONES]
    configs = [
        write_config(
            workdir / f"{d}.yaml",
            files,
            node=d,
            interface=lan[i].ifname,
            socket_path=str(socks[i]),
            extra=RELAY_CONFIG,
        )
        for i, d in enumerate(DRONES)
    ]
    daemons = []
    for i, d in enumerate(DRONES):
        with (workdir / f"{d}.log").open("ab") as err:
            argv = [str(BIN / "swarmd"), "run", "--config", str(configs[i])]
            daemons.append(lan[i].popen(argv, stderr=err))
    _until(
        lambda: all(
            sum(p["state"] == "discovered" for p in daemon_status(s)["peers"]) == 1 for s in socks
        ),
        lambda: str([daemon_status(s)["peers"] for s in socks if s.exists()]),
    )
    machine_ids = [write_machine_id(workdir, i) for i in range(2)]

    def start_node(i: int, node: str, role: str, seconds: float, *extra: str) -> Any:
        argv = [sys.executable, "-m", "swarmd_lab.ros2_node", role, "--name", node]
        argv += ["--seconds", str(seconds), "--graph-every", "1", *extra]
        return lan[i].popen(
            host_argv(argv, machine_ids[i]),
            env=ros2_lab.node_env(profiles / DRONES[i] / f"{node}.env"),
            stdout=subprocess.PIPE,
        )

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
