"""zenoh workload peer (PyPI ``eclipse-zenoh``, default peer mode and multicast scouting).

Default ``zenoh.Config()``: peer mode, scouting on 224.0.0.224:7446, sessions over TCP. A
member puts ``member,seq`` on ``swarm/ready/<member>`` once per ``--period``; the commander
subscribes to ``swarm/ready/*`` and records per-member counts and the time it first saw
all N-1 other peers (``session.info.peers_zid()``).

With ``--events 1`` (flight runs) every peer declares a liveliness token
``swarmbench/alive/<index>/<its zenoh id>`` and subscribes to ``swarmbench/alive/**`` with
history: a PUT is ``up``, a DELETE ``down``. Tokens rather than scouting or the transport
events: a token carries the drone index as data and zenoh withdraws it when the session
that declared it is gone from the router's view (closed, or its transport's lease expired:
zenoh's default ``transport.link.tx.lease`` 10 s), which is the loss an application sees;
scouting only tells who answers a multicast ``Scout`` (no loss at all), and the transport
events name zenoh ids, not drones. The zenoh id in the key tells two lives of a drone apart.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

import zenoh  # noqa: E402

from bench.wifi.peers.common import (  # noqa: E402
    FlightEvents,
    Tally,
    drone_index,
    parse_args,
    stop_event,
    wait_start_barrier,
    write_result,
)

TOKENS = "swarmbench/alive"


def _observe(sample: zenoh.Sample, events: FlightEvents) -> None:
    """A liveliness change (on zenoh's callback thread): ``<TOKENS>/<index>/<zid>``."""
    parts = str(sample.key_expr).split("/")
    if len(parts) != 4:
        return
    key = parts[3]
    if sample.kind == zenoh.SampleKind.PUT:
        events.up(key, drone_index(parts[2]))
    else:
        events.down(key)


def main() -> int:
    args = parse_args(__doc__ or "")
    stop = stop_event()
    config = zenoh.Config()
    wait_start_barrier(args.barrier)  # imports done; opening the session starts scouting
    session = zenoh.open(config)
    started = time.time()
    events = FlightEvents(bool(args.events), args.index)
    if events.enabled:
        events.hello()  # before the subscriber: its history comes at once
        token = session.liveliness().declare_token(f"{TOKENS}/{args.index}/{session.info.zid()}")
        watch = session.liveliness().declare_subscriber(
            f"{TOKENS}/**", lambda s: _observe(s, events), history=True
        )
    result: dict[str, object] = {"started": started, "index": args.index}
    deadline = time.monotonic() + args.duration
    all_peers: float | None = None
    try:
        if args.index == 0:
            tally = Tally(args.messages)

            def on_sample(sample: zenoh.Sample) -> None:
                member = str(sample.key_expr).rsplit("/", 1)[-1]
                if member.isdigit():
                    tally.add(int(member))

            sub = session.declare_subscriber("swarm/ready/*", on_sample)
            while not stop.is_set() and time.monotonic() < deadline:
                if all_peers is None and len(list(session.info.peers_zid())) >= args.n - 1:
                    all_peers = time.time()
                events.readiness(tally)
                stop.wait(0.05)
            sub.undeclare()  # type: ignore[no-untyped-call]
            result.update(received=tally.as_json(), all_discovered=all_peers)
        else:
            pub = session.declare_publisher(f"swarm/ready/{args.index}")
            seq = 0
            next_t = time.monotonic()
            while not stop.is_set() and time.monotonic() < deadline:
                seq += 1
                pub.put(f"{args.index},{seq}")
                next_t += args.period
                stop.wait(max(0.0, next_t - time.monotonic()))
            result.update(sent=seq)
    finally:
        if events.enabled:
            watch.undeclare()  # type: ignore[no-untyped-call]
            token.undeclare()  # type: ignore[no-untyped-call]
        # the result first: zenoh's close can time out on a congested channel (ZError)
        write_result(args.out, result)
        try:
            session.close()  # type: ignore[no-untyped-call]
        except zenoh.ZError as exc:
            print(f"zenoh close: {exc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
