"""Stock Cyclone DDS workload peer (PyPI ``cyclonedds``, default configuration).

One participant per drone on domain 0. A member writes ``Ready(member, seq)`` once per
``--period``; the commander (index 0) reads them and records per-member counts and the
time its reader had matched all N-1 writers (SPDP + SEDP done for every member). Default
QoS throughout (the paper tested each DDS "with its default QoS configuration"):
Cyclone's default DataWriter reliability is reliable. No CYCLONEDDS_URI: the harness
clears it, so Cyclone picks eth0, the namespace's only multicast interface.
"""

# No "from __future__ import annotations": cyclonedds resolves IdlStruct annotations by name.

import sys
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from bench.wifi.peers.common import (  # noqa: E402
    Tally,
    parse_args,
    stop_event,
    wait_start_barrier,
    write_result,
)


@dataclass
@annotate.keylist(["member"])
class Ready(IdlStruct, typename="swarmbench::Ready"):
    """The 1 Hz readiness sample, keyed by member.

    Keyed so each member is its own instance: with a keyless type the reader's default
    history (keep last 1) would hold one sample for the whole swarm, and two members'
    samples arriving between two ``take`` calls would overwrite each other.
    """

    member: int
    seq: int
    text: str


def main() -> int:
    args = parse_args(__doc__ or "")
    stop = stop_event()
    wait_start_barrier(args.barrier)  # imports done; the participant starts SPDP at once
    participant = DomainParticipant(0)
    started = time.time()
    topic = Topic(participant, "swarm_ready", Ready)
    result: dict[str, object] = {"started": started, "index": args.index}
    deadline = time.monotonic() + args.duration
    if args.index == 0:
        reader = DataReader(participant, topic)
        tally = Tally(args.messages)
        all_matched: float | None = None
        while not stop.is_set() and time.monotonic() < deadline:
            for sample in reader.take(N=256):
                if isinstance(sample, Ready):
                    tally.add(sample.member)
            if all_matched is None:
                status = reader.get_subscription_matched_status()  # type: ignore[no-untyped-call]
                if status.current_count >= args.n - 1:
                    all_matched = time.time()
            stop.wait(0.02)
        result.update(received=tally.as_json(), all_discovered=all_matched)
    else:
        writer = DataWriter(participant, topic)
        seq = 0
        next_t = time.monotonic()
        matched: float | None = None
        while not stop.is_set() and time.monotonic() < deadline:
            seq += 1
            writer.write(Ready(member=args.index, seq=seq, text=f"uav{args.index + 1} ready"))
            if matched is None:
                status = writer.get_publication_matched_status()  # type: ignore[no-untyped-call]
                if status.current_count >= 1:
                    matched = time.time()
            next_t += args.period
            stop.wait(max(0.0, next_t - time.monotonic()))
        result.update(sent=seq, commander_matched=matched)
    write_result(args.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
