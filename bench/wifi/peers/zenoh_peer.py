"""zenoh workload peer (PyPI ``eclipse-zenoh``, default peer mode and multicast scouting).

Default ``zenoh.Config()``: peer mode, scouting on 224.0.0.224:7446, sessions over TCP. A
member puts ``member,seq`` on ``swarm/ready/<member>`` once per ``--period``; the commander
subscribes to ``swarm/ready/*`` and records per-member counts and the time it first saw
all N-1 other peers (``session.info.peers_zid()``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

import zenoh  # noqa: E402

from bench.wifi.peers.common import (  # noqa: E402
    Tally,
    parse_args,
    stop_event,
    wait_start_barrier,
    write_result,
)


def main() -> int:
    args = parse_args(__doc__ or "")
    stop = stop_event()
    config = zenoh.Config()
    wait_start_barrier(args.barrier)  # imports done; opening the session starts scouting
    session = zenoh.open(config)
    started = time.time()
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
        # the result first: zenoh's close can time out on a congested channel (ZError)
        write_result(args.out, result)
        try:
            session.close()  # type: ignore[no-untyped-call]
        except zenoh.ZError as exc:
            print(f"zenoh close: {exc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
