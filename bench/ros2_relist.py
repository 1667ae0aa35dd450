"""Why stock ROS 2 never re-lists a returning drone (issue 20): a small, real reproduction.

Three emulated drones (``swarmd_lab.netns``; each its own machine id and ``/dev/shm``,
``swarmd_lab.ros2_lab.host_argv``, as the ROS 2 contenders run them) with ROS 2's stock
discovery (SIMPLE, SPDP multicast, rclpy 9.1 / rmw_fastrtps_cpp / Fast DDS 3.2 from the
PyPI wheels, ``bench.wifi.ros2_contenders.ros2_env``):

- drone 0: the ``ros2`` contender's commander, ``bench/wifi/peers/ros2_peer.py --events 1``
  (the flight observer: it polls ``get_node_names_and_namespaces``);
- drone 1: the contender's member (a talker on ``/swarm_ready``), the drone that leaves;
- drone 2: a probe node (``probe`` below) that logs its own graph (node namespaces and the
  ``/swarm_ready`` publishers with the node each belongs to) and, after the heal, the graph
  of a fresh participant it opens then (a late joiner: the control).

After ``--settle-s`` drone 1's link is cut both ways (an nftables bridge rule in the hub
drops every frame to or from its veth) for ``--cut-s`` (longer than Fast DDS's 20 s
participant lease), then restored; the run ends ``--after-s`` later. A capture on the bridge
shows what drone 1 sends after the restore: SPDP, SEDP, and its ``ros_discovery_info``
(rmw's graph topic) writer's DATA and HEARTBEAT, and the other participants' ACKNACKs.

    sudo nice -n 19 .venv/bin/python -m bench.ros2_relist [--json] [--out report.json]
    sudo nice -n 19 .venv/bin/python -m bench.ros2_relist --nudge-after-s 10

With ``--nudge-after-s`` drone 1 runs a publishing probe instead of the contender's member
and creates one more publisher that long after the heal: rmw then publishes a new
``ros_discovery_info`` sample, which the observers do take (docs/benchmarks.md, "Flight",
why stock ROS 2 never re-lists a returning drone).

Every wait is bounded; the namespaces and processes go on every exit path (``netns.Lan``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

REPO: Final = Path(__file__).resolve().parents[1]
NODE_NAMESPACE: Final = "/drone"  # bench/wifi/peers/ros2_peer.py NAMESPACE
TOPIC: Final = "/swarm_ready"  # bench/wifi/peers/ros2_peer.py TOPIC
GRAPH_TOPIC: Final = "ros_discovery_info"  # rmw_dds_common's graph topic (DDS name)
PROBE_POLL_S: Final = 0.25
PUBLISH_PERIOD_S: Final = 1.0  # the member's period (bench/wifi/peers/common.py --period)
NUDGE_TOPIC: Final = "/relist_nudge"
DATA_SUBMESSAGE: Final = "0x15"  # DDSI-RTPS 2.5 9.4.5.3 DATA
HEARTBEAT_SUBMESSAGE: Final = "0x07"  # 9.4.5.7
ACKNACK_SUBMESSAGE: Final = "0x06"  # 9.4.5.2
UNKNOWN_NODE: Final = "_NODE_NAME_UNKNOWN_"  # rmw_dds_common's name for an unowned endpoint
CAPTURE_START_S: Final = 10.0
TSHARK_TIMEOUT_S: Final = 120.0
GRAPH_FIELDS: Final = (
    "rtps.guidPrefix.src",
    "rtps.guidPrefix.dst",
    "rtps.sm.wrEntityId",
    "rtps.sm.rdEntityId",
    "rtps.sm.id",
    "rtps.sm.seqNumber",
)
WRITER_KINDS: Final = frozenset({"02", "03"})  # user-defined writer entity kinds
MAX_PROBE_LINES: Final = 10_000
STOP_TIMEOUT_S: Final = 15.0


# ---------------------------------------------------------------- the probe (in a drone)


def graph_view(node: Any) -> dict[str, Any]:
    """What ``node``'s graph lists: node namespaces, and the ``TOPIC`` publishers by the node
    rmw attributes each to (``_NODE_NAMESPACE_UNKNOWN_/_NODE_NAME_UNKNOWN_`` when rmw knows
    the DDS writer from SEDP but not which node owns it)."""
    namespaces = sorted({ns for _, ns in node.get_node_names_and_namespaces()})
    publishers = sorted(
        f"{info.node_namespace}/{info.node_name}"
        for info in node.get_publishers_info_by_topic(TOPIC)
    )
    return {"nodes": namespaces, "publishers": publishers}


def probe(args: argparse.Namespace) -> int:
    """Log the graph on every change until ``--until`` (wall clock). From ``--fresh-at`` also
    the graph of a participant created then; with ``--publish`` publish on ``TOPIC`` as a
    member does; at ``--nudge-at`` create one more publisher (rmw then publishes a new
    ``ros_discovery_info`` sample for this participant)."""
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    def make_node(context: Context | None) -> Any:
        return Node(
            "probe",
            namespace=f"{NODE_NAMESPACE}{args.index}",
            context=context,
            start_parameter_services=False,
            enable_rosout=False,
            parameter_overrides=[Parameter("start_type_description_service", value=False)],
        )

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = make_node(None)
    views: dict[str, Any] = {"probe": node}
    publisher = node.create_publisher(String, TOPIC, 10) if args.publish else None
    last: dict[str, dict[str, Any]] = {}
    fresh_context: Context | None = None
    nudged = False
    lines = seq = 0
    while time.time() < args.until and lines < MAX_PROBE_LINES:
        now = time.time()
        if args.fresh_at is not None and fresh_context is None and now >= args.fresh_at:
            fresh_context = Context()
            rclpy.init(context=fresh_context, signal_handler_options=SignalHandlerOptions.NO)
            views["fresh"] = make_node(fresh_context)
        if args.nudge_at is not None and not nudged and now >= args.nudge_at:
            node.create_publisher(String, NUDGE_TOPIC, 10)
            nudged = True
            print(json.dumps({"probe": "nudge", "t": now}), flush=True)
        if publisher is not None and now >= args.start + seq * PUBLISH_PERIOD_S:
            seq += 1
            publisher.publish(String(data=f"{args.index} {seq}"))
        for name, view_node in views.items():
            view = graph_view(view_node)
            if last.get(name) != view:
                last[name] = view
                print(json.dumps({"probe": name, "t": now, **view}), flush=True)
                lines += 1
        time.sleep(PROBE_POLL_S)
    for view_node in views.values():
        view_node.destroy_node()
    if fresh_context is not None:
        rclpy.try_shutdown(context=fresh_context)
    rclpy.try_shutdown()
    return 0


# ---------------------------------------------------------------- the run (as root)


CUT_TABLE: Final = "ros2_relist"


def cut_rules(port: str) -> str:
    """An nftables table for the hub's bridge that drops every frame to or from ``port``
    (a drone's veth): the drone's own stack sees nothing (no carrier change, no send
    error), as a radio link that fades out. (The box's kernel has no sch_netem.)"""
    return (
        f"table bridge {CUT_TABLE} {{\n"
        "  chain forward {\n"
        "    type filter hook forward priority 0; policy accept;\n"
        f'    iifname "{port}" drop\n'
        f'    oifname "{port}" drop\n'
        "  }\n"
        "}\n"
    )


def set_cut(hub: str, drone: int, on: bool) -> None:
    """Cut (or restore) drone ``drone``'s link in the hub namespace ``hub``."""
    nft = ["ip", "netns", "exec", hub, "nft"]
    if on:
        subprocess.run(  # noqa: S603 - argv list
            [*nft, "-f", "-"], input=cut_rules(f"v{drone}"), text=True, check=True, timeout=10
        )
    else:
        subprocess.run(  # noqa: S603 - argv list
            [*nft, "delete", "table", "bridge", CUT_TABLE], check=True, timeout=10
        )


def _datagram_rows(pcap: Path, *fields: str) -> list[list[str]]:
    """Time, source, destination and ``fields`` of every RTPS datagram in the capture
    (``ros2_lab.rtps_fields``: it finds Fast DDS's graph traffic on UDP 7000/7001 too)."""
    from swarmd_lab.ros2_lab import rtps_fields

    return rtps_fields(
        pcap, "frame.time_epoch", "ip.src", "ip.dst", *fields, timeout_s=TSHARK_TIMEOUT_S
    )


def graph_writer_id(pcap: Path, sender: str) -> str | None:
    """The entity id (``0x00000103``) of ``sender``'s ``ros_discovery_info`` writer, from the
    SEDP it sent: PID_TOPIC_NAME paired with PID_ENDPOINT_GUID (one pair per DATA, several
    DATA per datagram), the writer being the endpoint of a writer kind (DDSI-RTPS 2.5 9.3.1.2:
    0x02 with key, 0x03 without)."""
    rows = _datagram_rows(pcap, "rtps.param.topicName", "rtps.param.endpoint_guid")
    for _, src, _, topics, guids in rows:
        names, endpoints = topics.split(","), guids.split(",")
        if src != sender or len(names) != len(endpoints):
            continue
        for topic, guid in zip(names, endpoints, strict=True):
            if topic == GRAPH_TOPIC and guid[-2:] in WRITER_KINDS:
                return "0x" + guid[-8:]
    return None


def graph_traffic(
    pcap: Path, addresses: list[str], drone: int, since: float, until: float
) -> dict[str, Any]:
    """What the capture shows of drone ``drone``'s graph between ``since`` and ``until``
    (the nodes' teardown after ``until`` sends more): ``summarize_graph_rows``."""
    rows = _datagram_rows(pcap, *GRAPH_FIELDS)
    writer = graph_writer_id(pcap, addresses[drone])
    return summarize_graph_rows(rows, addresses, drone, writer, since, until)


def summarize_graph_rows(
    rows: list[list[str]],
    addresses: list[str],
    drone: int,
    writer: str | None,
    since: float,
    until: float,
) -> dict[str, Any]:
    """From ``since`` to ``until``: the SPDP/SEDP datagrams drone ``drone`` sent, its
    ``ros_discovery_info`` ``writer``'s DATA and HEARTBEAT datagrams per receiving
    participant, and those participants' ACKNACK bitmap bases for that writer (DDSI-RTPS 2.5
    8.3.7.1: the base is the first sequence number the reader still misses, so a base past
    the writer's last sequence number says "I have it all" and nothing is resent).

    ``rows``: ``[time, ip.src, ip.dst, *GRAPH_FIELDS]`` per datagram. A participant is named
    ``drone<i>`` by its address, with ``-new`` when it first spoke from ``since`` on (the
    probe's fresh participant)."""
    from swarmd_lab.ros2_lab import SEDP_IDS, SPDP_IDS

    sender = addresses[drone]
    first_seen: dict[str, float] = {}
    for row in rows:
        first_seen.setdefault(row[3], _time(row[0]))

    def name(ip: str, prefix: str) -> str:
        host = f"drone{addresses.index(ip)}" if ip in addresses else ip
        return host + ("-new" if first_seen.get(prefix, 0.0) >= since else "")

    out: dict[str, Any] = {"graph_writer": writer, "spdp": 0, "sedp": 0}
    data: dict[str, int] = {}
    heartbeats: dict[str, int] = {}
    bases: dict[str, list[int]] = {}
    for t, src, dst, src_prefix, dst_prefix, writers, readers, kinds, seqs in rows:
        if not since <= _time(t) < until:
            continue
        ids = set(writers.split(",")) | set(readers.split(","))
        submessages = set(kinds.split(","))
        graph = writer is not None and writer in writers.split(",")
        if src == sender:
            out["spdp"] += bool(ids & SPDP_IDS)
            out["sedp"] += bool(ids & SEDP_IDS)
            receiver = name(dst, dst_prefix.split(",")[0])
            if graph and DATA_SUBMESSAGE in submessages:
                data[receiver] = data.get(receiver, 0) + 1
            if graph and HEARTBEAT_SUBMESSAGE in submessages:
                heartbeats[receiver] = heartbeats.get(receiver, 0) + 1
        elif dst == sender and graph and ACKNACK_SUBMESSAGE in submessages:
            seen = bases.setdefault(name(src, src_prefix), [])
            for value in seqs.split(","):
                if value.isdigit() and int(value) not in seen:
                    seen.append(int(value))
    out.update(graph_data_to=data, graph_heartbeats_to=heartbeats)
    out["graph_acknack_bases_from"] = bases
    return out


def _time(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return 0.0


def observer_changes(log: Path, n: int) -> list[tuple[float, int, str]]:
    """The commander's per-pair changes exactly as the flight measure reads them."""
    from bench.wifi.flight_events import PeerEvents

    events = PeerEvents(n)
    events.feed(0, log.read_text(errors="replace").splitlines())
    return events.changes[0]


def probe_lines(log: Path) -> list[dict[str, Any]]:
    """The probe's JSON lines (rmw and Fast DDS log lines in the same file are skipped)."""
    out = []
    for line in log.read_text(errors="replace").splitlines():
        if line.startswith('{"probe"'):
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
    return out


def first_listing(
    lines: list[dict[str, Any]], view: str, since: float, drone: int
) -> dict[str, float | None]:
    """Seconds from ``since`` until ``view`` first listed drone ``drone``'s node, and its
    ``TOPIC`` publisher (under any node name, and under the drone's own namespace)."""
    ns = f"{NODE_NAMESPACE}{drone}"
    found: dict[str, float | None] = {"node": None, "publisher": None, "publisher_named": None}
    for line in lines:
        if line["probe"] != view or line["t"] < since:
            continue
        pubs = line["publishers"]
        got = {
            "node": ns in line["nodes"],
            "publisher": any(p.startswith(ns + "/") or UNKNOWN_NODE in p for p in pubs),
            "publisher_named": any(p.startswith(ns + "/") for p in pubs),
        }
        for key, listed in got.items():
            if listed and found[key] is None:
                found[key] = round(line["t"] - since, 3)
    return found


def run(args: argparse.Namespace) -> dict[str, Any]:
    from swarmd_lab import netns, ros2_lab

    from bench.wifi.ros2_contenders import ros2_env

    work = Path(args.work or tempfile.mkdtemp(prefix="ros2-relist-"))
    work.mkdir(parents=True, exist_ok=True)
    total_s = args.settle_s + args.cut_s + args.after_s
    env = ros2_env({"PYTHONPATH": f"{REPO}:{REPO / 'lab'}"})
    logs = [work / f"drone-{i}.log" for i in range(3)]
    peer = [sys.executable, str(REPO / "bench/wifi/peers/ros2_peer.py")]
    probe_cmd = [sys.executable, "-m", "bench.ros2_relist", "probe"]
    with netns.Lan(3) as lan:
        addresses = [h.address for h in lan]
        pcap = work / "link.pcapng"
        capture = ros2_lab.start_capture(lan.hub, netns.BRIDGE, pcap, CAPTURE_START_S)
        procs: list[subprocess.Popen[bytes]] = []
        try:
            start = time.time()
            cut_at = start + args.settle_s
            heal_at = cut_at + args.cut_s
            end_at = heal_at + args.after_s
            common = ["--until", f"{end_at:.3f}", "--start", f"{start:.3f}"]
            argvs = [
                [*peer, "--index", "0", "--n", "3", "--duration", f"{total_s + 5:g}"]
                + ["--out", str(work / "result-0.json"), "--events", "1"],
                [*peer, "--index", "1", "--n", "3", "--duration", f"{total_s + 5:g}"]
                + ["--out", str(work / "result-1.json"), "--events", "1"],
                [*probe_cmd, "--index", "2", *common]
                + ["--fresh-at", f"{heal_at + args.fresh_after_s:.3f}"],
            ]
            if args.nudge_after_s is not None:  # drone 1: a member that nudges rmw's graph
                argvs[1] = [*probe_cmd, "--index", "1", *common, "--publish"]
                argvs[1] += ["--nudge-at", f"{heal_at + args.nudge_after_s:.3f}"]
            for i, argv in enumerate(argvs):
                with logs[i].open("wb") as out:
                    procs.append(
                        lan[i].popen(
                            ros2_lab.own_host_argv(argv, work, i),
                            env=env,
                            stdout=out,
                            stderr=subprocess.STDOUT,
                        )
                    )
            time.sleep(max(0.0, cut_at - time.time()))
            set_cut(lan.hub, 1, on=True)
            time.sleep(max(0.0, heal_at - time.time()))
            set_cut(lan.hub, 1, on=False)
            time.sleep(max(0.0, end_at - time.time()))
        finally:
            netns.stop_processes(procs, STOP_TIMEOUT_S)
            capture.terminate()
            capture.wait(timeout=STOP_TIMEOUT_S)
    changes = observer_changes(logs[0], 3)
    lines = probe_lines(logs[2])
    result_0 = work / "result-0.json"
    received = json.loads(result_0.read_text()).get("received", {}) if result_0.exists() else {}
    nudges = [line["t"] for line in probe_lines(logs[1]) if line["probe"] == "nudge"]
    return {
        "versions": versions(),
        "start_epoch": start,
        "work": str(work),
        "timeline_s": {"cut": args.settle_s, "heal": args.settle_s + args.cut_s, "end": total_s},
        "nudge_s": round(nudges[0] - start, 3) if nudges else None,
        "observer": {
            "changes": [[round(t - start, 3), j, c] for t, j, c in changes],
            "lost_drone1_after_cut_s": next(
                (round(t - cut_at, 3) for t, j, c in changes if j == 1 and c == "lost"), None
            ),
            "relisted_drone1_after_heal_s": next(
                (round(t - heal_at, 3) for t, j, c in changes if j == 1 and c == "regained"),
                None,
            ),
            "received_from_drone1": received.get("1", {}).get("count"),
        },
        "probe_drone2_after_heal_s": first_listing(lines, "probe", heal_at, 1),
        "fresh_participant_after_heal_s": first_listing(lines, "fresh", heal_at, 1),
        "fresh_participant_created_after_heal_s": args.fresh_after_s,
        "drone1_link_after_heal": graph_traffic(pcap, addresses, 1, heal_at, end_at),
        "addresses": addresses,
        "probe_lines": [{**line, "t": round(line["t"] - start, 3)} for line in lines],
    }


def versions() -> dict[str, str]:
    """The ROS 2 stack under test: the PyPI wheels' versions."""
    from importlib import metadata

    out = {}
    for dist in ("ros-rclpy", "ros-rmw-fastrtps-cpp", "ros-rmw-dds-common", "ros-fastdds"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[dist] = metadata.version(dist)
    return out


MAX_RUN_S: Final = 600.0  # settle + cut + after: the run's bound


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="bench.ros2_relist", description=(__doc__ or "").split("\n\n")[0]
    )
    sub = p.add_subparsers(dest="command")
    pr = sub.add_parser("probe", help="(internal) the graph probe run inside a drone")
    pr.add_argument("--index", type=int, required=True)
    pr.add_argument("--until", type=float, required=True, help="wall clock end")
    pr.add_argument("--start", type=float, required=True, help="wall clock of the run's start")
    pr.add_argument("--fresh-at", type=float, help="wall clock of the fresh participant")
    pr.add_argument("--publish", action="store_true", help="publish on the topic as a member")
    pr.add_argument("--nudge-at", type=float, help="wall clock of the extra publisher")
    p.add_argument("--settle-s", type=float, default=10.0, help="before the cut (default 10)")
    p.add_argument("--cut-s", type=float, default=25.0, help="cut length (default 25 > lease 20)")
    p.add_argument("--after-s", type=float, default=30.0, help="after the heal (default 30)")
    p.add_argument(
        "--fresh-after-s",
        type=float,
        default=15.0,
        help="heal to the probe's fresh participant, the late-joiner control (default 15)",
    )
    p.add_argument(
        "--nudge-after-s",
        type=float,
        help="drone 1 runs a publishing probe instead of the contender's member and, this "
        "long after the heal, creates one more publisher (a new ros_discovery_info sample)",
    )
    p.add_argument("--work", help="directory for logs and the capture (default: a temp dir)")
    p.add_argument("--json", action="store_true", help="print the whole report as JSON")
    p.add_argument("--out", type=Path, help="also write the JSON report to this file")
    args = p.parse_args(argv)
    if args.command is None:
        spans = (args.settle_s, args.cut_s, args.after_s)
        if min(spans) <= 0 or sum(spans) > MAX_RUN_S:
            p.error(f"--settle-s, --cut-s, --after-s must be > 0 and sum to <= {MAX_RUN_S:g}")
        if not 0 <= args.fresh_after_s < args.after_s:
            p.error("--fresh-after-s must be in [0, --after-s)")
        if args.nudge_after_s is not None and not 0 <= args.nudge_after_s < args.after_s:
            p.error("--nudge-after-s must be in [0, --after-s)")
    return args


def summary(report: dict[str, Any]) -> str:
    """The report in five lines (``--json`` prints all of it)."""
    obs, link = report["observer"], report["drone1_link_after_heal"]
    return "\n".join(
        [
            f"stack: {report['versions']}; timeline (s): {report['timeline_s']}",
            f"observer (ros2_peer --events): lost drone 1 {obs['lost_drone1_after_cut_s']} s "
            f"after the cut, re-listed it {obs['relisted_drone1_after_heal_s']} s after the "
            f"heal (None: never); messages from drone 1: {obs['received_from_drone1']}",
            f"probe on drone 2 (old participant), s after heal: "
            f"{report['probe_drone2_after_heal_s']}",
            f"fresh participant on drone 2 (created "
            f"{report['fresh_participant_created_after_heal_s']} s after heal), s after heal: "
            f"{report['fresh_participant_after_heal_s']}",
            f"drone 1 after heal: SPDP {link['spdp']}, SEDP {link['sedp']}, graph DATA to "
            f"{link['graph_data_to']}, graph HEARTBEAT to {link['graph_heartbeats_to']}, "
            f"ACKNACK bases {link['graph_acknack_bases_from']}",
        ]
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    if args.command == "probe":
        return probe(args)
    if os.geteuid() != 0:
        print("bench.ros2_relist: needs root (network namespaces)", file=sys.stderr)
        return 2
    report = run(args)
    text = json.dumps(report, indent=1)
    print(text if args.json else summary(report))
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
