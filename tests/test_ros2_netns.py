"""Real rclpy nodes on three emulated drones with the profiles ``swarmctl ros2 profile`` writes
(issue 19): messages flow on the declared topic, the declared service answers across drones,
and the link carries SPDP but no SEDP (static EDP from the bundle).

Each drone is a network namespace (``swarmd_lab.netns``) plus a private mount namespace with
its own ``/etc/machine-id`` and ``/dev/shm`` (``swarmd_lab.ros2_lab.host_argv``): without them
Fast DDS 3.2 takes the three "hosts" for one and moves the data through shared memory.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
from swarmd_lab import netns, ros2_lab
from swarmd_lab.ros2_lab import discovery_counts

from swarmd.cli.swarmctl import main as swarmctl

rclpy = pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = [
    pytest.mark.skipif(netns.unavailable_reason() is not None, reason="no network namespaces"),
    pytest.mark.skipif(shutil.which("tshark") is None, reason="tshark not installed"),
    pytest.mark.skipif(shutil.which("unshare") is None, reason="unshare not installed"),
]

RUN_S = 14.0
CAPTURE_START_S = 10.0


def _start_capture(hub: str, pcap: Path) -> subprocess.Popen[bytes]:
    return ros2_lab.start_capture(hub, netns.BRIDGE, pcap, CAPTURE_START_S)


def test_three_drones_talk_and_call_with_generated_profiles_and_no_sedp(tmp_path: Path) -> None:
    with netns.Lan(3) as lan:
        addresses = [lan[i].address for i in range(3)]
        mission = tmp_path / "mission.yaml"
        mission.write_text(ros2_lab.chatter_mission("ros2-netns", 0, addresses, discovery=None))
        bundle = tmp_path / "s.swb"
        assert swarmctl(["bundle", "build", str(mission), "-o", str(bundle), "--unsigned-dev"]) == 0
        out = tmp_path / "profiles"
        code = swarmctl(["ros2", "profile", str(bundle), "--allow-dev", "--out", str(out)])
        assert code == 0
        pcap = tmp_path / "link.pcapng"
        capture = _start_capture(lan.hub, pcap)
        drones = [("lead", "listener"), ("drone-1", "talker"), ("drone-2", "talker")]
        nodes = ros2_lab.NodeLauncher(lan, [drone for drone, _ in drones], out, tmp_path)
        procs = []
        try:
            for i, (drone, node) in enumerate(drones):
                argv = ros2_lab.node_argv(node, RUN_S, "--tag", drone)
                procs.append(nodes.start(i, node, argv))
            results = []
            for proc in procs:
                stdout, _ = proc.communicate(timeout=RUN_S + 30)
                assert proc.returncode == 0
                results.append(json.loads(stdout.decode().strip().splitlines()[-1]))
        finally:
            capture.terminate()
            capture.wait(timeout=10)
        listener = results[0]
        assert listener["senders"] == ["drone-1", "drone-2"], listener
        assert listener["received"] > 10
        assert listener["answers"] and listener["answers"][0].startswith("triggered by")
        counts = discovery_counts(pcap)
        print(f"link: {counts}; first message after {listener['first_message_s']:.2f} s")
        assert counts.spdp > 0  # the participants do find each other over the link
        assert counts.sedp == 0  # endpoints come from the bundle's static EDP file
        assert counts.multicast == 0  # unicast-only discovery
