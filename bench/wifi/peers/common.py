"""What the Cyclone DDS and zenoh workload scripts share: arguments, the result file, stop.

Every peer runs inside one drone's namespace. A member publishes ``(member, seq)`` at 1 Hz
from seq 1; the commander (index 0) subscribes and records, per member, how many samples
arrived and the wall time of the ``--messages``-th one (the paper's success criterion,
section 5.1: the subscriber receives the 20th message of every publisher within the
window). Each peer writes one JSON result file when ``--duration`` ends or on SIGTERM.
With ``--barrier PATH`` a peer, once imported, waits on the harness's start barrier
(bench/wifi/barrier.py) before it creates its participant or session.
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
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--index", type=int, required=True, help="0 = commander, else member")
    p.add_argument("--n", type=int, required=True, help="swarm size")
    p.add_argument("--duration", type=float, required=True, help="seconds to run")
    p.add_argument("--messages", type=int, default=20, help="success = this many received")
    p.add_argument("--period", type=float, default=1.0, help="seconds between publications")
    p.add_argument("--out", type=Path, required=True, help="result JSON file")
    p.add_argument("--barrier", type=Path, help="UNIX socket of the harness's start barrier")
    return p.parse_args()


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
