"""The fair start: every contender process finishes its start-up, then all begin at once.

N Python processes importing Cyclone DDS, zenoh or swarmd on two shared cores take tens of
seconds of CPU, and while they do, ns-3 falls behind real time (docs/testbed.md, pitfall
10). So the harness starts them all at low priority, lets each import and build what it
can, and counts them as they block on a UNIX stream socket (``SWARMD_START_BARRIER`` for
swarmd, ``--barrier`` for the peer scripts); once all N wait, it restores their priority
and releases them with one byte each. The measurement window counts from the release.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Final, Protocol

from swarmd_lab.closing import Closing

LAUNCH_NICE: Final = 10  # imports at nice 10 while ns-3 runs at -10: a 1:~100 CPU weight
RUN_NICE: Final = 0  # during the window the stacks run at normal priority, as before


class Process(Protocol):
    """What ``wait_all`` needs of a contender process (``subprocess.Popen`` has it)."""

    @property
    def returncode(self) -> int | None: ...

    def poll(self) -> int | None: ...


class BarrierError(RuntimeError):
    """The contenders did not all reach the barrier (one died or start-up hung)."""


class StartBarrier(Closing):
    """A listening UNIX socket; ``wait_all`` counts arrivals, ``release`` lets them go."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(str(path))
        self._listener.listen(256)
        self._waiting: list[socket.socket] = []

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    def wait_all(self, procs: Sequence[Process], timeout_s: float) -> float:
        """Block until every process in ``procs`` waits; the seconds it took."""
        t0 = time.monotonic()
        self._listener.settimeout(0.5)
        while len(self._waiting) < len(procs):
            dead = [p for p in procs if p.poll() is not None]
            if dead:
                raise BarrierError(
                    f"contender {procs.index(dead[0])} exited with {dead[0].returncode} "
                    "before the start barrier (see its log with --keep-logs)"
                )
            if time.monotonic() - t0 > timeout_s:
                raise BarrierError(
                    f"{len(self._waiting)}/{len(procs)} contenders reached the start barrier "
                    f"in {timeout_s:.0f} s"
                )
            try:
                conn, _ = self._listener.accept()
            except TimeoutError:
                continue
            self._waiting.append(conn)
        return time.monotonic() - t0

    def release(self) -> None:
        """Let every waiting process go (one byte each, then close)."""
        for conn in self._waiting:
            try:
                conn.sendall(b"g")
            except OSError:
                pass  # it died meanwhile; the run will show it
        for conn in self._waiting:
            conn.close()
        self._waiting.clear()

    def close(self) -> None:
        self.release()
        self._listener.close()
        self.path.unlink(missing_ok=True)


def set_priority(pid: int, nice: int) -> None:
    """Set ``nice`` on every thread of ``pid`` (Linux priorities are per thread)."""
    try:
        tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except FileNotFoundError:
        return  # exited; the run reports it
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except (ProcessLookupError, PermissionError):
            pass
