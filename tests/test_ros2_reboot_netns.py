"""A drone's ROS 2 data reaches its peers again after an in-air reboot (issue 20, docs/ros2.md
"A restart under the same GUIDs").

Two drones in network namespaces, each with swarmd on the relay route (``ros2.relay: true``)
and one real rclpy node (``swarmd_lab.ros2_lab``: its own machine id and ``/dev/shm``): the
lead's listener, drone-1's talker. swarmd's discovery lease (20 s, as in flight) outlasts
every outage below, so the lead's swarmd never loses drone-1: the attack-style reboot of the
flight scenario (``flight_run --scenarios reboot --contenders ros2-swarmd``).

The bundle fixes each node's GUID prefix and entity ids, so a restarted talker's writer has
the GUID of its earlier life and numbers its samples from 1 again. The listener's reader
still holds the earlier writer proxy (its relay renews it) and drops every sample numbered
at or below the last one it took (DDSI-RTPS 2.5 8.4.12, the reliable StatefulReader: its
writer proxy keeps the highest sequence number received). The talker's first life is
therefore made longer than the bound of its second: before the fix (698603e) not one
message of the second life arrived, in either case.

1. drone-1's swarmd and talker are SIGKILLed and restarted, the state dir kept (a reboot);
2. drone-1's talker alone is SIGKILLed and restarted at once, swarmd running;
3. as 2, with a second node on drone-1 (a subscriber, the monitor) that finds the talker
   directly on [::1] and holds its writer proxy too;
4. as 3, the talker down longer than its own lease: the monitor drops it by lease, which
   keeps the reader's record of the writer's last sequence number (Fast DDS
   ``BaseReader::may_remove_history_record``), and a dispose removes only the numbers of
   writers it has matched again (``SWARMD_ROS2_PCAP=dir`` captures drone-1's loopback and
   shows the SPDP datagrams about the talker's new life at the monitor).

In each, the subscribers must hear the new life within ``RECOVER_S`` (a liveness bound on
real processes with generous slack; nothing else is timed).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab import ros2_lab, rtps_timeline

from swarmd.bundle.ros2 import bundle_ros2_participants
from tests.conftest import LanFactory
from tests.daemon_support import (
    BundleFiles,
    Daemons,
    daemon_status,
    relay_config,
    ros2_profiles,
    run_domain,
    until,
    write_mission_bundle,
)

pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = [
    pytest.mark.netns,
    pytest.mark.skipif(shutil.which("unshare") is None, reason="unshare not installed"),
]

WAIT_S = 30.0
# the talker's first life after the listener first heard it: at 5 messages/s, ~75 samples,
# more than its second life can send within RECOVER_S (so none would pass an old proxy)
FIRST_LIFE_S = 15.0
RECOVER_S = 12.0
SECOND_LIFE_S = 30.0
LISTEN_S = 90.0
ROS2_DOMAIN = 7
# swarmd's discovery: quick announcements, the flight's 20 s lease (no PeerLost in a reboot)
DISCOVERY = "{t_min_s: 0.2, t_max_s: 0.5, lease_s: 20}"
DRONES = ("lead", "drone-1")
# the talker's own SPDP lease in case 4, set in its generated profile (20 s there, Fast DDS's
# default): short, so that the test's outage outlasts it within a few seconds
SHORT_NODE_LEASE_S = 4
PAST_LEASE_S = 3 * SHORT_NODE_LEASE_S


def _senders(log: Path) -> dict[str, dict[str, Any]]:
    """The listener's first message per sender tag (``ros2_node --senders-log``)."""
    if not log.exists():
        return {}
    rows = [json.loads(line) for line in log.read_text().splitlines() if line]
    return {row["sender"]: row for row in rows}


def _log(log: Path, peer: str, *names: str) -> list[dict[str, Any]]:
    """The daemon's JSON log lines about ``peer`` whose event is one of ``names``."""
    return [
        e
        for e in (json.loads(x) for x in log.read_text().splitlines() if x.startswith("{"))
        if e.get("peer") == peer and e["event"] in names
    ]


