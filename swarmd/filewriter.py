"""The daemon's file writes, off its event loop: one writer thread, the newest state wins.

Why: every save of the state file (a member's command record) and of the SPDP replay
windows is ``safeopen.write_atomic``: a temp file, an fsync, a rename and an fsync of the
folder. A Jetson Nano boots from an SD card, where one fsync under write load takes
hundreds of milliseconds to seconds. Run on the loop, that stalled the whole daemon:
discovery, readiness, the PX4 link, and a take-off in flight, whose retransmission then
came late and failed ``held_up`` (``px4/takeoff.py``) on an honest drone
(docs/operations.md, "A slow SD card").

What this is: ``submit(key, write, done)`` from the loop queues ``write`` (a callable that
does the blocking I/O) under ``key`` (one per file) and returns at once. One thread at a
time runs the queued writes, oldest key first, so writes never overlap. A write queued
under a key whose previous write has not started yet replaces it (coalescing: the newest
state wins; every save holds the whole file, so the replaced one's content is in it) and
its ``done`` joins the list. When a write ends, each of its ``done(error)`` runs on the loop
(``call_soon_threadsafe``), in the order they were submitted, with the write's error
(None: written). So the loop never waits for a write, and every caller learns how its
save went: ``swarmapp_saves.StateSaves._persist`` (the write-ahead before the vehicle
moves, and the ``[not saved on drone]`` report of a failed save),
``daemon.Daemon._save_windows``.

The thread is started from the loop's next turn (``call_soon``), not inside ``submit``: the
saves one loop callback asks for become one write. A received command is two
``PersistExecuted`` in one drain (its id, then its outcome) before its ``VehicleRequest``;
started at once, the first write ran alone and the request waited for two writes in a row,
two fsyncs of a slow card against a take-off's 3 s validity (review 17b; the request is
refused ``expired_before_start`` past it, docs/dataplane.md).

``flush()`` waits, on the loop, until every submitted write has ended and its ``done`` has
run: the daemon's stop (SIGTERM, ``systemctl stop``) writes the last state before it exits.
The thread exists only while writes are queued and is not a daemon thread, so even an
interpreter that exits without ``flush`` finishes the write under way first.

Daemon tier (threads, the loop); the cores never see it: they emit ``PersistExecuted`` and
are told ``state_saved`` as before.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

Done = Callable[[Exception | None], None]
THREAD_NAME: Final = "swarmd-files"


@dataclass(slots=True)
class _Job:
    write: Callable[[], None]
    done: list[Done] = field(default_factory=list)


class FileWriter:
    """Blocking file writes run on one thread at a time, coalesced per key (module
    docstring). ``submit`` and ``flush`` are called on the event loop; ``counters``:
    ``writes``, ``writes_coalesced`` (saves replaced by a newer one before they started),
    ``write_errors``, ``thread_start_errors`` (the thread could not start: written on the
    loop instead); ``swarmctl status`` shows them as ``file_*``."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: dict[str, _Job] = {}  # key -> its newest write not started yet
        self._thread: threading.Thread | None = None
        self._start_asked = False  # a thread start is queued on the loop (loop side only)
        self._loop: asyncio.AbstractEventLoop | None = None
        # submitted writes whose ``done`` has not run yet (loop side only)
        self._outstanding = 0
        self._idle: asyncio.Event | None = None
        self.counters: dict[str, int] = {
            "writes": 0,
            "writes_coalesced": 0,
            "write_errors": 0,
            "thread_start_errors": 0,
        }

    @property
    def outstanding(self) -> int:
        """Writes submitted whose ``done`` has not run yet (``swarmctl status``)."""
        return self._outstanding

    def submit(self, key: str, write: Callable[[], None], done: Done) -> None:
        """Queue ``write`` under ``key``; ``done(error)`` runs on the loop once the write (or
        a newer one under the same key that replaced it) has ended. Never blocks."""
        if self._loop is None:
            self._loop = asyncio.get_running_loop()
            self._idle = asyncio.Event()
        assert self._idle is not None  # noqa: S101 - set with the loop
        self._idle.clear()
        with self._lock:
            job = self._pending.get(key)
            if job is None:
                self._pending[key] = _Job(write, [done])
                self._outstanding += 1
            else:  # not started yet: the newer state replaces it, both are answered
                job.write = write
                job.done.append(done)
                self.counters["writes_coalesced"] += 1
            idle = self._thread is None
        if idle and not self._start_asked:  # a running thread picks the job up itself
            self._start_asked = True
            self._loop.call_soon(self._start)

    def _start(self) -> None:
        """On the loop, the turn after the first ``submit`` of a burst (module docstring):
        start the thread for what is queued, unless one runs already."""
        self._start_asked = False
        with self._lock:
            if self._thread is not None or not self._pending:
                return
            thread = self._thread = threading.Thread(target=self._run, name=THREAD_NAME)
        try:
            thread.start()
        except RuntimeError:
            # no thread (EAGAIN: a task or memory limit). Left set, ``_thread`` would keep
            # every later write queued for good, and every vehicle request held behind
            # them, a LAND's included (review 17b): write here, on the loop, the way
            # every save ran before session 17; ``_run`` ends by clearing ``_thread``
            self.counters["thread_start_errors"] += 1
            self._run()

    async def flush(self) -> None:
        """Wait until every write submitted so far has ended and its ``done`` has run."""
        if self._idle is not None and self._outstanding:
            await self._idle.wait()

    def _run(self) -> None:
        """The writer thread: the queued writes, oldest key first, until none is left."""
        loop = self._loop
        assert loop is not None  # noqa: S101 - submit set it before starting us
        while True:
            with self._lock:
                if not self._pending:
                    self._thread = None
                    return
                key = next(iter(self._pending))
                job = self._pending.pop(key)
            error: Exception | None = None
            try:
                job.write()
            except Exception as exc:  # noqa: BLE001 - handed to the caller's ``done``
                error = exc
            try:
                loop.call_soon_threadsafe(self._finish, job, error)
            except RuntimeError:  # the loop is closed: nobody is left to tell
                pass

    def _finish(self, job: _Job, error: Exception | None) -> None:
        """On the loop: the write ended; tell each caller, in submission order."""
        self.counters["writes"] += 1
        if error is not None:
            self.counters["write_errors"] += 1
        for done in job.done:
            try:
                done(error)
            except Exception as exc:  # noqa: BLE001 - one caller's bug must not lose the rest
                assert self._loop is not None  # noqa: S101 - set at the first submit
                self._loop.call_exception_handler(
                    {"message": "a file write's done callback raised", "exception": exc}
                )
        self._outstanding -= 1
        if self._outstanding == 0 and self._idle is not None:
            self._idle.set()
