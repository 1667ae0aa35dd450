"""ROS 2 workload peer: a real rclpy node (rmw_fastrtps_cpp, Fast DDS 3.2 from the PyPI wheels).

The paper's workload as ROS 2 nodes: on every member a ``talker`` publishing a
``std_msgs/msg/String`` ``"<member> <seq>"`` on ``/swarm_ready`` once per ``--period``, on the
commander (index 0) a ``listener`` subscribing to it, ROS 2's default QoS (reliable, volatile,
keep last 10), which is what ``create_publisher(String, topic, 10)`` gives. How discovery
works is decided by the environment the harness starts the process with (stock SIMPLE,
``ROS_DISCOVERY_SERVER`` or the generated profiles of ``swarmctl ros2 profile``:
bench/wifi/ros2_contenders.py); the node is the same for all of them.

The node turns off parameter services, rosout and the type description service, as
docs/ros2.md asks of nodes on a static graph (static EDP lists only the declared endpoints):
every ROS 2 contender runs this same node, so they differ by discovery alone. A default node
would add 15 endpoints (reference/ros2-fastdds-facts.md) and so more SEDP under SIMPLE.

The commander records what the other workload peers record (bench/wifi/peers/common.py) and
``all_discovered``: the time its subscription had matched N-1 publishers (the ``matched``
event of rmw_fastrtps: SPDP + SEDP, or SPDP + the static file, done for every member).

With ``--events 1`` (flight runs) the node lives in the namespace ``/drone<index>`` (the topic
is absolute, so it is unchanged) and polls the rclpy graph (``get_node_names_and_namespaces``)
every ``GRAPH_POLL_S``: a drone's namespace appearing is ``up``, disappearing ``down``. In ROS
2 a node leaves the graph when rmw_fastrtps drops its participant: a goodbye, or the lease of
Fast DDS 3.2's default participant (``leaseDuration`` 20 s) expiring. The publishers'
matched-subscription counts could not tell which drone went, and on a member they only see
the commander. A rebooted node's new participant and the old one share the namespace: the
graph shows the drone present throughout, which is what a ROS 2 application would see.
A drone lost by lease expiry is listed again only when its participant publishes a new
``ros_discovery_info`` sample (a node or endpoint created or destroyed): Fast DDS keeps the
reader's last sequence number across the drop, so the old sample is never resent and
rmw's graph cache, which dropped the node names with the participant, never relearns them
(``bench/ros2_relist.py``; docs/benchmarks.md, "Flight").

``--node NAME`` (the ``ros2-swarmd`` flight route) names the node ``NAME`` in the root
namespace instead: on the relay route the other drones' node names come from swarmd's graph
participant, which gives each the name the bundle declares, in ``/`` (swarmd.ros2.graph), so
the flight mission declares one node ``drone<index>`` per drone and each node takes its
own. A drone is then read from the node's fully qualified name, ``/drone<index>`` either
way (``graph_drones``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

from bench.wifi.peers.common import (  # noqa: E402
    FlightEvents,
    Tally,
    drone_index,
    parser,
    stop_event,
    wait_start_barrier,
    write_result,
)

TOPIC = "/swarm_ready"
DEPTH = 10  # ROS 2's default history depth for a plain create_publisher(..., 10)
SPIN_S = 0.02  # longest spin between two checks of the clock and the stop flag
GRAPH_POLL_S = 0.25  # how often a flight peer reads the graph (a local cache: cheap)
NAMESPACE = "/drone"  # + index: how a flight peer's node names its drone in the graph


def graph_drones(names_and_namespaces: list[tuple[str, str]]) -> set[int]:
    """The drone indices the graph lists: nodes whose fully qualified name starts with the
    segment ``/drone<index>`` (a node in the namespace ``/drone<index>``, the stock flight
    peers, or a node named ``drone<index>`` in ``/``, the relay route's); others are not
    drones."""
    found = set()
    for name, namespace in names_and_namespaces:
        qualified = namespace.rstrip("/") + "/" + name
        head = "/" + qualified.split("/")[1]  # "" before the leading slash
        if head.startswith(NAMESPACE):
            index = drone_index(head[len(NAMESPACE) :])
            if index is not None:
                found.add(index)
    return found


class GraphWatch:
    """The graph poll's diff: the drones listed now against the last poll, as ``up``/``down``
    events (the instance key is the drone's namespace: one node per drone). A drone that
    leaves and is listed again gives ``down`` then ``up``: when stock ROS 2 does not list a
    returning drone again, it is rmw's graph, not this diff (docs/benchmarks.md, "Flight")."""

    def __init__(self, events: FlightEvents, own_index: int) -> None:
        self.events = events
        self.own = own_index
        self.present: set[int] = set()

    def update(self, names_and_namespaces: list[tuple[str, str]]) -> None:
        now = graph_drones(names_and_namespaces) - {self.own}
        for j in sorted(now - self.present):
            self.events.up(f"{NAMESPACE}{j}", j)
        for j in sorted(self.present - now):
            self.events.down(f"{NAMESPACE}{j}")
        self.present = now


def main() -> int:
    p = parser(__doc__ or "")
    p.add_argument("--node", help="the node's name in the root namespace (module doc)")
    args = p.parse_args()
    stop = stop_event()
    # imports before the barrier: rclpy and the message types take seconds of CPU
    import rclpy
    from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    wait_start_barrier(args.barrier)
    # our own SIGTERM handler (stop_event) writes the result; rclpy's would raise instead
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    started = time.time()
    events = FlightEvents(bool(args.events), args.index)
    events.hello()
    name = args.node or ("listener" if args.index == 0 else "talker")
    node = Node(
        name,
        namespace=f"{NAMESPACE}{args.index}" if events.enabled and not args.node else None,
        start_parameter_services=False,
        enable_rosout=False,
        parameter_overrides=[Parameter("start_type_description_service", value=False)],
    )
    result: dict[str, Any] = {"started": started, "index": args.index}
    deadline = time.monotonic() + args.duration
    matched: list[float] = []  # the time the wanted number of peers had matched

    graph = GraphWatch(events, args.index)
    next_graph = 0.0

    def watch_graph() -> None:
        nonlocal next_graph
        if not events.enabled or time.monotonic() < next_graph:
            return
        next_graph = time.monotonic() + GRAPH_POLL_S
        graph.update(node.get_node_names_and_namespaces())

    def on_match(info: Any, wanted: int) -> None:
        if not matched and int(info.current_count) >= wanted:
            matched.append(time.time())

    if args.index == 0:
        tally = Tally(args.messages)

        def heard(msg: String) -> None:
            head = msg.data.split(" ", 1)[0]
            if head.isdigit():
                tally.add(int(head))

        node.create_subscription(
            String,
            TOPIC,
            heard,
            DEPTH,
            event_callbacks=SubscriptionEventCallbacks(
                matched=lambda info: on_match(info, args.n - 1)
            ),
        )
        while not stop.is_set() and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=SPIN_S)
            watch_graph()
            events.readiness(tally)
        result.update(received=tally.as_json(), all_discovered=matched[0] if matched else None)
    else:
        publisher = node.create_publisher(
            String,
            TOPIC,
            DEPTH,
            event_callbacks=PublisherEventCallbacks(matched=lambda info: on_match(info, 1)),
        )
        seq = 0
        next_t = time.monotonic()
        while not stop.is_set() and (now := time.monotonic()) < deadline:
            if now >= next_t:
                seq += 1
                msg = String()
                msg.data = f"{args.index} {seq} uav{args.index + 1} ready"
                publisher.publish(msg)
                next_t += args.period
            rclpy.spin_once(node, timeout_sec=max(0.0, min(SPIN_S, next_t - now)))
            watch_graph()
        result.update(sent=seq, commander_matched=matched[0] if matched else None)
    write_result(args.out, result)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
