"""A slow disk must not stall the daemon's loop (``swarmd.filewriter``, session 17).

Every save of the state file and of the SPDP replay windows is two fsyncs; on a Jetson
Nano's SD card one can take seconds, and run on the loop it held up discovery, the data
plane, the PX4 link and a take-off in flight (``held_up``). Now the writes run on the
daemon's writer thread. Each test here makes one write wait on a gate that only the
event loop opens, after it has done something (handled a datagram, run a timer) the
blocked write must not stop: on main the write ran on the loop, so the loop could not
open the gate and the write gave up waiting (``gate_timeout``). The waits are bounds, not
measures: nothing asserts how fast anything happened.

Asserted as well: the write-ahead holds across the thread (a vehicle request emitted after
a ``PersistExecuted`` reaches the bridge only once that write has ended); a write that
fails is still told (``state_save_failed``, counted, the core's ``state_saved``) and the
command still runs; a stop while a write is blocked waits for it (the last state is on
disk when ``stop`` returns); a take-off runs to success while a save blocks (on main it
failed: the loop, and the in-process vehicle simulator on it, stood still for the write;
``no_liftoff`` there, where a real PX4 on its own CPU would have met a late retransmission,
``held_up``); the writer coalesces (the newest state wins) and answers every save.
"""

from __future__ import annotations

import asyncio
import errno
import json
import socket
import threading
from collections.abc import AsyncIterator, Callable, MutableMapping
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd import statefile
from swarmd.auth import windows as windows_mod
from swarmd.auth.freshness import Freshness
from swarmd.bundle.safeopen import Folder, write_atomic
from swarmd.daemon import Daemon
from swarmd.px4.takeoff import TakeoffSucceeded
from swarmd.px4.transport import parse_connection
from swarmd.px4.vehicle import TaskKind, VehicleRequest
from swarmd.rawclock import run_on_raw_clock
from swarmd.swarm.events import PersistExecuted
from swarmd.swarmapp import SwarmApp
from tests.daemon_support import (
    BundleFiles,
    loopback_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
)
from tests.test_takeoff_loopback import N, _mavlink_port

GATE_S = 10.0  # how long a blocked write waits for the loop: a bound, not a measure
WAIT_S = 20.0
COMMAND = ("uav2", 7)


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)


class SlowDisk:
    """``write_atomic`` for one file name that, armed, waits on ``gate`` (set from the
    loop) before it writes: a slow card's fsync. ``poke``: called first, on the writing
    thread (it sends the daemon a datagram); ``fail``: the write then raises EROFS."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.gate = threading.Event()
        self.armed = False
        self.fail = False
        self.poke: Callable[[], None] | None = None
        self.log: list[str] = []
        self.submitted_at_write: list[VehicleRequest] | None = None
        self.bridge: FakeBridge | None = None

    def __call__(self, folder: Folder, name: str, data: bytes, mode: int) -> None:
        if not self.armed or name != self.name:
            write_atomic(folder, name, data, mode)
            return
        self.armed = False
        self.log.append("write_started")
        if self.poke is not None:
            self.poke()
        opened = self.gate.wait(GATE_S)
        self.log.append("written" if opened else "gate_timeout")
        if self.bridge is not None:  # what the vehicle had been told when the write ended
            self.submitted_at_write = list(self.bridge.submitted)
        if self.fail:
            raise OSError(errno.EROFS, "Read-only file system")
        write_atomic(folder, name, data, mode)


class FakeBridge:
    """The PX4 bridge as ``SwarmApp`` uses it after start: what it was asked to run."""

    def __init__(self) -> None:
        self.submitted: list[VehicleRequest] = []

    def submit(self, request: VehicleRequest) -> None:
        self.submitted.append(request)

    async def close(self) -> None:
        return None


def _daemon(workdir: Path, files: BundleFiles) -> Daemon:
    extra = swarm_sections(workdir / "state-uav1", None, period_s=0.5)
    return loopback_daemon(workdir, files, "uav1", extra=extra)


def _app(daemon: Daemon) -> SwarmApp:
    assert daemon.app is not None and daemon.app.state is not None
    return daemon.app


def _slow_state_disk(monkeypatch: pytest.MonkeyPatch, daemon: Daemon) -> SlowDisk:
    state = _app(daemon).state
    assert state is not None
    disk = SlowDisk(state.path.name)
    monkeypatch.setattr(statefile, "write_atomic", disk)
    return disk


@asynccontextmanager
async def _slow_member(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> AsyncIterator[tuple[Daemon, SwarmApp, SlowDisk, FakeBridge]]:
    """uav1's daemon started, its state file written through a ``SlowDisk`` (not armed yet:
    it writes at once) and its PX4 bridge a ``FakeBridge``. On the way out the gate opens
    and the daemon stops, within ``WAIT_S`` (a stop that waits for ever fails the test)."""
    daemon = _daemon(workdir, files)
    await daemon.start()
    disk = _slow_state_disk(monkeypatch, daemon)
    try:
        app = _app(daemon)
        bridge = FakeBridge()
        app.bridge = bridge  # type: ignore[assignment]
        yield daemon, app, disk, bridge
    finally:
        disk.gate.set()
        await asyncio.wait_for(daemon.stop("test"), WAIT_S)


def _kept(daemon: Daemon) -> list[list[Any]]:
    state = _app(daemon).state
    assert state is not None
    executed: list[list[Any]] = json.loads(state.path.read_text("utf-8"))["executed"]
    return executed


def _poke_daemon(daemon: Daemon) -> Callable[[], None]:
    """Send one datagram (not RTPS: dropped, counted) to the daemon's metatraffic port."""
    assert daemon.engine is not None
    port = daemon.engine.metatraffic_port

    def poke() -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.sendto(b"not rtps", ("127.0.0.1", port))

    return poke


