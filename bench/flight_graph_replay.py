"""What the ROS 2 relay's graph writer adds to swarmd's own re-discoveries: a replay on
virtual time (docs/benchmarks.md, "ROS 2 on swarmd's slow pairs, split").

    .venv/bin/python -m bench.flight_graph_replay \
        bench/results/flight-stagger/runs/flight-fly-out-swarmd-n20-r{4,5,6,7}.json

A ROS 2 on swarmd run records when the node's graph lists a drone, not when swarmd found it
(``bench/wifi/peers/ros2_peer.py``). A swarmd run records swarmd's own re-discoveries (its
``PeerRegained``, dated by the daemon). This takes those, heal by heal and observer by
observer, and feeds them to the relay's graph writer as the relay does
(``GraphParticipant.publish`` at each one: ``swarmd/ros2/relay_remote.py``), built from this
checkout's code, with a model of the node's graph reader: it answers every HEARTBEAT with an
ACKNACK of what it lacks ``RESPONSE_S`` later (Fast DDS's default heartbeatResponseDelay,
5 ms) and takes every DATA at once. The drone is listed at the first graph poll after its
sample arrived (the flight peer polls every ``POLL_S``, 0.25 s; ``--seeds`` poll phases per
observer). It prints, over every re-discovery, p50/p90/max seconds after the return and how
many pass 2 s: swarmd's own; with the poll only; through the graph writer and the poll.

What it leaves out: the dilated node's own processing and rmw's graph cache, and a channel
that differs from run to run (the swarmd run's channel stands for the ROS 2 run's).
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import random
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from bench.flight_slow_pair import stages
from bench.wifi.ros2_contenders import ros2_mission_text
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import Ros2EndpointKind, Ros2Participant, bundle_ros2_participants
from swarmd.ros2.graph import GraphParticipant, graph_endpoint_id, graph_participant_prefix
from swarmd.rtps.locator import Locator
from swarmd.rtps.message import (
    AckNack,
    Data,
    Header,
    Heartbeat,
    InfoDst,
    SequenceNumberSet,
    decode_message,
    encode_message,
)
from swarmd.rtps.types import GuidPrefix, ProtocolVersion, VendorId

RESPONSE_S: Final = 0.005  # Fast DDS ReaderTimes.heartbeat_response_delay default
POLL_S: Final = 0.25  # bench/wifi/peers/ros2_peer.py GRAPH_POLL_S
OVER_S: Final = 2.0  # the re-discovery target


def flight_participants(n: int) -> tuple[Ros2Participant, ...]:
    """The ROS 2 participants of the flight's relay route: one node per drone
    (``ros2_mission_text(per_drone=True)``, as ``flight_run`` builds the bundle)."""
    addresses = [f"10.0.0.{i + 1}" for i in range(n)]
    mission = parse_mission(ros2_mission_text(addresses, per_drone=True))
    return bundle_ros2_participants(build_dev_bundle(mission).bundle)


def graph_arrivals(
    participants: tuple[Ros2Participant, ...], observer: int, found: Sequence[tuple[float, int]]
) -> dict[int, float]:
    """When observer's node takes each drone's graph sample, the relay publishing one at
    each ``(time, drone)`` in ``found`` (each a return, the drone's sample withdrawn at its
    loss before); the model reader (module doc) is up to date at the start. Keyed by the
    index in ``found``."""
    me = next(p for p in participants if p.drone_index == observer)
    graph = GraphParticipant(
        participants,
        me.drone,
        prefix=graph_participant_prefix(bytes(range(1, 11))),
        relay_locator=Locator.udpv6("::1", 7399),
        domain_id=0,
        lease_s=20.0,
    )
    header = Header(ProtocolVersion(2, 3), VendorId(b"\x01\x0f"), GuidPrefix(me.guid_prefix))
    reader = graph_endpoint_id(me, Ros2EndpointKind.READER)

    def acknack(base: int, missing: list[int]) -> bytes:
        bits = len(missing) and max(missing) - base + 1
        state = SequenceNumberSet.of(base, missing, num_bits=bits)
        return encode_message(
            header, [InfoDst(graph.prefix), AckNack(reader, graph.writer_id, state, 1)]
        )

    prefix_of = {p.drone_index: GuidPrefix(p.guid_prefix) for p in participants}
    graph.receive_datagram(acknack(1, []), -1.0)  # matched long before, nothing to take
    drone_of: dict[int, int] = {}  # SN -> drone
    sn = 0
    have: set[int] = set()
    arrived: dict[int, float] = {}
    # events: (time, order, ACKNACK bytes or None for a publish, drone)
    queue: list[tuple[float, int, bytes | None, int]] = [
        (t, k, None, k) for k, (t, _) in enumerate(found)
    ]
    heapq.heapify(queue)
    order = len(queue)
    budget = 100 * len(found) + 100  # a bound on the replay's steps, whatever the writer does
    while budget and (queue or graph.get_timer() is not None):
        budget -= 1
        due = graph.get_timer()
        if due is not None and (not queue or due < queue[0][0]):
            now = due
            graph.handle_timer(now)
        else:
            now, _, datagram, j = heapq.heappop(queue)
            if datagram is None:
                graph.publish(prefix_of[found[j][1]], now)
                sn += 1  # the writer numbers its samples from 1, one per publish
                drone_of[sn] = j
            else:
                graph.receive_datagram(datagram, now)
        for data, _ in graph.datagrams_to_send():
            for sm in decode_message(data).submessages:
                if isinstance(sm, Data):
                    have.add(sm.writer_sn)
                    k = drone_of.get(sm.writer_sn)
                    if k is not None:
                        arrived.setdefault(k, now)
                elif isinstance(sm, Heartbeat):
                    lacking = [s for s in range(sm.first_sn, sm.last_sn + 1) if s not in have]
                    base = min(lacking, default=sm.last_sn + 1)
                    order += 1
                    heapq.heappush(queue, (now + RESPONSE_S, order, acknack(base, lacking), -1))
        if len(arrived) == len(found) and graph.get_timer() is None:
            break
    return arrived


def _polled(t: float, phase: float) -> float:
    return phase + POLL_S * math.ceil((t - phase) / POLL_S)


def replay(runs: Sequence[Mapping[str, Any]], seeds: int) -> dict[str, list[float]]:
    """Per kind (``own``, ``poll``, ``graph``): every re-discovery's seconds after its
    return, ``seeds`` poll phases per observer for the last two."""
    out: dict[str, list[float]] = {"own": [], "poll": [], "graph": []}
    rng = random.Random(1)
    for run in runs:
        participants = flight_participants(int(run["n"]))
        # one replay per observer over the whole run: its writer serves every heal
        by_observer: dict[int, list[tuple[float, int, float]]] = {}
        for r in stages(run, -1.0):
            by_observer.setdefault(r["observer"], []).append((r["found"], r["peer"], r["back"]))
        for observer, rows in sorted(by_observer.items()):
            rows.sort()
            arrived = graph_arrivals(participants, observer, [(t, j) for t, j, _ in rows])
            out["own"] += [max(0.0, t - back) for t, _, back in rows]
            for _ in range(seeds):
                phase = rng.uniform(0.0, POLL_S)
                for k, (t, _, back) in enumerate(rows):
                    out["poll"].append(max(0.0, _polled(t, phase) - back))
                    out["graph"].append(max(0.0, _polled(arrived[k], phase) - back))
    return out


def summary(values: Sequence[float], per: int) -> str:
    s = sorted(values)
    if not s:
        return "-"
    p50, p90 = (s[min(len(s) - 1, round(q * (len(s) - 1)))] for q in (0.5, 0.9))
    over = sum(v > OVER_S for v in s) / per
    return f"p50 {p50:.3f} p90 {p90:.3f} max {s[-1]:.3f} s, over {OVER_S:g} s: {over:g}"


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.flight_graph_replay",
        description="swarmd runs' re-discoveries replayed through the relay's graph writer.",
    )
    parser.add_argument("runs", type=Path, nargs="+", help="swarmd flight run files")
    parser.add_argument("--seeds", type=int, default=20, help="graph poll phases per observer")
    args = parser.parse_args(argv)
    runs = []
    for path in args.runs:
        if not path.is_file():
            print(f"{path}: no such run file", file=sys.stderr)
            return 66  # EX_NOINPUT
        runs.append(json.loads(path.read_text()))
    seeds = max(1, min(args.seeds, 1000))
    out = replay(runs, seeds)
    print(f"{len(runs)} runs, {len(out['own'])} re-discoveries, {seeds} poll phases per observer")
    print(f"  swarmd's own:            {summary(out['own'], 1)}")
    print(f"  + the 0.25 s graph poll: {summary(out['poll'], seeds)} (per run set)")
    print(f"  + graph writer and poll: {summary(out['graph'], seeds)} (per run set)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
