"""``make demo ROS2=1``: every drone also runs a real rclpy node through its swarmd.

The mission gets the ROS 2 graph of ``scenario.ROS2_GRAPH`` (talkers on the members, a
listener on the commander that also calls the members' Trigger service), each swarmd
``ros2.relay: true``, and each node the profile ``swarmctl ros2 profile --via-swarmd``
writes (docs/ros2.md). The nodes start once discovery is done, each in a private mount
namespace with its drone's own machine id and ``/dev/shm`` (``swarmd_lab.ros2_lab``), and
tshark records the LAN bridge for the whole run, so the report shows the messages that
flowed and the discovery frames on the link: ROS 2's (0 expected) apart from swarmd's own.
Namespaces only: on the loopback every drone would share one address and the same ports.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final

from swarmd.bundle.errors import BundleError
from swarmd.bundle.loader import load_bundle
from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd_lab.demo.hosts import NamespaceHosts
from swarmd_lab.demo.scenario import Drone, Scenario
from swarmd_lab.netns import BRIDGE, stop_processes
from swarmd_lab.ros2_lab import (
    DiscoveryCounts,
    discovery_counts,
    graph_datagrams,
    graph_entity_ids,
    own_host_argv,
    ros2_ports,
    start_capture,
)

NODE_S: Final = 20.0  # how long each node runs (from the end of discovery)
CAPTURE_START_S: Final = 10.0
STOP_TIMEOUT_S: Final = 10.0


@dataclass(frozen=True, slots=True)
class Ros2Result:
    listener: dict[str, Any] | None  # the listener's JSON line (swarmd_lab.ros2_node)
    talkers: int
    counts: DiscoveryCounts | None
    graph: int | None = None  # rmw's ros_discovery_info datagrams on the link (0 expected)

    @property
    def ok(self) -> bool:
        if self.listener is None or self.counts is None:
            return False
        heard = len(self.listener.get("senders") or [])
        return (
            heard == self.talkers
            and bool(self.listener.get("answers"))
            and self.counts.ros2_spdp == 0
            and self.counts.ros2_sedp == 0
            and not self.graph
        )

    def lines(self) -> list[str]:
        if self.listener is None:
            return ["ROS 2: the listener gave no result (see logs/lead.ros2.log)"]
        heard = len(self.listener.get("senders") or [])
        answered = "answered" if self.listener.get("answers") else "not answered"
        out = [
            f"ROS 2 (rclpy through swarmd): the commander's listener got "
            f"{self.listener.get('received', 0)} messages from {heard}/{self.talkers} talkers; "
            f"the Trigger service {answered}"
        ]
        c = self.counts
        if c is not None:
            out.append(
                f"on the link from the drones: ROS 2 SPDP {c.ros2_spdp}, ROS 2 SEDP "
                f"{c.ros2_sedp}, ROS 2 graph (ros_discovery_info) "
                f"{'-' if self.graph is None else self.graph}; swarmd's own SPDP "
                f"{c.spdp_swarmd}; RTPS in all {c.rtps}"
            )
        return out

    def as_json(self) -> dict[str, Any]:
        c = self.counts
        return {
            "talkers": self.talkers,
            "listener": self.listener,
            "link": None
            if c is None
            else {
                "rtps": c.rtps,
                "ros2_spdp": c.ros2_spdp,
                "ros2_sedp": c.ros2_sedp,
                "ros2_graph": self.graph,
                "swarmd_spdp": c.spdp_swarmd,
            },
        }


def available() -> str | None:
    """Why ``ROS2=1`` cannot run here, or None."""
    try:
        import rclpy  # noqa: F401 - only whether it imports
    except ImportError:
        return "the ROS 2 wheels are not installed (scripts/setup.sh installs them)"
    for tool in ("tshark", "unshare"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed"
    return None


class Ros2Demo:
    """The ROS 2 part of one demo run: profiles, capture, nodes, result."""

    def __init__(self, scenario: Scenario, hosts: NamespaceHosts) -> None:
        self.s = scenario
        self.hosts = hosts
        self.profiles = scenario.root / "ros2"
        self.pcap = scenario.root / "link.pcapng"
        self._capture: subprocess.Popen[bytes] | None = None
        self._nodes: list[tuple[Drone, subprocess.Popen[bytes]]] = []
        self._logs: list[IO[bytes]] = []

    def write_profiles(self) -> None:
        argv = [
            sys.executable,
            "-m",
            "swarmd.cli.swarmctl",
            "ros2",
            "profile",
            str(self.s.bundle_path),
            "--trusted-key",
            str(self.s.trusted_key),
            "--out",
            str(self.profiles),
            "--via-swarmd",
        ]
        subprocess.run(argv, check=True, capture_output=True, timeout=60)  # noqa: S603

    def start_capture(self) -> None:
        try:
            self._capture = start_capture(self.hosts.lan.hub, BRIDGE, self.pcap, CAPTURE_START_S)
        except RuntimeError:  # the demo's operator line names no namespace
            raise RuntimeError("tshark did not start capturing on the LAN bridge") from None

    def start_nodes(self) -> None:
        for d in self.s.drones:
            node = "listener" if d.role == "commander" else "talker"
            env = [
                line
                for line in (self.profiles / d.name / f"{node}.env").read_text().splitlines()
                if line and not line.startswith("#")
            ]
            argv = ["env", *env, sys.executable, "-m", "swarmd_lab.ros2_node", node]
            argv += ["--tag", d.name, "--seconds", str(NODE_S)]
            log = self.s.log_path(d, "ros2").open("wb")
            self._logs.append(log)
            wrapped = own_host_argv(argv, self.s.root, d.index)
            self._nodes.append((d, self.hosts.popen(d.index, wrapped, log)))

    def finish(self) -> Ros2Result:
        """Wait for the nodes (they stop by themselves), stop the capture, count."""
        deadline = time.monotonic() + NODE_S + 30
        for _d, proc in self._nodes:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        for log in self._logs:
            log.close()
        self.stop_capture()
        listener: dict[str, Any] | None = None
        for d, _proc in self._nodes:
            if d.role == "commander":
                listener = _last_json(self.s.log_path(d, "ros2"))
        counts = None
        graph = None
        if self.pcap.exists():
            senders = frozenset(d.address for d in self.s.drones)
            with contextlib.suppress(subprocess.SubprocessError, OSError):
                counts = discovery_counts(self.pcap, senders)
            with contextlib.suppress(subprocess.SubprocessError, OSError, BundleError):
                bundle = load_bundle(self.s.bundle_path, self.s.trusted_key, allow_dev=True)
                participants = bundle_ros2_participants(bundle)
                ids = graph_entity_ids(participants)
                graph = graph_datagrams(self.pcap, ids, senders, ros2_ports(participants))
        talkers = sum(1 for d in self.s.drones if d.role != "commander")
        return Ros2Result(listener, talkers, counts, graph)

    def stop_capture(self) -> None:
        if self._capture is not None:
            stop_processes([self._capture], STOP_TIMEOUT_S)


def _last_json(path: Path) -> dict[str, Any] | None:
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return None
    for line in reversed(lines):
        if line.startswith("{"):
            with contextlib.suppress(ValueError):
                value = json.loads(line)
                if isinstance(value, dict):
                    return value
    return None
