"""Graph preloading with real rclpy (issue 19, docs/ros2.md "Graph preloading").

Two drones in network namespaces, each with swarmd (``ros2.relay: true``) and one rclpy node
on the ``--via-swarmd`` profile (its own machine id and ``/dev/shm``); an outsider on the
same bridge. The lead's listener prints its view of the ROS 2 graph every second. Checked:
the lead's node lists drone-1's talker by name (``get_node_names_and_namespaces``), served by
the lead's swarmd; the link carries 0 ``ros_discovery_info`` datagrams and 0 ROS 2 SPDP/SEDP;
graph samples forged from the outsider (under drone-1's talker's graph writer, and under a
graph participant prefix swarmd could have drawn) to every port the lead's node may listen
on never show their node; when drone-1's swarmd stops, the talker leaves the lead's graph.
Assertions are on what arrived, never on elapsed time.
"""

from __future__ import annotations

import json
import secrets
import signal
import subprocess
import time
from pathlib import Path

import pytest
from swarmd_lab import netns, ros2_lab
from swarmd_lab.ros2_lab import discovery_counts, graph_datagrams

from swarmd.bundle.ros2 import Ros2EndpointKind, bundle_ros2_participants
from swarmd.ros2.graph import (
    GRAPH_PREFIX_RANDOM_BYTES,
    NodeEntitiesInfo,
    ParticipantEntitiesInfo,
    encode_entities_info,
    endpoint_entity_id,
    graph_endpoint_id,
    graph_participant_prefix,
    graph_reader_port,
    graph_writer_user_id,
)
from swarmd.rtps.message import Data, Header, Heartbeat, InfoDst, encode_message
from swarmd.rtps.types import ENTITYID_UNKNOWN, EntityId, GuidPrefix, ProtocolVersion, VendorId
from tests.conftest import LanFactory
from tests.daemon_support import daemon_status
from tests.ros2_relay_support import (
    NETNS_MARKS,
    WAIT_S,
    start_relay_swarm,
    write_chatter_bundle,
)

pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")

pytestmark = NETNS_MARKS

RUN_S = 22.0  # both nodes
STOP_DRONE1_AFTER_S = 11.0  # then drone-1's swarmd stops: its talker must leave the graph
CAPTURE_START_S = 10.0
FORGERY_ROUNDS = 5

DRONES = ("lead", "drone-1")


def _forged_graph_sample(
    writer_prefix: GuidPrefix, writer_id: EntityId, victim: GuidPrefix, gid_prefix: bytes
) -> bytes:
    """A ros_discovery_info DATA + HEARTBEAT naming a node ``forged``, as an outsider who
    read the (public) bundle can make it, with a sequence number far ahead."""
    info = ParticipantEntitiesInfo(
        gid_prefix + bytes.fromhex("000001c1"), (NodeEntitiesInfo("/", "forged", (), ()),)
    )
    header = Header(ProtocolVersion(2, 3), VendorId(b"\x01\x0f"), writer_prefix)
    sn = 1 << 40
    return encode_message(
        header,
        [
            InfoDst(victim),
            Data(ENTITYID_UNKNOWN, writer_id, sn, serialized_payload=encode_entities_info(info)),
            Heartbeat(ENTITYID_UNKNOWN, writer_id, sn, sn, 1 << 20),
        ],
    )