@pytest.mark.parametrize("swarmd_too", [True, False], ids=["reboot", "node-only"])
def test_a_restarted_drones_ros2_samples_reach_its_peer_again(
    lan_factory: LanFactory, workdir: Path, swarmd_too: bool
) -> None:
    lan = lan_factory(2)
    text = ros2_lab.chatter_mission(
        "ros2-reboot",
        run_domain(),
        [lan[0].address, lan[1].address],
        ros2_domain=ROS2_DOMAIN,
        discovery=DISCOVERY,
    )
    files: BundleFiles = write_mission_bundle(workdir, text, "ros2-reboot", "ros2-reboot.yaml")
    profiles = workdir / "profiles"
    assert ros2_profiles(files, profiles, "--via-swarmd") == 0
    swarm = Daemons(lan, workdir, files, DRONES, extra=relay_config())
    daemons = swarm.start_all(WAIT_S)
    nodes = ros2_lab.NodeLauncher(lan, DRONES, profiles, workdir)
    senders_log = workdir / "listener-senders.jsonl"

    def talker(tag: str, seconds: float) -> subprocess.Popen[bytes]:
        argv = ros2_lab.node_argv("talker", seconds, "--tag", tag)
        return nodes.start(1, "talker", argv, stdout=subprocess.DEVNULL)

    listener = nodes.start(
        0,
        "listener",
        ros2_lab.node_argv("listener", LISTEN_S, "--senders-log", str(senders_log)),
        stdout=subprocess.DEVNULL,
    )
    first = talker("life-1", LISTEN_S)
    until(lambda: "life-1" in _senders(senders_log), lambda: _senders(senders_log), WAIT_S)
    time.sleep(FIRST_LIFE_S)  # the first life numbers its samples past the second's bound

    first.send_signal(signal.SIGKILL)  # no DATA(p[UD]): the node's lease has not run out
    first.wait(timeout=WAIT_S)
    if swarmd_too:
        daemons[1].send_signal(signal.SIGKILL)
        daemons[1].wait(timeout=WAIT_S)
        swarm.start(1)  # the same config and state dir: its boot epoch rises
        until(
            lambda: daemon_status(swarm.socks[1])["ros2"] is not None,
            lambda: "drone-1's swarmd is not up",
            WAIT_S,
        )
    second = talker("life-2", SECOND_LIFE_S)
    restarted_at = time.monotonic()
    try:
        until(
            lambda: "life-2" in _senders(senders_log),
            lambda: f"the listener heard {sorted(_senders(senders_log))}",
            RECOVER_S,
        )
    finally:
        # shown, not asserted: from the talker's restart to the poll that saw its message
        print(
            f"\nnew life heard {time.monotonic() - restarted_at:.1f} s after the talker's "
            f"restart; the listener's first message per sender: {_senders(senders_log)}"
        )
        for proc in (second, listener):
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=WAIT_S)
    # the lead's swarmd never lost drone-1: a reboot is its signed restart (a higher epoch)
    lead_log = swarm.logs[0]
    events = [e["event"] for e in _log(lead_log, "drone-1", "peer_lost", "peer_restarted")]
    assert events == (["peer_restarted"] if swarmd_too else []), events
    # and the lead's relay disposed drone-1's node and announced it again, once: for the
    # reboot on the restart, for the node alone on drone-1's signed restart count
    relayed = _log(lead_log, "drone-1", "ros2_relay_peer", "ros2_remote_node_liveness")
    again = [(e["event"], e["up"]) for e in relayed if e["restarted"]]
    want = "ros2_relay_peer" if swarmd_too else "ros2_remote_node_liveness"
    assert again == [(want, True)], relayed
    for d in swarm.procs:
        d.send_signal(signal.SIGTERM)
        assert d.wait(timeout=WAIT_S) == 0


def _show_arrivals(pcap: Path, port: int, prefix: bytes) -> None:
    """Shown, not asserted (``SWARMD_ROS2_PCAP``): the SPDP datagrams about the talker's
    last life at the monitor's port, the relay's and its own, in the order they came."""
    arrivals = rtps_timeline.last_life(rtps_timeline.read_arrivals(pcap, port, prefix.hex()))
    start = arrivals[0].at if arrivals else 0.0
    for a in arrivals[:32]:
        kind = "dispose" if a.disposed else f"alive, {a.static_endpoints} static endpoints"
        who = "relay" if a.from_relay else "node"
        print(f"  at the monitor {a.at - start:+.3f} s: {who} sn {a.sequence_number} {kind}")


def _shorten_lease(profile: Path, lease_s: int) -> None:
    """The node's SPDP lease (and announcement period, a quarter of it) in its generated
    profile (swarmd.ros2.profile, ``leaseDuration``)."""
    text = profile.read_text()
    lease = re.compile(r"<leaseDuration><sec>\d+</sec></leaseDuration>")
    period = re.compile(r"<leaseAnnouncement><sec>\d+</sec></leaseAnnouncement>")
    assert lease.search(text) and period.search(text), profile
    text = lease.sub(f"<leaseDuration><sec>{lease_s}</sec></leaseDuration>", text)
    text = period.sub(
        f"<leaseAnnouncement><sec>{max(1, lease_s // 4)}</sec></leaseAnnouncement>", text
    )
    profile.write_text(text)


