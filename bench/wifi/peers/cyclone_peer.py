"""Stock Cyclone DDS workload peer (PyPI ``cyclonedds``, default configuration).

One participant per drone on domain 0. A member writes ``Ready(member, seq)`` once per
``--period``; the commander (index 0) reads them and records per-member counts and the
time its reader had matched all N-1 writers (SPDP + SEDP done for every member). Default
QoS throughout (the paper tested each DDS "with its default QoS configuration"):
Cyclone's default DataWriter reliability is reliable. No CYCLONEDDS_URI: the harness
clears it, so Cyclone picks eth0, the namespace's only multicast interface.

With ``--events 1`` (flight runs) the participant carries its drone index as USER_DATA
(the one QoS change: a few octets more in its SPDP) and a reader of the builtin
DCPSParticipant topic reports every remote participant: an ALIVE sample is ``up``, an
instance going NOT_ALIVE_DISPOSED (the remote deleted its participant) or NOT_ALIVE_NO_WRITERS
(its lease expired: Cyclone's default ``Discovery/LeaseDuration`` 10 s) is ``down``.
"""

# No "from __future__ import annotations": cyclonedds resolves IdlStruct annotations by name.

import sys
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))

import cyclonedds.idl.annotations as annotate  # noqa: E402
from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsParticipant  # noqa: E402
from cyclonedds.core import InstanceState, Listener, Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from bench.wifi.peers.common import (  # noqa: E402
    FlightEvents,
    Tally,
    drone_index,
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


def _observe(reader: BuiltinDataReader, events: FlightEvents) -> None:
    """Drain the DCPSParticipant reader (on Cyclone's listener thread) into events."""
    for sample in reader.take(N=64):
        key = str(sample.key)
        state = sample.sample_info.instance_state
        if state == InstanceState.Alive:
            data = sample.qos[Policy.Userdata] if sample.qos is not None else None
            events.up(key, drone_index(data.data) if data is not None else None)
        else:  # NotAliveDisposed | NotAliveNoWriters
            events.down(key)


def main() -> int:
    args = parse_args(__doc__ or "")
    stop = stop_event()
    wait_start_barrier(args.barrier)  # imports done; the participant starts SPDP at once
    events = FlightEvents(bool(args.events), args.index)
    if events.enabled:
        participant = DomainParticipant(0, qos=Qos(Policy.Userdata(data=str(args.index).encode())))
        events.hello()
        # the listener can fire inside the constructor, before the reader exists for Python
        # (cyclonedds hands it None then): it drains the reader held here, and once by hand
        held: list[BuiltinDataReader] = []

        def on_data(_: object) -> None:
            if held:
                _observe(held[0], events)

        listener = Listener(on_data_available=on_data)  # type: ignore[no-untyped-call]
        held.append(BuiltinDataReader(participant, BuiltinTopicDcpsParticipant, listener=listener))
        _observe(held[0], events)
    else:
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
            events.readiness(tally)
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