def test_a_node_lists_the_other_drones_nodes_with_no_graph_traffic_on_the_air(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(3)  # hosts 0-1: the drones; host 2: an outsider on the same link
    outsider = lan[2]
    files = write_chatter_bundle(workdir, "ros2-graph", [lan[i].address for i in range(2)])
    participants = bundle_ros2_participants(files.bundle)
    lead_p = next(p for p in participants if p.drone == "lead")
    talker_p = next(p for p in participants if p.drone == "drone-1")
    relay = start_relay_swarm(lan, workdir, files, DRONES)
    daemons, socks, nodes = relay.daemons, relay.socks, relay.nodes

    def start_node(i: int, node: str, *extra: str) -> subprocess.Popen[bytes]:
        return nodes.start(i, node, ros2_lab.node_argv(node, RUN_S, *extra))

    pcap = workdir / "link.pcapng"
    capture = ros2_lab.start_capture(lan.hub, netns.BRIDGE, pcap, CAPTURE_START_S)
    victim = GuidPrefix(lead_p.guid_prefix)
    graph_writer = endpoint_entity_id(graph_writer_user_id(participants), Ros2EndpointKind.WRITER)
    forgeries = [
        # as drone-1's talker's own graph writer (the relay does not announce it)
        _forged_graph_sample(
            GuidPrefix(talker_p.guid_prefix),
            graph_endpoint_id(talker_p, Ros2EndpointKind.WRITER),
            victim,
            talker_p.guid_prefix,
        ),
        # as swarmd's graph writer under a prefix it could have drawn (it draws its own)
        _forged_graph_sample(
            graph_participant_prefix(secrets.token_bytes(GRAPH_PREFIX_RANDOM_BYTES)),
            graph_writer,
            victim,
            bytes(12),
        ),
    ]
    # every UDP port the lead's node may listen on from the air: its user port, its graph
    # reader's unique-flow port, Fast DDS's stock unique-flow ports, the relay's
    reader_port = graph_reader_port(lead_p, participants)
    ports = sorted(
        {lead_p.user_port, lead_p.metatraffic_port, reader_port, 7399, *range(7000, 7004)}
    )
    try:
        listener = start_node(0, "listener", "--tag", "lead", "--graph-every", "1")
        talker = start_node(1, "talker", "--tag", "drone-1")
        sender = outsider.socket()
        try:
            for _ in range(FORGERY_ROUNDS):
                for forgery in forgeries:
                    for port in ports:
                        sender.sendto(forgery, (lan[0].address, port))
                time.sleep(1.0)  # bounded: FORGERY_ROUNDS x 2 x ports datagrams in all
        finally:
            sender.close()
        time.sleep(max(0.0, STOP_DRONE1_AFTER_S - FORGERY_ROUNDS))
        status_before = daemon_status(socks[0])
        daemons[1].send_signal(signal.SIGTERM)
        assert daemons[1].wait(timeout=WAIT_S) == 0
        out, _ = listener.communicate(timeout=RUN_S + 30)
        talker.communicate(timeout=RUN_S + 30)
        assert listener.returncode == 0 and talker.returncode == 0
        status_after = daemon_status(socks[0])
    finally:
        capture.terminate()
        capture.wait(timeout=10)
    lines = [json.loads(x) for x in out.decode().splitlines() if x.startswith("{")]
    snapshots = [x for x in lines if "graph" in x]
    result = lines[-1]
    drones = frozenset(lan[i].address for i in range(2))
    graph_ids = ros2_lab.graph_entity_ids(participants) | {f"0x{graph_writer.value.hex()}"}
    air_ports = ros2_lab.ros2_ports(participants) | frozenset(ports)
    graph_on_air = graph_datagrams(pcap, graph_ids, drones, air_ports)
    forged_seen = graph_datagrams(pcap, graph_ids, frozenset({outsider.address}), air_ports)
    counts = discovery_counts(pcap, drones)
    print(
        f"\nlistener graph: {snapshots}\nresult: {result}\nlink from the drones: {counts}; "
        f"ros_discovery_info datagrams {graph_on_air}; forged seen on the link {forged_seen}"
        f"\nlead relay: {status_before['ros2']['graph']} {status_after['ros2']['counters']}"
    )
    # drone-1's talker is in the lead's graph by name, its publisher counted
    seen = [s for s in snapshots if "/talker" in s["nodes"]]
    assert seen, snapshots
    assert any(s["publishers"] >= 1 for s in seen), snapshots
    assert "drone-1" in result["senders"]
    # the forgeries crossed the link and never showed up
    assert forged_seen >= FORGERY_ROUNDS * 2
    assert not any("/forged" in s["nodes"] for s in snapshots), snapshots
    # withdrawn once drone-1's swarmd stopped (the lead's relay disposes its participants)
    assert "/talker" not in snapshots[-1]["nodes"], snapshots[-1]
    # no graph traffic and no ROS 2 discovery on the air
    assert graph_on_air == 0
    assert counts.ros2_spdp == 0 and counts.ros2_sedp == 0
    counters = status_after["ros2"]["counters"]
    assert counters["graph_tx_data"] >= 1 and counters["graph_rx_acknack"] >= 1, counters
    daemons[0].send_signal(signal.SIGTERM)
    assert daemons[0].wait(timeout=WAIT_S) == 0
