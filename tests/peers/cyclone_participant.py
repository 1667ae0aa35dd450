"""A stock Cyclone DDS participant (PyPI ``cyclonedds``) for interop tests; run in a namespace.

Usage: ``cyclone_participant.py --trace FILE [--interface eth0] [--duration S]``

Creates one participant on domain 0 with Cyclone's default discovery settings, plus a
topic and a writer so its SPDP looks like a real application's, prints one line
``READY <guid prefix in Cyclone's a:b:c form> <cyclonedds version>`` on stdout, then runs
until ``--duration`` elapses, stdin closes or SIGTERM/SIGINT arrives, and deletes the
participant cleanly so Cyclone sends its DATA(p[UD]) before the process exits.

Discovery is observed only through Cyclone's trace (category ``discovery``): reading the
DCPSParticipant builtin topic from Python aborts the process with a double free
(cyclonedds 11.0.1), so this script never does.
"""

# No "from __future__ import annotations": cyclonedds resolves IdlStruct field annotations
# by name in this module, where "int" and "str" are not attributes.

import argparse
import importlib.metadata
import os
import signal
import stat
import sys
import threading
from dataclasses import dataclass
from types import FrameType
from xml.sax.saxutils import quoteattr

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic


@dataclass
class Sample(IdlStruct, typename="swarmd_interop::Sample"):
    """An application sample type; its only job is to give the participant a real writer."""

    seq: int
    text: str


def cyclone_config(trace_file: str, interface: str | None) -> str:
    """The CYCLONEDDS_URI XML: stock discovery, trace to ``trace_file``, bound to one NIC."""
    interfaces = (
        f"<Interfaces><NetworkInterface name={quoteattr(interface)}/></Interfaces>"
        if interface
        else ""
    )
    return (
        "<CycloneDDS><Domain>"
        f"<General>{interfaces}</General>"
        "<Tracing><Category>discovery</Category>"
        f"<OutputFile>{trace_file}</OutputFile></Tracing>"
        "</Domain></CycloneDDS>"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trace", required=True, help="Cyclone discovery trace output file")
    parser.add_argument("--interface", default=None, help="network interface to use (eth0)")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds to run at most")
    parser.add_argument("--topic", default="swarmd_interop", help="topic of the extra writer")
    args = parser.parse_args(argv)

    # Read when the domain is created, i.e. by the first DomainParticipant below.
    os.environ["CYCLONEDDS_URI"] = cyclone_config(args.trace, args.interface)

    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    participant = DomainParticipant(0)
    topic = Topic(participant, args.topic, Sample)
    writer = DataWriter(participant, topic)
    writer.write(Sample(seq=0, text="hello"))
    prefix = participant.guid.bytes[:12]
    words = ":".join(f"{int.from_bytes(prefix[i : i + 4], 'big'):x}" for i in (0, 4, 8))
    version = importlib.metadata.version("cyclonedds")
    print(f"READY {words} {version}", flush=True)

    def watch_stdin() -> None:
        # stdin is a pipe from the test: its EOF (the test closed it or died) means "stop now"
        try:
            sys.stdin.buffer.read()
        except (OSError, ValueError):
            pass
        stop.set()

    if stat.S_ISFIFO(os.fstat(sys.stdin.fileno()).st_mode):
        threading.Thread(target=watch_stdin, daemon=True).start()
    stop.wait(args.duration)

    # Delete children before the participant; dds_delete on the participant sends
    # DATA(p[UD]) to every locator Cyclone announced to (reference section 1.11).
    del writer, topic
    participant.__del__()
    print("STOPPED", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