@pytest.mark.parametrize("past_lease", [False, True], ids=["at-once", "past-its-lease"])
def test_a_restarted_nodes_samples_reach_its_sibling_on_the_same_drone_again(
    lan_factory: LanFactory, workdir: Path, past_lease: bool
) -> None:
    """Nodes of one drone find each other directly on [::1] (docs/ros2.md, "Several nodes
    on one drone"): drone-1's monitor holds the talker's writer proxy as the lead's
    listener does. The talker alone is SIGKILLed and restarted at once, or after more than
    its own lease (the monitor then drops it by lease and keeps its old numbers)."""
    lan = lan_factory(2)
    # investigation aid: drone-1's loopback captured (tshark) and the talker's last life's
    # SPDP datagrams at the monitor shown (docs/ros2.md, "A node back after its own lease")
    pcap_dir = os.environ.get("SWARMD_ROS2_PCAP")
    if pcap_dir:
        pcap = Path(pcap_dir) / "drone-1-lo.pcapng"
        pcap.parent.mkdir(parents=True, exist_ok=True)
        capture = ros2_lab.start_capture(lan[1].name, "lo", pcap, WAIT_S)
    nodes_declared = (ros2_lab.TALKER_NODE, ros2_lab.MONITOR_NODE, ros2_lab.LISTENER_NODE)
    text = ros2_lab.chatter_mission(
        "ros2-reboot",
        run_domain(),
        [lan[0].address, lan[1].address],
        nodes_declared,
        ros2_domain=ROS2_DOMAIN,
        discovery=DISCOVERY,
    )
    files = write_mission_bundle(workdir, text, "ros2-reboot", "ros2-reboot.yaml")
    profiles = workdir / "profiles"
    assert ros2_profiles(files, profiles, "--via-swarmd") == 0
    if past_lease:
        _shorten_lease(profiles / "drone-1" / "talker.xml", SHORT_NODE_LEASE_S)
    swarm = Daemons(lan, workdir, files, DRONES, extra=relay_config())
    swarm.start_all(WAIT_S)
    nodes = ros2_lab.NodeLauncher(lan, DRONES, profiles, workdir)
    logs = {who: workdir / f"{who}-senders.jsonl" for who in ("lead", "monitor")}

    def subscriber(i: int, node: str, log: Path) -> subprocess.Popen[bytes]:
        argv = ros2_lab.node_argv("listener", LISTEN_S, "--senders-log", str(log), name=node)
        return nodes.start(i, node, argv, stdout=subprocess.DEVNULL)

    def talker(tag: str) -> subprocess.Popen[bytes]:
        argv = ros2_lab.node_argv("talker", LISTEN_S, "--tag", tag)
        return nodes.start(1, "talker", argv, stdout=subprocess.DEVNULL)

    listener = subscriber(0, "listener", logs["lead"])
    monitor = subscriber(1, "monitor", logs["monitor"])
    first = talker("life-1")
    until(
        lambda: all("life-1" in _senders(log) for log in logs.values()),
        lambda: {who: sorted(_senders(log)) for who, log in logs.items()},
        WAIT_S,
    )
    time.sleep(FIRST_LIFE_S)
    first.send_signal(signal.SIGKILL)
    first.wait(timeout=WAIT_S)
    if past_lease:
        time.sleep(PAST_LEASE_S)  # the monitor drops the talker by lease
        state = {r["node"]: r["state"] for r in daemon_status(swarm.socks[1])["ros2"]["local"]}
        assert state["talker"] == "lease expired", state
    second = talker("life-2")
    restarted_at = time.monotonic()
    try:
        until(
            lambda: all("life-2" in _senders(log) for log in logs.values()),
            lambda: {who: sorted(_senders(log)) for who, log in logs.items()},
            RECOVER_S,
        )
    finally:
        print(
            f"\nnew life heard by both {time.monotonic() - restarted_at:.1f} s after the "
            f"talker's restart: { {who: _senders(log) for who, log in logs.items()} }"
        )
        drone_1 = daemon_status(swarm.socks[1])["ros2"]
        print(f"drone-1's relay: {drone_1['counters']}, {drone_1['local']}")
        for proc in (second, monitor, listener):
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=WAIT_S)
        if pcap_dir:
            capture.terminate()
            capture.wait(timeout=WAIT_S)
            ours = {p.node.name: p for p in bundle_ros2_participants(files.bundle)}
            port, prefix = ours["monitor"].metatraffic_port, ours["talker"].guid_prefix
            _show_arrivals(pcap, port, prefix)
    # drone-1's relay disposed the talker at the monitor once; the lead's relay re-matched
    # it on drone-1's signed restart count (past its lease: its bit went down, a dispose,
    # and up again, an announcement: no restart to count there)
    counters = daemon_status(swarm.socks[1])["ros2"]["counters"]
    assert counters["tx_sibling_dispose"] == 1, counters
    # past its lease the dispose waited for the talker's own DATA(p) to list its writers
    assert counters["sibling_dispose_deferred"] == (1 if past_lease else 0), counters
    remote_restarts = daemon_status(swarm.socks[0])["ros2"]["counters"]["remote_restarts"]
    assert remote_restarts == (0 if past_lease else 1)
    for d in swarm.procs:
        d.send_signal(signal.SIGTERM)
        assert d.wait(timeout=WAIT_S) == 0
