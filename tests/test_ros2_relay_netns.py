"""Stock rclpy nodes on three drones find each other through swarmd (issue 19, docs/ros2.md).

Each drone is a network namespace running swarmd with ``ros2.relay: true`` and real rclpy
nodes started with the profiles ``swarmctl ros2 profile --via-swarmd`` writes (their
discovery on [::1] only, swarmd's relay their one initial peer), each node in a private
mount namespace with the drone's own machine id and ``/dev/shm`` (``swarmd_lab.ros2_lab``).
A fourth namespace on the same bridge is an outsider that forges a stock ROS 2 participant.

One run checks, in order of the issue's list: messages on the declared topic from both
members and the service across drones; 0 ROS 2 SPDP and 0 SEDP datagrams on the link (and
swarmd's own SPDP, counted apart); a talker restarted under the same GUID prefix is heard
again; a stopped talker is lost from the listener's graph on another drone (its relay tells
the others through swarmd's signed SPDP, theirs dispose it) and is back when it starts
again; a drone's swarmd restarted (SIGTERM: its peers dispose its ROS 2 participants, then
find it again) and the nodes' traffic resumes; the forged participant reaches no node and is
not relayed; an endpoint the bundle does not hold is reported by swarmd by node.
Assertions are on what arrived and on the daemons' status, never on elapsed time.
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab import netns, ros2_lab
from swarmd_lab.ros2_lab import discovery_counts

from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp
from swarmd.rtps.types import Duration, GuidPrefix, ProtocolVersion, VendorId
from tests.conftest import LanFactory
from tests.daemon_support import daemon_status, matched_counts, ros2_profiles, until
from tests.ros2_relay_support import (
    NETNS_MARKS,
    ROS2_DOMAIN,
    WAIT_S,
    start_relay_swarm,
    write_chatter_bundle,
)

pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = NETNS_MARKS

LISTEN_S = 40.0  # the listener and drone-2's talker run through every step below
FIRST_LIFE_S = 8.0  # drone-1's talker, before its restart
SECOND_LIFE_S = 16.0
CAPTURE_START_S = 10.0
FORGERY_ROUNDS = 5
# a talker's messages that may still be in flight (or lost to the restart) at the end
TAIL_MESSAGES = 15

DRONES = ("lead", "drone-1", "drone-2")


def _until(cond: Callable[[], bool], what: Callable[[], str]) -> None:
    until(cond, what, WAIT_S)


def _status(sock: Path) -> dict[str, Any]:
    return daemon_status(sock)


def _start_capture(hub: str, pcap: Path) -> subprocess.Popen[bytes]:
    return ros2_lab.start_capture(hub, netns.BRIDGE, pcap, CAPTURE_START_S)


def _forged_spdp(attacker: str) -> bytes:
    """A stock-looking Fast DDS participant in the ROS 2 domain, all of its locators at the
    attacker, every builtin endpoint announced (what stock Fast DDS took from outsiders:
    reference/ros2-fastdds-facts.md, "Hostile input")."""
    prefix = GuidPrefix(bytes.fromhex("010f0bad0000000000000001"))
    return encode_spdp(
        SpdpParticipant(
            prefix,
            protocol_version=ProtocolVersion(2, 3),
            vendor_id=VendorId(b"\x01\x0f"),
            domain_id=ROS2_DOMAIN,
            metatraffic_unicast_locators=(Locator.udpv4(attacker, 7410),),
            default_unicast_locators=(Locator.udpv4(attacker, 7411),),
            lease_duration=Duration(20, 0),
            builtin_endpoints=0xFC3F,
            entity_name="/",
        ),
        sequence_number=1,
        timestamp=None,
    )


def test_ros2_nodes_discover_through_swarmd_with_no_ros2_discovery_on_the_air(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(4)  # hosts 0-2: the drones; host 3: an outsider on the same link
    outsider = lan[3]
    files = write_chatter_bundle(workdir, "ros2-relay", [lan[i].address for i in range(3)])
    relay = start_relay_swarm(lan, workdir, files, DRONES)
    swarm, daemons, socks, nodes = relay.swarm, relay.daemons, relay.socks, relay.nodes
    logs = swarm.logs

    def start_node(i: int, node: str, seconds: float, *extra: str) -> subprocess.Popen[bytes]:
        return nodes.start(i, node, ros2_lab.node_argv(node, seconds, *extra))

    def result(proc: subprocess.Popen[bytes], seconds: float) -> dict[str, Any]:
        stdout, _ = proc.communicate(timeout=seconds + 30)
        assert proc.returncode == 0
        value: dict[str, Any] = json.loads(stdout.decode().strip().splitlines()[-1])
        return value

    attacker_rx = [outsider.socket() for _ in range(2)]
    for sock, port in zip(attacker_rx, (7410, 7411), strict=True):
        sock.bind((outsider.address, port))
        sock.setblocking(False)
    pcap = workdir / "link.pcapng"
    capture = _start_capture(lan.hub, pcap)
    try:
        matched_log = workdir / "listener-matched.jsonl"
        listener = start_node(
            0, "listener", LISTEN_S, "--tag", "lead", "--matched-log", str(matched_log)
        )
        steady = start_node(2, "talker", LISTEN_S, "--tag", "drone-2")
        first = start_node(1, "talker", FIRST_LIFE_S, "--tag", "drone-1")
        _until(lambda: 2 in matched_counts(matched_log), lambda: str(matched_counts(matched_log)))
        first_result = result(first, FIRST_LIFE_S)
        # drone-1's talker has stopped (its DATA(p[UD]) reached its relay only): the lead's
        # listener loses it, through drone-1's signed liveness and the lead's relay
        _until(
            lambda: matched_counts(matched_log)[-1:] == [1],
            lambda: str(matched_counts(matched_log)),
        )
        # the lead's node and swarmd bind discovery on [::1] only (ss: local address column)
        sockets = lan[0].run(["ss", "-uanH"]).stdout.split("\n")
        local_ends = [line.split()[3] for line in sockets if len(line.split()) > 3]
        listener_meta = next(
            p.metatraffic_port for p in bundle_ros2_participants(files.bundle) if p.drone == "lead"
        )
        bound = sorted(e for e in local_ends if e.endswith((f":{listener_meta}", ":7399")))
        print(f"\nlead's discovery sockets: {bound}")
        assert bound == sorted([f"[::1]:{listener_meta}", "[::1]:7399"]), local_ends
        # the same node again, same GUID prefix, a new process; with an undeclared topic
        second = start_node(
            1, "talker", SECOND_LIFE_S, "--tag", "drone-1-again", "--undeclared", "/extra"
        )
        _until(
            lambda: matched_counts(matched_log)[-1:] == [2],
            lambda: str(matched_counts(matched_log)),
        )
        # drone-2's swarmd restarts while its talker runs: its peers dispose its ROS 2
        # participants at their nodes (DATA(p[UD]) from swarmd), then find it again
        daemons[2].send_signal(signal.SIGTERM)
        assert daemons[2].wait(timeout=WAIT_S) == 0
        swarm.start(2)
        # the outsider forges a ROS 2 participant at every port a node or swarmd has on
        # the drones' address (bounded: FORGERY_ROUNDS x drones x ports)
        forgery = _forged_spdp(outsider.address)
        participants = bundle_ros2_participants(files.bundle)
        ports = sorted(
            {p.metatraffic_port for p in participants}
            | {p.user_port for p in participants}
            | {7000, 7399}
        )
        sender = outsider.socket()
        try:
            for _ in range(FORGERY_ROUNDS):
                for i in range(3):
                    for port in ports:
                        sender.sendto(forgery, (lan[i].address, port))
                time.sleep(0.2)
        finally:
            sender.close()
        second_result = result(second, SECOND_LIFE_S)
        steady_result = result(steady, LISTEN_S)
        listener_result = result(listener, LISTEN_S)
        # every node has now left: each drone's relay shows the others' nodes stopped
        _until(
            lambda: all(
                {r["state"] for r in _status(s)["ros2"]["remote"]} == {"node stopped"}
                for s in socks
            ),
            lambda: str([[r["state"] for r in _status(s)["ros2"]["remote"]] for s in socks]),
        )
        statuses = [_status(s) for s in socks]
    finally:
        capture.terminate()
        capture.wait(timeout=10)
    answered_outsider = sum(_drain(sock) for sock in attacker_rx)
    for sock in attacker_rx:
        sock.close()
    counts = discovery_counts(pcap, frozenset(lan[i].address for i in range(3)))
    ros2_participants = bundle_ros2_participants(files.bundle)
    graph = ros2_lab.graph_datagrams(
        pcap,
        ros2_lab.graph_entity_ids(ros2_participants),
        frozenset(lan[i].address for i in range(3)),
        ros2_lab.ros2_ports(ros2_participants),
    )
    forged = discovery_counts(pcap, frozenset({outsider.address}))
    print(f"\nrelay counters: {[st['ros2']['counters'] for st in statuses]}")
    print(
        f"\nlink, from the drones: {counts}; ROS 2 SPDP {counts.ros2_spdp}, ROS 2 SEDP "
        f"{counts.ros2_sedp}, swarmd SPDP {counts.spdp_swarmd}, ROS 2 graph (ros_discovery_info) "
        f"{graph}; from the outsider: {forged}; "
        f"listener {listener_result}"
    )

    # messages from both members, the service answered across drones
    assert {"drone-1", "drone-1-again", "drone-2"} <= set(listener_result["senders"])
    assert listener_result["answers"] and listener_result["answers"][0].startswith("triggered")
    # the restarted talker is heard to its last messages; drone-2's talker after its
    # swarmd's restart too (its last messages were sent long after the restart)
    last = listener_result["last"]
    assert last["drone-1-again"] >= second_result["sent"] - TAIL_MESSAGES, last
    assert last["drone-2"] >= steady_result["sent"] - TAIL_MESSAGES, last
    assert first_result["sent"] > 0
    # no ROS 2 discovery on the air; swarmd's own SPDP is there (and is all the SPDP)
    assert counts.ros2_spdp == 0
    assert counts.ros2_sedp == 0
    # nor rmw's graph topic: it matches only between the nodes of one drone
    assert graph == 0
    assert counts.spdp_swarmd > 0
    assert counts.multicast <= counts.spdp_swarmd  # swarmd's announcements only
    # the forged participant reached no node (no node sent it anything) and no relay
    assert answered_outsider == 0
    # the capture did see them (tshark takes port 7000 for AFS and does not count it)
    assert forged.spdp >= FORGERY_ROUNDS * 3 * (len(ports) - 1)
    for st in statuses:
        ros2 = st["ros2"]
        assert ros2["unknown"] == [], ros2
        assert all(r["guid_prefix"] != "10f0bad:0:1" for r in ros2["remote"])
        assert ros2["counters"]["rx_malformed"] == 0
        assert ros2["counters"]["rx_wlp"] == 0  # relayed participants announce no WLP reader
    # every relay heard its node (which has now left: its DATA(p[UD]) on shutdown) and
    # tells the others; the lead's listener saw drone-1's talker go and come back
    for st in statuses:
        assert [r["state"] for r in st["ros2"]["local"]] == ["left"], st["ros2"]
        assert st["ros2"]["alive_bitmap"] == "00"
    matched = matched_counts(matched_log)
    assert matched[matched.index(2) :][:3] == [2, 1, 2], matched
    # the undeclared /extra publisher of drone-1's talker is reported, by node
    undeclared = statuses[1]["ros2"]["local"][0]["undeclared_endpoints"]
    assert [u["kind"] for u in undeclared] == ["writer"], undeclared
    assert statuses[0]["ros2"]["local"][0]["undeclared_endpoints"] == []
    # drone-2's restart went through the relay: disposed at the lead's node, then relayed
    lead_log = [json.loads(x) for x in logs[0].read_text().splitlines() if x.startswith("{")]
    drone2 = [
        e["up"] for e in lead_log if e["event"] == "ros2_relay_peer" and e["peer"] == "drone-2"
    ]
    assert drone2 == [True, False, True], drone2
    for d in daemons:
        d.send_signal(signal.SIGTERM)
        assert d.wait(timeout=WAIT_S) == 0


def _drain(sock: Any) -> int:
    received = 0
    while True:
        try:
            sock.recv(65536)
        except BlockingIOError:
            return received
        received += 1


def test_the_same_forgery_reaches_a_node_on_the_plain_route(
    lan_factory: LanFactory, workdir: Path
) -> None:
    """The control for the forgery above: the plain generated profile (no swarmd) binds the
    node's discovery port on the drone's address, and stock Fast DDS answers the forged
    participant (reference/ros2-fastdds-facts.md, "Hostile input")."""
    lan = lan_factory(2)  # host 0: the lead's listener; host 1: the outsider
    outsider = lan[1]
    base = lan[0].address.rsplit(".", 1)[0]
    files = write_chatter_bundle(
        workdir, "ros2-relay", [lan[0].address, f"{base}.201", f"{base}.202"]
    )
    profiles = workdir / "profiles"
    code = ros2_profiles(files, profiles, "--drone", "lead")
    assert code == 0
    rx = outsider.socket()
    rx.bind((outsider.address, 7410))
    rx.setblocking(False)
    lead_host = ros2_lab.NodeLauncher([lan[0]], ["lead"], profiles, workdir)
    node = lead_host.start(0, "listener", ros2_lab.node_argv("listener", 6))
    lead = next(p for p in bundle_ros2_participants(files.bundle) if p.drone == "lead")
    sender = outsider.socket()
    try:
        time.sleep(1.0)  # the node is up (a bounded wait: the assertion is on replies)
        for _ in range(FORGERY_ROUNDS):
            sender.sendto(_forged_spdp(outsider.address), (lan[0].address, lead.metatraffic_port))
            time.sleep(0.2)
        node.communicate(timeout=40)
    finally:
        sender.close()
    answered = _drain(rx)
    rx.close()
    assert answered > 0