def _open_when_handled(daemon: Daemon, disk: SlowDisk) -> None:
    """A loop timer, every 10 ms: once the daemon has handled the poke, note it and open
    the gate. Runs only while the loop runs, so only if the write is off the loop."""
    loop = asyncio.get_running_loop()
    before = daemon.counters.get("rx_unicast", 0)

    def tick() -> None:
        if daemon.counters.get("rx_unicast", 0) > before:
            disk.log.append("datagram_handled")
            disk.gate.set()
            return
        if not disk.gate.is_set():
            loop.call_later(0.01, tick)

    loop.call_later(0.01, tick)


def _files(daemon: Daemon) -> dict[str, int]:
    """The writer's counters in ``swarmctl status --json``."""
    daemon_counters: dict[str, int] = daemon.status()["counters"]["daemon"]
    return {k: v for k, v in daemon_counters.items() if k.startswith("file_")}


async def _until(cond: Callable[[], bool], what: str) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not cond():
        if loop.time() > deadline:
            raise AssertionError(f"gave up waiting for {what}")
        await asyncio.sleep(0.02)


@dataclass
class Seen:
    """What one command's write on the slow disk left: the disk's log, what the vehicle
    had been told when the write ended and after, the file's executed ids, the log lines
    and the app's and the executor's counters."""

    disk_log: list[str]
    submitted_at_write: list[VehicleRequest] | None
    submitted: list[VehicleRequest]
    kept: list[list[Any]]
    logs: list[MutableMapping[str, Any]]
    counters: dict[str, int]
    executor: dict[str, int]


HOLD = VehicleRequest(1, TaskKind.HOLD, None, COMMAND)


def _command_on_a_slow_disk(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch, *, fail: bool
) -> Seen:
    """The swarm core's two orders for a received command, ``PersistExecuted`` then a
    ``VehicleRequest``, with the write blocked until the loop has handled a datagram;
    ``fail``: the write then fails (EROFS)."""

    async def main() -> Seen:
        async with _slow_member(workdir, files, monkeypatch) as (daemon, app, disk, bridge):
            disk.poke, disk.bridge, disk.fail = _poke_daemon(daemon), bridge, fail
            disk.armed = True
            _open_when_handled(daemon, disk)
            with capture_logs() as logs:
                app._on_event(PersistExecuted((COMMAND,), command=COMMAND))
                app._on_event(HOLD)
                await _until(lambda: bool(bridge.submitted), "the held request")
            executor = dict(app._core().executor_counters)
            return Seen(
                disk.log,
                disk.submitted_at_write,
                bridge.submitted,
                _kept(daemon),
                logs,
                dict(app.counters),
                executor,
            )

    return run_on_raw_clock(main())


