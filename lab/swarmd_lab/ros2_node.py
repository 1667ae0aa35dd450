"""A real rclpy node for the ROS 2 tests (issue 19): talker (publishes, serves) or listener
(subscribes, calls), run for a bounded time, then one JSON line on stdout with what it got.

    python -m swarmd_lab.ros2_node talker --topic /chatter --service /trigger --seconds 12

Parameter services, the type-description service and rosout are off, as docs/ros2.md asks of
nodes on a static graph (their endpoints are not in the generated static EDP file).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from typing import Any

PUBLISH_PERIOD_S = 0.2


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="swarmd_lab.ros2_node")
    parser.add_argument("role", choices=("talker", "listener"))
    parser.add_argument("--name", help="node name (default: the role)")
    parser.add_argument("--topic", default="/chatter")
    parser.add_argument("--service", default="/trigger")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--tag", help="what a talker's messages start with (default: name)")
    parser.add_argument(
        "--undeclared",
        metavar="TOPIC",
        help="also publish TOPIC (a String), which the bundle does not declare",
    )
    parser.add_argument(
        "--also-publish",
        metavar="TOPIC",
        help="listener: also publish TOPIC (a String tagged with --tag or the name) every "
        f"{PUBLISH_PERIOD_S} s, so that it talks to the other drones' listeners too",
    )
    parser.add_argument(
        "--matched-log",
        metavar="PATH",
        help="append a JSON line to PATH whenever the listener's subscription's matched "
        "publisher count (the talker's publisher's matched subscription count) changes "
        "(a node disposed or announced again)",
    )
    parser.add_argument(
        "--senders-log",
        metavar="PATH",
        help="listener: append a JSON line to PATH when a message of a sender (its tag) not "
        'heard before arrives ({"t": s, "sender": tag, "number": n})',
    )
    parser.add_argument(
        "--graph-every",
        type=float,
        metavar="S",
        help="print the node's view of the ROS 2 graph every S seconds as a JSON line "
        '({"graph": t, "nodes": [...], "publishers": N})',
    )
    args = parser.parse_args(argv)

    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    rclpy.init()
    name = args.name or args.role
    node = Node(
        name,
        start_parameter_services=False,
        enable_rosout=False,
        parameter_overrides=[Parameter("start_type_description_service", value=False)],
    )
    received: list[str] = []
    senders_heard: set[str] = set()
    answers: list[str] = []
    first_message_s: float | None = None
    start = time.monotonic()
    sent = [0]
    if args.role == "talker":
        publisher = node.create_publisher(String, args.topic, 10)

        def tick() -> None:
            msg = String()
            msg.data = f"{args.tag or name} {sent[0]}"
            sent[0] += 1
            publisher.publish(msg)

        def answer(_request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            response.success = True
            response.message = f"triggered by {name}"
            return response

        node.create_timer(PUBLISH_PERIOD_S, tick)
        node.create_service(Trigger, args.service, answer)
    else:

        def heard(msg: String) -> None:
            nonlocal first_message_s
            if first_message_s is None:
                first_message_s = time.monotonic() - start
            received.append(msg.data)
            sender, _, number = msg.data.rpartition(" ")
            if args.senders_log and sender not in senders_heard:
                senders_heard.add(sender)
                line = {"t": time.monotonic() - start, "sender": sender, "number": number}
                with open(args.senders_log, "a") as log:
                    log.write(json.dumps(line) + "\n")

        subscription = node.create_subscription(String, args.topic, heard, 10)
        client: Any = node.create_client(Trigger, args.service)
    if args.role == "listener" and args.also_publish:
        also = node.create_publisher(String, args.also_publish, 10)

        def tick_also() -> None:
            msg = String()
            msg.data = f"{args.tag or name} {sent[0]}"
            sent[0] += 1
            also.publish(msg)

        node.create_timer(PUBLISH_PERIOD_S, tick_also)
    matched = -1
    if args.undeclared:
        node.create_publisher(String, args.undeclared, 10)
    future = None
    end = start + args.seconds
    next_graph = start
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
        if args.graph_every and time.monotonic() >= next_graph:
            next_graph += args.graph_every
            names = node.get_node_names_and_namespaces()
            snapshot = {
                "graph": round(time.monotonic() - start, 2),
                "nodes": sorted(f"{ns.rstrip('/')}/{n}" for n, ns in names),
                "publishers": node.count_publishers(args.topic),
            }
            print(json.dumps(snapshot), flush=True)
        if args.matched_log:
            count = (
                subscription.get_publisher_count()
                if args.role == "listener"
                else publisher.get_subscription_count()
            )
            if count != matched:
                matched = count
                with open(args.matched_log, "a") as log:
                    log.write(json.dumps({"t": time.monotonic() - start, "matched": count}) + "\n")
        if args.role == "listener":
            if future is None and client.service_is_ready():
                future = client.call_async(Trigger.Request())
            if future is not None and future.done() and not answers:
                result = future.result()
                answers.append(result.message if result is not None else "")
    senders = sorted({m.rsplit(" ", 1)[0] for m in received})
    last: dict[str, int] = {}  # sender -> highest message number heard (restarts survived)
    for m in received:
        sender, _, number = m.rpartition(" ")
        if number.isdigit():
            last[sender] = max(last.get(sender, -1), int(number))
    print(
        json.dumps(
            {
                "node": name,
                "received": len(received),
                "senders": senders,
                "last": last,
                "first_message_s": first_message_s,
                "answers": answers,
                "sent": sent[0],
            }
        ),
        flush=True,
    )
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
