"""A member host that suspends never runs a command late (session 16 command review).

The validity proof needs each node's clock to measure its own intervals (docs/dataplane.md,
"Validity"). The daemon's clock was CLOCK_MONOTONIC_RAW alone, and Linux stops it, as it
stops CLOCK_MONOTONIC, while the system is suspended; only CLOCK_BOOTTIME counts the sleep
(clock_gettime(2)). A companion computer put to sleep (a Jetson's suspend, to save the
battery on the ground) freezes its processes first and takes its network down after, so a
command that arrives in between waits in the daemon's socket buffer. On resume the member
read its elapsed time without the sleep: the command had spent none of its validity, and
a TAKEOFF ran a minute after the commander had told the operator it could no longer run
there (``unreachable``, ``not_reached_while_valid``).

The test drives the member's swarm core on the daemon's own clock,
``RawClockEventLoop.time()``, reading a played kernel: a suspend stops CLOCK_MONOTONIC_RAW
and CLOCK_MONOTONIC and leaves CLOCK_BOOTTIME running. Everything else is the virtual-time
swarm of ``tests/test_swarm_core.py`` (``Swarm``, ``MemNet``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import pytest
from swarmd_lab.memnet import Address

from swarmd.dataplane.validity import EXPIRED
from swarmd.px4.vehicle import TaskKind
from swarmd.rawclock import RawClockEventLoop
from swarmd.swarm.commander import NOT_REACHED, UNREACHABLE
from swarmd.swarm.core import SwarmCore
from swarmd.swarm.events import SwarmEvent
from tests.test_swarm_core import Swarm

SLEEP_S = 60.0  # the host's suspend: far past a TAKEOFF's 3 s validity and the 2 s grace
# CLOCK_MONOTONIC and CLOCK_BOOTTIME share an origin; CLOCK_MONOTONIC_RAW has its own (they
# part by whatever NTP has slewed since boot). The raw origin is 0 so the played host's
# clock starts where the swarm's virtual time does.
MONOTONIC_ORIGIN_S = 5_000.0


class PlayedKernel:
    """The member host's clocks as clock_gettime(2) reads them, at the true time
    ``now()``: a suspend stops CLOCK_MONOTONIC_RAW and CLOCK_MONOTONIC; CLOCK_BOOTTIME is
    CLOCK_MONOTONIC plus every suspend since boot. CLOCK_MONOTONIC is slewed ``slew``
    against the raw clock (NTP's, as chrony's ``maxslewrate`` allows)."""

    def __init__(self, now: Callable[[], float], slew: float = 0.0) -> None:
        self._now = now
        self._slew = slew
        self.slept = 0.0
        self._since: float | None = None

    def suspend(self) -> None:
        self._since = self._now()

    def resume(self) -> None:
        assert self._since is not None
        self.slept += self._now() - self._since
        self._since = None

    def clock_gettime(self, clock: int) -> float:
        awake = (self._now() if self._since is None else self._since) - self.slept
        monotonic = MONOTONIC_ORIGIN_S + awake * (1.0 + self._slew)
        if clock == time.CLOCK_BOOTTIME:
            return monotonic + self.slept
        if clock == time.CLOCK_MONOTONIC:
            return monotonic
        if clock == time.CLOCK_MONOTONIC_RAW:
            return awake
        raise AssertionError(f"the daemon's clock read clock id {clock}")


class SuspendableHost:
    """A member's swarm core on a host that can sleep, its ``now`` the daemon's clock.

    Asleep, the process runs nothing: its timers do not fire, and what the network still
    delivers before it goes down waits in the socket buffer, read on resume."""

    def __init__(self, core: SwarmCore, clock: Callable[[], float], true: Callable[[], float]):
        self.core = core
        self._clock = clock
        self._true = true
        self.asleep = False
        self.socket_buffer: list[tuple[bytes, Any]] = []
        self._due = self._fire = math.inf  # the core's deadline, and the true time it falls

    def receive_datagram(self, data: bytes, source: Any, now: float) -> None:
        if self.asleep:
            self.socket_buffer.append((data, source))
            return
        self.core.receive_datagram(data, source, self._clock())

    def handle_timer(self, now: float) -> None:
        if not self.asleep:
            # fired at the true time the host's clock reaches the core's deadline: read as
            # at least that (the two clocks' float sums differ in the last bits)
            self.core.handle_timer(max(self._clock(), self._due if now >= self._fire else 0.0))

    def datagrams_to_send(self) -> Sequence[tuple[bytes, Address]]:
        return [] if self.asleep else self.core.datagrams_to_send()

    def get_timer(self) -> float | None:
        deadline = None if self.asleep else self.core.get_timer()
        if deadline is None:
            return None
        # the core's deadline is on the host's clock; the network runs on the true time
        self._due, self._fire = deadline, deadline + self._true() - self._clock()
        return self._fire

    def next_event(self) -> SwarmEvent | None:
        return None if self.asleep else self.core.next_event()

    def resume(self) -> None:
        self.asleep = False
        buffered, self.socket_buffer = self.socket_buffer, []
        for data, source in buffered:
            self.core.receive_datagram(data, source, self._clock())


@pytest.fixture
def loop() -> Iterator[RawClockEventLoop]:
    built = RawClockEventLoop()
    yield built
    built.close()


def _daemon_clock(
    loop: RawClockEventLoop, kernel: PlayedKernel, monkeypatch: pytest.MonkeyPatch
) -> Callable[[], float]:
    """``loop.time()``, the ``now`` every core of the daemon sees, on the played kernel."""

    def read() -> float:
        with monkeypatch.context() as patch:
            patch.setattr(time, "clock_gettime", kernel.clock_gettime)
            return loop.time()

    return read


def test_a_takeoff_waiting_in_a_suspended_members_socket_buffer_never_runs_late(
    loop: RawClockEventLoop, monkeypatch: pytest.MonkeyPatch
) -> None:
    """[fails on main: m01 ran the TAKEOFF 60 s after its validity, after the commander
    had said `unreachable`: it can no longer run there]"""
    swarm = Swarm(2, seed=16)
    kernel = PlayedKernel(lambda: swarm.net.now)
    m01 = swarm.ids["m01"]
    host = SuspendableHost(
        swarm.cores["m01"], _daemon_clock(loop, kernel, monkeypatch), lambda: swarm.net.now
    )
    swarm.net.replace(m01, host)
    swarm.run(3.0)
    # the host goes to sleep: its processes freeze first, its Wi-Fi goes down after
    host.asleep = True
    kernel.suspend()
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    assert "m01" in sent["ready"], sent  # its last report is fresh
    cid = int(sent["command_id"])
    swarm.run(0.05)
    assert host.socket_buffer, "the TAKEOFF reached m01 before its network went down"
    swarm.net.isolate(m01)
    swarm.run(SLEEP_S)
    row = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"]["m01"]
    assert (row["state"], row["reason"]) == (UNREACHABLE, NOT_REACHED)  # "can no longer run"
    # a minute later the host wakes and reads its socket buffer
    kernel.resume()
    swarm.net.isolate(m01, False)
    host.resume()
    swarm.net.poke(m01)
    assert swarm.requests("m01") == [], "the TAKEOFF ran a minute late"
    swarm.run(3.0)
    counters = swarm.cores["m01"].executor_status()["counters"]
    assert counters["refused_expired"] == 1
    row = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)["nodes"]["m01"]
    assert (row["state"], row["reason"]) == ("rejected", EXPIRED)
    assert swarm.requests("m01") == []


def test_the_daemons_clock_counts_a_suspend(
    loop: RawClockEventLoop, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The clock itself: across a 60 s suspend ``loop.time()`` moves 60 s, and between
    suspends it is CLOCK_MONOTONIC_RAW's rate (the played kernel does not slew; the slew
    is ``tests/test_clock_raw.py``'s). [fails on main: it moved 0 s across the sleep]"""
    true = [100.0]
    kernel = PlayedKernel(lambda: true[0])
    clock = _daemon_clock(loop, kernel, monkeypatch)
    before = clock()
    kernel.suspend()
    true[0] += SLEEP_S
    kernel.resume()
    true[0] += 1.5
    assert clock() - before == pytest.approx(SLEEP_S + 1.5)


