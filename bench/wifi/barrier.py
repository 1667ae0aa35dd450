"""The fair start: every contender process finishes its start-up, then all begin at once.

N Python processes importing Cyclone DDS, zenoh or swarmd on two shared cores take tens of
seconds of CPU, and while they do, ns-3 falls behind real time (docs/testbed.md, pitfall
10). So the harness starts them all at low priority, lets each import and build what it
can, and counts them as they block on a UNIX stream socket (``SWARMD_START_BARRIER`` for
swarmd, ``--barrier`` for the peer scripts); once all N wait, it restores their priority
and releases them with one byte each. The measurement window counts from the release.

A flight run (``bench/wifi/flight_run.py``) may release each drone at its own offset after
that instant instead (``release_staggered``): real drones switched on together boot seconds
apart, and stacks whose periodic announcements carry no jitter stay in lockstep for a whole
run when all start at one instant (docs/testbed.md, "Staggered start"). The harness tells
which connection is which drone by the connecting process's pid (``SO_PEERCRED``), walked up
its parents to the contender process it started (``nice``, ``ip netns exec``, ``unshare``
and ``sh`` sit between them), so no client changes: the peers, the C++ Fast DDS peer and
swarmd's launcher all still wait for one byte.
"""

from __future__ import annotations

import os
import socket
import struct
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Final, Protocol

from swarmd_lab.closing import Closing

LAUNCH_NICE: Final = 10  # imports at nice 10 while ns-3 runs at -10: a 1:~100 CPU weight
RUN_NICE: Final = 0  # during the window the stacks run at normal priority, as before
# parents walked from a connecting pid to the contender process: nice and ip netns exec
# exec, unshare and the ROS 2 host's sh may fork (swarmd_lab.ros2_lab.host_argv)
MAX_WRAPPER_DEPTH: Final = 8


class Process(Protocol):
    """What ``wait_all`` needs of a contender process (``subprocess.Popen`` has it)."""

    @property
    def pid(self) -> int: ...

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
        self._stagger: threading.Thread | None = None
        self._hurry = threading.Event()  # close(): release the rest at once
        # process index -> time.monotonic() its byte was sent (release_staggered)
        self.released_at: dict[int, float] = {}

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

    def release_staggered(self, procs: Sequence[Process], delays_s: Sequence[float]) -> None:
        """Release ``procs[i]`` ``delays_s[i]`` real seconds from now, each by its own
        connection (module doc), from a thread; returns at once. ``released_at`` gets each
        send's ``time.monotonic()``. ``close`` releases whoever still waits at once.

        Raises ``BarrierError`` unless every waiting connection belongs to exactly one of
        ``procs`` and every process has one: a byte to the wrong drone would start it at
        another's offset."""
        if len(delays_s) != len(procs) or any(not d >= 0.0 for d in delays_s):
            raise ValueError(f"release_staggered: {len(procs)} processes, delays {delays_s}")
        pids = {p.pid: i for i, p in enumerate(procs)}
        by_index: dict[int, socket.socket] = {}
        for conn in self._waiting:
            i = owner(peer_pid(conn), pids)
            if i is None or i in by_index:
                raise BarrierError(
                    f"a start-barrier connection (pid {peer_pid(conn)}) is "
                    + (
                        "from none of the contender processes"
                        if i is None
                        else f"a second one of contender {i}"
                    )
                )
            by_index[i] = conn
        if len(by_index) != len(procs):
            missing = sorted(set(range(len(procs))) - set(by_index))
            raise BarrierError(f"contenders {missing} never reached the start barrier")
        self._waiting.clear()
        t0 = time.monotonic()
        order = sorted(range(len(procs)), key=lambda i: delays_s[i])

        def send_in_turn() -> None:
            for i in order:
                self._hurry.wait(max(0.0, t0 + delays_s[i] - time.monotonic()))
                conn = by_index[i]
                # dated before the byte goes: whoever sees the drone started sees the date
                self.released_at[i] = time.monotonic()
                try:
                    conn.sendall(b"g")
                except OSError:
                    pass  # it died meanwhile; the run will show it
                conn.close()

        self._stagger = threading.Thread(target=send_in_turn, name="stagger", daemon=True)
        self._stagger.start()

    def close(self) -> None:
        if self._stagger is not None:
            self._hurry.set()
            self._stagger.join()
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


def peer_pid(conn: socket.socket) -> int | None:
    """The pid of the process at the other end of a UNIX stream connection (Linux
    ``SO_PEERCRED``: the connecting process's pid, uid, gid as three ints)."""
    raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    pid = int(struct.unpack("3i", raw)[0])
    return pid if pid > 0 else None


def parent_pid(pid: int) -> int | None:
    """``pid``'s parent from ``/proc/PID/stat`` (the field after the state, which follows
    the command name's closing parenthesis; the name itself may hold spaces and ``)``)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2 :].split()
    return int(fields[1]) if len(fields) > 1 and fields[1].isdigit() else None


def owner(pid: int | None, pids: dict[int, int]) -> int | None:
    """The index in ``pids`` (pid -> index) of ``pid`` or of its nearest ancestor there,
    walking at most ``MAX_WRAPPER_DEPTH`` parents; None if none is."""
    for _ in range(MAX_WRAPPER_DEPTH + 1):
        if pid is None or pid <= 1:
            return None
        if pid in pids:
            return pids[pid]
        pid = parent_pid(pid)
    return None
