"""Set-up shared by the tests that run stock rclpy nodes on swarmd's relay route, one drone per
network namespace (docs/ros2.md): the chatter mission's dev-signed bundle, the
``--via-swarmd`` profiles, one swarmd per drone with ``ros2.relay: true`` (a 6 s lease), and
a launcher for the nodes (``swarmd_lab.ros2_lab``). Each test adds its own nodes, capture and
attacks; this module only saves them the same twenty lines."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
from swarmd_lab import ros2_lab
from swarmd_lab.netns import Lan

from tests.daemon_support import (
    BundleFiles,
    Daemons,
    relay_config,
    ros2_profiles,
    run_domain,
    write_mission_bundle,
)

# every such test: root for namespaces, tshark for the link capture, unshare for the nodes'
# own mount namespaces (their machine id and /dev/shm)
NETNS_MARKS = [
    pytest.mark.netns,
    pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark not installed"),
    pytest.mark.skipif(shutil.which("unshare") is None, reason="unshare not installed"),
]

WAIT_S = 30.0  # each bounded wait: daemons discovering each other, nodes matching
ROS2_DOMAIN = 7


def write_chatter_bundle(
    workdir: Path,
    swarm: str,
    addresses: Sequence[str],
    nodes: Sequence[str] = (ros2_lab.TALKER_NODE, ros2_lab.LISTENER_NODE),
) -> BundleFiles:
    """The dev-signed bundle of ``ros2_lab.chatter_mission`` for swarm ``swarm``: one drone per
    address, ``nodes`` its ROS 2 nodes, on ROS 2 domain ``ROS2_DOMAIN``."""
    text = ros2_lab.chatter_mission(swarm, run_domain(), addresses, nodes, ros2_domain=ROS2_DOMAIN)
    return write_mission_bundle(workdir, text, swarm, f"{swarm}.yaml")


@dataclass(frozen=True)
class RelaySwarm:
    """A running swarm on the relay route: its bundle, the nodes' profiles, the daemons (all
    discovered each other) and the launcher that starts a node on drone ``i``."""

    files: BundleFiles
    swarm: Daemons
    daemons: list[subprocess.Popen[bytes]]
    nodes: ros2_lab.NodeLauncher

    @property
    def socks(self) -> list[Path]:
        return self.swarm.socks


def start_relay_swarm(
    lan: Lan, workdir: Path, files: BundleFiles, drones: Sequence[str]
) -> RelaySwarm:
    """Write ``files``' ``--via-swarmd`` profiles, start one swarmd per drone on ``lan``'s first
    hosts (``drones[i]`` on ``lan[i]``) and wait until each has discovered the others."""
    profiles = workdir / "profiles"
    assert ros2_profiles(files, profiles, "--via-swarmd") == 0
    swarm = Daemons(lan, workdir, files, drones, extra=relay_config(lease_s=6))
    daemons = swarm.start_all(WAIT_S)
    return RelaySwarm(files, swarm, daemons, ros2_lab.NodeLauncher(lan, drones, profiles, workdir))