def test_a_blocked_state_write_leaves_the_loop_running_and_the_vehicle_waits_for_it(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """While the member's write-ahead write blocks, the daemon handles a datagram and runs
    its timers; the vehicle request emitted after it reaches the bridge only once the
    write has ended, and the file then holds the command's id."""
    seen = _command_on_a_slow_disk(workdir, files, monkeypatch, fail=False)
    assert seen.disk_log == ["write_started", "datagram_handled", "written"]
    assert seen.submitted_at_write == []  # write-ahead: nothing ran before the write ended
    assert seen.submitted == [HOLD]
    assert list(COMMAND) in seen.kept


def test_a_failed_write_off_the_loop_is_still_told_and_the_command_still_runs(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """docs/dataplane.md, "A failed save": logged with its command, counted, answered to the
    core (``state_saved`` with the error: the commander's ``[not saved on drone]``), and
    the vehicle still gets the command, after the failure is known."""
    seen = _command_on_a_slow_disk(workdir, files, monkeypatch, fail=True)
    assert seen.disk_log == ["write_started", "datagram_handled", "written"]
    failed = [e for e in seen.logs if e["event"] == "state_save_failed"]
    assert len(failed) == 1
    assert (failed[0]["commander"], failed[0]["command_id"]) == COMMAND
    assert seen.counters["state_save_errors"] == 1
    assert seen.executor.get("state_save_failed") == 1
    assert seen.submitted_at_write == []
    assert seen.submitted == [HOLD]
    assert list(COMMAND) not in seen.kept


def test_a_stop_during_a_blocked_write_waits_for_it(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """SIGTERM (``run``'s stop) while a write is blocked: ``stop`` returns after the write
    ended, so the newest state is on disk when the process exits. The vehicle request that
    waited for it never reaches the closing PX4 link (dropped, logged): a stop loses a
    command, never starts one on its way out."""

    async def main() -> None:
        async with _slow_member(workdir, files, monkeypatch) as (daemon, app, disk, bridge):
            disk.armed = True
            loop = asyncio.get_running_loop()

            def open_gate() -> None:
                disk.log.append("opened_during_stop" if daemon.stopped.is_set() else "opened")
                disk.gate.set()

            app._on_event(PersistExecuted((COMMAND,), command=COMMAND))
            newer = (COMMAND, ("uav2", 8))
            app._on_event(PersistExecuted(newer, command=("uav2", 8)))  # coalesced: newest
            app._on_event(HOLD)
            loop.call_later(0.05, open_gate)
            with capture_logs() as logs:
                await daemon.stop("test")
            disk.log.append("stopped")
        assert disk.log == ["write_started", "opened_during_stop", "written", "stopped"]
        assert _kept(daemon) == [list(c) for c in newer]
        assert bridge.submitted == []
        dropped = [e for e in logs if e["event"] == "vehicle_requests_dropped_stopping"]
        assert [e["count"] for e in dropped] == [1]

    run_on_raw_clock(main())


def test_a_blocked_windows_write_leaves_the_loop_running(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The replay windows' save (every ``SAVE_PERIOD_S`` while one moved): the daemon
    handles a datagram while it blocks, and the file holds the windows after."""

    async def main() -> None:
        daemon = _daemon(workdir, files)
        await daemon.start()
        disk = SlowDisk(daemon._windows_path.name)
        monkeypatch.setattr(windows_mod, "write_atomic", disk)
        try:
            auth = daemon._spdp_auth
            assert auth is not None
            prefix = files.bundle.participants[1].guid_prefix.value
            auth.verifier.restore({prefix: Freshness(3, 40)})
            auth.verifier.windows_changed = True
            disk.poke, disk.armed = _poke_daemon(daemon), True
            _open_when_handled(daemon, disk)
            daemon._save_windows()

            def saved() -> Freshness | None:
                return windows_mod.load_windows(daemon._windows_path).highs.get(prefix)

            await _until(lambda: saved() == Freshness(3, 40), "the windows on disk")
            assert disk.log == ["write_started", "datagram_handled", "written"]
            await _until(lambda: _files(daemon)["file_writes_pending"] == 0, "the answer")
            assert _files(daemon)["file_writes"] >= 1  # swarmctl status counts them
        finally:
            disk.gate.set()
            await daemon.stop("test")

    run_on_raw_clock(main())


def test_a_take_off_completes_while_a_windows_save_blocks(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The case that made it matter: a take-off in progress (the vehicle simulator on its
    MAVLink port, the bridge's own take-off) while the replay windows' save blocks. The
    save's gate opens only when the take-off has ended, so the take-off runs to the end on
    the daemon's loop during the write, and succeeds (on main the write held the loop, and
    the take-off with it, until the gate gave up)."""

    async def main() -> None:
        port = _mavlink_port(N)  # beyond the ports tests/test_takeoff_loopback.py uses
        extra = swarm_sections(workdir / "state", f"udpin:127.0.0.1:{port}", period_s=0.5)
        daemon = loopback_daemon(workdir, files, "uav1", extra=extra)
        await daemon.start()
        endpoint = parse_connection(f"udpout:127.0.0.1:{port}")
        sim = await start_sim(SimConfig(sysid=1, gps_fix_after_s=0.2), endpoint, seed=0)
        disk = SlowDisk(daemon._windows_path.name)
        try:
            bridge = _app(daemon).bridge
            auth = daemon._spdp_auth
            assert bridge is not None and auth is not None
            await _until(lambda: bridge.readiness().ready, "the simulated vehicle ready")
            monkeypatch.setattr(windows_mod, "write_atomic", disk)
            takeoff = asyncio.create_task(bridge.takeoff(5.0))

            def ended(_task: object) -> None:
                disk.log.append("takeoff_ended")
                disk.gate.set()

            takeoff.add_done_callback(ended)
            await _until(lambda: bridge.state.armed is True, "the vehicle armed")
            prefix = files.bundle.participants[1].guid_prefix.value
            auth.verifier.restore({prefix: Freshness(3, 40)})
            auth.verifier.windows_changed = True
            disk.armed = True
            daemon._save_windows()
            outcome = await asyncio.wait_for(takeoff, WAIT_S)
            assert isinstance(outcome, TakeoffSucceeded), outcome
            await _until(lambda: disk.log[-1] in ("written", "gate_timeout"), "the write's end")
            assert disk.log == ["write_started", "takeoff_ended", "written"]
        finally:
            disk.gate.set()
            sim.close()
            await daemon.stop("test")

    run_on_raw_clock(main())


# ---- the writer alone ---------------------------------------------------------------------


def test_the_writer_coalesces_to_the_newest_and_answers_every_save_in_order() -> None:
    """Saves 2 and 3 queued while 1 blocks: 3 replaces 2 (the newest state wins), 2's and
    3's callers are both told, after 1's, with 3's result; a failing write's error reaches
    its caller; ``flush`` waits for all of it."""

    from swarmd.filewriter import FileWriter  # here: the daemon tests above run on main too

    async def main() -> None:
        writer = FileWriter()
        gate, started = threading.Event(), threading.Event()
        written: list[int] = []
        told: list[tuple[int, str | None]] = []

        def write(n: int) -> None:
            if n == 1:
                started.set()
                assert gate.wait(GATE_S)
            if n == 4:
                raise OSError(errno.ENOSPC, "No space left on device")
            written.append(n)

        def done(n: int) -> Callable[[Exception | None], None]:
            return lambda error: told.append((n, None if error is None else type(error).__name__))

        writer.submit("state", lambda: write(1), done(1))
        await _until(started.is_set, "the first write to start")
        for n in (2, 3):
            writer.submit("state", lambda n=n: write(n), done(n))  # type: ignore[misc]
        writer.submit("other", lambda: write(4), done(4))
        assert told == []  # nothing waited for the blocked write
        gate.set()
        await writer.flush()
        assert written == [1, 3]
        assert [t for t in told if t[0] != 4] == [(1, None), (2, None), (3, None)]
        assert (4, "OSError") in told
        assert writer.counters == {
            "writes": 3,
            "writes_coalesced": 1,
            "write_errors": 1,
            "thread_start_errors": 0,
        }
        assert writer.outstanding == 0

    asyncio.run(main())


def _no_thread(times: int) -> Callable[[threading.Thread], None]:
    """``threading.Thread.start`` that fails (EAGAIN: ``can't start new thread``) for the
    writer's thread, ``times`` times, then starts threads again."""
    real, left = threading.Thread.start, [times]

    def start(thread: threading.Thread) -> None:
        if thread.name == "swarmd-files" and left[0] > 0:
            left[0] -= 1
            raise RuntimeError("can't start new thread")
        real(thread)

    return start


def test_a_writer_thread_that_cannot_start_still_writes_and_answers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Review 17b: the thread's start failed (a task or memory limit) once. On main the
    writer kept the unstarted thread as its own, so no later save ever started: every
    caller waited for good (and ``submit`` raised into the caller). Now the save is
    written on the loop instead, every caller is answered and the next save has its
    thread again."""
    from swarmd.filewriter import FileWriter

    monkeypatch.setattr(threading.Thread, "start", _no_thread(1))

    async def main() -> None:
        writer = FileWriter()
        written: list[int] = []
        told: list[int] = []
        for n in (1, 2):
            writer.submit("state", lambda n=n: written.append(n), lambda _e, n=n: told.append(n))  # type: ignore[misc]
            await asyncio.wait_for(writer.flush(), WAIT_S)
        assert written == [1, 2]
        assert told == [1, 2]
        assert writer.counters["thread_start_errors"] == 1
        assert writer.outstanding == 0

    asyncio.run(main())


def test_a_vehicle_request_goes_when_the_writer_thread_cannot_start(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 17b, the daemon's view of the above: a received command's write-ahead and
    its vehicle request, dispatched by the driver as in flight. On main the write's
    ``submit`` raised (counted as a handler error), the write never ran and the request
    was held for good: no LAND or ABORT after it would have reached the vehicle, and the
    stop's flush waited for ever (systemd's SIGKILL after ``TimeoutStopSec``). Now the
    file holds the command, the request reaches the bridge and the stop returns."""

    async def main() -> None:
        # the stop on the way out is bounded: on main its flush waited for the write that
        # never ran
        async with _slow_member(workdir, files, monkeypatch) as (daemon, app, _disk, bridge):
            monkeypatch.setattr(threading.Thread, "start", _no_thread(1))
            core = app._core()
            core._events.extend([PersistExecuted((COMMAND,), command=COMMAND), HOLD])
            app._driver().drain()
            await _until(lambda: bool(bridge.submitted), "the held request")
            assert bridge.submitted == [HOLD]
            assert list(COMMAND) in _kept(daemon)

    run_on_raw_clock(main())


def test_a_received_commands_saves_are_one_write_before_its_request(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Review 17b: a received command is two ``PersistExecuted`` in one drain (its id, then
    its outcome) before its ``VehicleRequest``. The writer started its thread inside the
    first ``submit``, so the first write ran alone and the request waited for two writes
    in a row (two fsyncs of a slow card against a take-off's 3 s validity). Now the saves
    of one loop callback are one write: the request goes after that one, and the file
    holds both."""

    async def main() -> None:
        async with _slow_member(workdir, files, monkeypatch) as (daemon, app, disk, bridge):
            writer = daemon.writer
            await _until(lambda: writer.outstanding == 0, "start-up saves")
            before = dict(writer.counters)
            disk.bridge, disk.armed = bridge, True
            newer = (COMMAND, ("uav2", 8))
            core = app._core()
            core._events.extend(
                [
                    PersistExecuted((COMMAND,), command=COMMAND),
                    PersistExecuted(newer, command=("uav2", 8)),
                    HOLD,
                ]
            )
            app._driver().drain()
            asyncio.get_running_loop().call_later(0.05, disk.gate.set)
            await _until(lambda: bool(bridge.submitted), "the held request")
            after = dict(writer.counters)
            assert disk.log == ["write_started", "written"]
            assert disk.submitted_at_write == []  # the write-ahead still holds
            assert after["writes"] - before["writes"] == 1
            assert after["writes_coalesced"] - before["writes_coalesced"] == 1
            assert _kept(daemon) == [list(c) for c in newer]

    run_on_raw_clock(main())