def test_the_daemons_clock_never_runs_backwards_when_a_read_is_paused(
    loop: RawClockEventLoop, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sleep since boot is a difference of two clocks, read one after the other, and a
    thread can be paused between any two reads. Read in the order BOOTTIME, MONOTONIC,
    RAW, a pause only makes that read stale, never ahead of the next one, while MONOTONIC
    runs slower than RAW (the next test: either way, by the loop's guard). [MONOTONIC
    before BOOTTIME, or RAW between them: the clock steps back; of the six orders only RAW,
    MONOTONIC, BOOTTIME also holds]"""
    true = [300.0]
    kernel = PlayedKernel(lambda: true[0], slew=-0.08)
    kernel.suspend()
    true[0] += 30.0
    kernel.resume()
    reads = [0]
    # three reads a call: paused after the 1st read of the 1st call, the 2nd of the 3rd,
    # the 3rd of the 5th; each paused call followed by one that is not
    pause_after = {0, 7, 14}

    def paused(clock: int) -> float:
        value = kernel.clock_gettime(clock)
        if reads[0] in pause_after:
            true[0] += 0.004
        reads[0] += 1
        true[0] += 1e-6
        return value

    def read() -> float:
        with monkeypatch.context() as patch:
            patch.setattr(time, "clock_gettime", paused)
            return loop.time()

    seen = [read() for _ in range(8)]
    assert all(b > a for a, b in zip(seen, seen[1:], strict=False)), seen
    assert seen[-1] - seen[0] == pytest.approx(true[0] - 300.0 - 30.0, abs=0.01)


@pytest.mark.parametrize("slew", [-0.08, 0.08, -0.0005, 0.0005])
@pytest.mark.parametrize("paused_read", range(3, 12))
def test_the_daemons_clock_never_runs_backwards_whichever_way_ntp_slews(
    loop: RawClockEventLoop, monkeypatch: pytest.MonkeyPatch, slew: float, paused_read: int
) -> None:
    """NTP slews CLOCK_MONOTONIC either way against the raw clock: chrony runs it fast
    while the system clock is behind (up to 8 %), and a slow crystal's frequency is
    corrected for good (up to 500 ppm). A call paused after any one read, with calls before
    and after it (each read 1 us apart), never reads earlier than the call before it.
    [on main: a pause between the BOOTTIME and MONOTONIC reads with MONOTONIC fast steps
    the clock back by the pause times the slew, 0.32 ms at 8 % for a 4 ms pause]"""
    true = [300.0]
    kernel = PlayedKernel(lambda: true[0], slew=slew)
    kernel.suspend()
    true[0] += 30.0
    kernel.resume()
    reads = [0]

    def paused(clock: int) -> float:
        value = kernel.clock_gettime(clock)
        if reads[0] == paused_read:
            true[0] += 0.004
        reads[0] += 1
        true[0] += 1e-6
        return value

    with monkeypatch.context() as patch:
        patch.setattr(time, "clock_gettime", paused)
        seen = [loop.time() for _ in range(5)]
    assert all(b >= a for a, b in zip(seen, seen[1:], strict=False)), seen


def test_on_the_real_kernel_the_clock_is_raw_plus_the_sleep_since_boot(
    loop: RawClockEventLoop,
) -> None:
    """On this host: ``loop.time()`` lies between two reads of CLOCK_MONOTONIC_RAW plus
    CLOCK_BOOTTIME minus CLOCK_MONOTONIC (an ordering, not a timing)."""

    def raw_plus_sleep() -> float:
        boot = time.clock_gettime(time.CLOCK_BOOTTIME)
        monotonic = time.clock_gettime(time.CLOCK_MONOTONIC)
        return time.clock_gettime(time.CLOCK_MONOTONIC_RAW) + boot - monotonic

    before = raw_plus_sleep()
    now = loop.time()
    after = raw_plus_sleep()
    assert before <= now <= after, (before, now, after)


def test_a_commander_that_slept_dates_its_table_and_commands_on_the_time_that_passed(
    loop: RawClockEventLoop, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The commander's host sleeps a minute. On resume, before any new report: its table
    knows the reports are a minute old (``report_stale``), and a LAND issued at once
    echoes m01's last report with the minute in its age, so m01 runs it.
    [fails on main: the table said ready on minute-old reports, and the LAND echoed a
    near-zero age, so m01 refused it `expired` although it reached it at once]"""
    swarm = Swarm(2, seed=17)
    kernel = PlayedKernel(lambda: swarm.net.now)
    lead = swarm.ids["lead"]
    clock = _daemon_clock(loop, kernel, monkeypatch)
    host = SuspendableHost(swarm.lead, clock, lambda: swarm.net.now)
    swarm.net.replace(lead, host)
    swarm.run(3.0)
    # nothing waits in its socket buffer (a report read after the sleep is dated at its
    # read: docs/dataplane.md, "A host that sleeps")
    swarm.net.isolate(lead)
    swarm.run(0.05)
    host.asleep = True
    kernel.suspend()
    swarm.run(SLEEP_S)
    kernel.resume()
    swarm.net.isolate(lead, False)
    host.resume()
    swarm.net.poke(lead)
    rows = swarm.lead.table.rows(clock())
    assert (rows["m01"]["ready"], rows["m01"]["reason"]) == (False, "report_stale"), rows
    sent = swarm.lead.request_command({"kind": "land", "only": ["m01"]}, clock())
    swarm.net.poke(lead)
    swarm.run(3.0)
    row = swarm.lead.request_outcomes({"command_id": sent["command_id"]}, clock())["nodes"]
    assert row["m01"]["state"] == "completed", row
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.LAND]
