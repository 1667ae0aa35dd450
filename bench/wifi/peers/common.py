"""What the Cyclone DDS and zenoh workload scripts share: arguments, the result file, stop.

Every peer runs inside one drone's namespace. A member publishes ``(member, seq)`` at 1 Hz
from seq 1; the commander (index 0) subscribes and records, per member, how many samples
arrived and the wall time of the ``--messages``-th one (the paper's success criterion,
section 5.1: the subscriber receives the 20th message of every publisher within the
window). Each peer writes one JSON result file when ``--duration`` ends or on SIGTERM.
With ``--barrier PATH`` a peer, once imported, waits on the harness's start barrier
(bench/wifi/barrier.py) before it creates its participant or session.

With ``--events 1`` (the flight harness, bench/wifi/flight_run.py) a peer also reports what
its stack's own discovery API tells it, one JSON line per event on its stdout (the log file
the harness gave it), each dated by the peer's own wall clock (``FlightEvents``): ``hello``
when its participant or session exists, ``up``/``down`` when a remote participant (session,
node) carrying another drone's index appears or goes, and on the commander a ``readiness``
snapshot of its tally once a second. The drone index comes from the stack's discovery data
(DDS USER_DATA, a zenoh liveliness token's key, a ROS 2 node's namespace), set by the other
peer from its ``--index``; ``key`` names the remote participant instance (a GUID, a zenoh id)
so a reboot's new participant and the old one's late removal are told apart.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any


@dataclass
class Tally:
    """The commander's per-member counts (thread-safe: listeners run on library threads)."""

    messages: int
    counts: dict[int, int] = field(default_factory=dict)
    first: dict[int, float] = field(default_factory=dict)
    nth: dict[int, float] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, member: int) -> None:
        now = time.time()
        with self.lock:
            c = self.counts.get(member, 0) + 1
            self.counts[member] = c
            self.first.setdefault(member, now)
            if c == self.messages:
                self.nth[member] = now

    def as_json(self) -> dict[str, Any]:
        with self.lock:
            return {
                str(m): {"count": self.counts[m], "first": self.first[m], "nth": self.nth.get(m)}
                for m in sorted(self.counts)
            }


def parse_args(doc: str) -> argparse.Namespace:
    return parser(doc).parse_args()


def parser(doc: str) -> argparse.ArgumentParser:
    """Every peer's arguments (a peer may add its own before parsing)."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--index", type=int, required=True, help="0 = commander, else member")
    p.add_argument("--n", type=int, required=True, help="swarm size")
    p.add_argument("--duration", type=float, required=True, help="seconds to run")
    p.add_argument("--messages", type=int, default=20, help="success = this many received")
    p.add_argument("--period", type=float, default=1.0, help="seconds between publications")
    p.add_argument("--out", type=Path, required=True, help="result JSON file")
    p.add_argument("--barrier", type=Path, help="UNIX socket of the harness's start barrier")
    p.add_argument("--events", type=int, default=0, help="1: flight events on stdout")
    return p


def wait_start_barrier(path: Path | None) -> None:
    """Connect to the harness's barrier and block until it sends a byte or closes."""
    if path is None:
        return
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.connect(str(path))
        sock.recv(1)


def stop_event() -> threading.Event:
    """Set on SIGTERM/SIGINT or when the caller's deadline passes."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return stop


def write_result(path: Path, result: dict[str, Any]) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result))
    os.replace(tmp, path)


EVENT_TAG = "flight"  # the JSON field that marks an event line among a stack's log lines
MAX_INSTANCES = 1024  # remote participants a peer remembers (a reboot adds one per life)


def drone_index(raw: bytes | str) -> int | None:
    """The drone index a remote participant carries (ASCII decimal), or None for anything
    else (a discovery server, a foreign participant on the domain, junk)."""
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else raw
    text = text.strip().rstrip("\x00")
    return int(text) if text.isascii() and text.isdigit() and len(text) <= 6 else None


class FlightEvents:
    """A peer's event lines (module doc); a no-op when ``--events`` is 0.

    Thread-safe: the stacks call back on their own threads. ``seen`` maps a remote instance
    key to the drone index it announced, so a ``down`` (which carries only the key for DDS)
    names the same drone as its ``up``.
    """

    def __init__(self, enabled: bool, own_index: int) -> None:
        self.enabled = enabled
        self.own = own_index
        self.seen: dict[str, int] = {}
        self.lock = threading.Lock()
        self._next_readiness = 0.0

    def _write(self, record: dict[str, Any]) -> None:
        line = json.dumps({EVENT_TAG: record.pop("kind"), "t": time.time(), **record})
        with self.lock:
            print(line, flush=True)

    def hello(self) -> None:
        if self.enabled:
            self._write({"kind": "hello", "self": self.own})

    def up(self, key: str, index: int | None) -> None:
        """Remote instance ``key`` alive, announcing drone ``index`` (None: not a drone)."""
        if not self.enabled or index is None or index == self.own:
            return
        with self.lock:
            if key in self.seen or len(self.seen) >= MAX_INSTANCES:
                return
            self.seen[key] = index
        self._write({"kind": "up", "peer": index, "key": key})

    def down(self, key: str) -> None:
        if not self.enabled:
            return
        with self.lock:
            index = self.seen.pop(key, None)
        if index is not None:
            self._write({"kind": "down", "peer": index, "key": key})

    def readiness(self, tally: Tally) -> None:
        """The commander's counts, at most once a second (monotonic, so dilated too)."""
        if not self.enabled or time.monotonic() < self._next_readiness:
            return
        self._next_readiness = time.monotonic() + 1.0
        with tally.lock:
            counts = {str(m): c for m, c in sorted(tally.counts.items())}
        self._write({"kind": "readiness", "counts": counts})
