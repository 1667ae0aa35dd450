"""A PX4 that reboots behind a MAVLink link: the last life's state is forgotten
(docs/px4.md, "Fresh state", "A PX4 that reboots").

Over XRCE-DDS a new session hands the vehicle state a ``StateReset``. MAVLink has no
session: a rebooted PX4's first HEARTBEAT met the last life's landed state, GPS fix, home
and battery until each was sent again, so readiness judged the new life by the old one's
facts and an ABORT sent NAV_LAND to a vehicle on the ground from the old IN_AIR. Now the
MAVLink intake tells a new life by PX4's boot clock (``time_boot_ms`` going back:
``boot_watch``), from trusted frames only, and hands the core the same ``StateReset``.

Virtual time: the simulator's frames cross as real MAVLink 2 bytes (signed when a key is
given) into ``MavlinkIntake`` and a ``VehicleCore``, one message per datagram as PX4 sends
on UDP; the simulator reboots with ``SimVehicle.reboot`` (silent while it boots).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.px4.sim_model import REBOOT_S, SimConfig
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd.cli.status_cmd import render_px4_backend
from swarmd.px4.boot_watch import (
    BOOT_CLOCK_WRAP,
    REBOOT_JUMP_MS,
    SILENCE_S,
    UNDECIDED_MAX_S,
    BootWatch,
)
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, COMP_ID_ONBOARD_COMPUTER, LandedState
from swarmd.px4.linkguard import AutopilotPin
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.mavlink_intake import MavlinkIntake
from swarmd.px4.messages import BootClock, Observation, StateReset, VehicleCommand
from swarmd.px4.readiness import Reason
from swarmd.px4.signing import TICKS_PER_S, timestamp_from_unix
from swarmd.px4.takeoff import TakeoffPhase
from swarmd.px4.transport import UdpLink, parse_connection
from swarmd.px4.vehicle import (
    ON_GROUND_DISARMED,
    ReadinessChanged,
    TaskKind,
)
from tests.test_px4_vehicle import Bench

PX4 = "127.0.0.1:14580"
ELSEWHERE = "127.0.0.1:40000"
KEY = bytes(range(1, 33))
T0 = timestamp_from_unix(1_790_000_000.0)  # the signing clock at virtual time 0
LATENCY_S = 0.005


def _clock(now: float) -> int:
    return T0 + int(now * TICKS_PER_S)


class MavBench(Bench):
    """``SimVehicle`` -> MAVLink bytes -> ``MavlinkIntake`` -> ``VehicleCore`` and back
    (``Bench`` of test_px4_vehicle, its requests and tasks, with the wire in between)."""

    def __init__(self, config: SimConfig | None = None, key: bytes | None = None) -> None:
        super().__init__(config)
        self.px4_codec = MavlinkCodec(1, COMP_ID_AUTOPILOT1, signing_key=key)
        codec = MavlinkCodec(1, COMP_ID_ONBOARD_COMPUTER, signing_key=key)
        self.companion_codec = codec
        self.intake = MavlinkIntake(
            codec, sysid=1, compid=COMP_ID_ONBOARD_COMPUTER, pin=AutopilotPin(), datagrams=True
        )
        self.delivered: list[tuple[float, Observation]] = []
        self.sent_at: list[tuple[float, VehicleCommand]] = []  # when each reached PX4
        self.wire_up: list[tuple[object, bytes]] = []  # (message, datagram) PX4 sent

    def _deliver(self, direction: str, msg: Observation | VehicleCommand | BootClock) -> None:
        """As ``Bench``, but each message crosses as one MAVLink 2 datagram, signed with the
        clock of its arrival (the latency is a few ms), into the intake."""
        if direction == "down":
            assert isinstance(msg, VehicleCommand)
            self.sent_at.append((self.now, msg))
            self.companion_codec.advance_clock(_clock(self.now))
            self.px4_codec.advance_clock(_clock(self.now))
            data = self.companion_codec.encode(msg)
            for frame in self.px4_codec.feed(data, datagram=True):
                self.sim.receive(frame.msg, (frame.src_system, frame.src_component), self.now)
            self._pump_sim()
            return
        self.px4_codec.advance_clock(_clock(self.now))
        data = self.px4_codec.encode(msg)
        self.wire_up.append((msg, data))
        self.receive(data, PX4)

    def receive(self, data: bytes, source: str) -> None:
        """One datagram from ``source`` reaches the companion now."""
        self.companion_codec.advance_clock(_clock(self.now))
        for obs in self.intake.receive(data, source, self.now):
            self.delivered.append((self.now, obs))
            self.core.receive_datagram(obs, None, self.now)
        self._pump_core()

    def reboot_and_await_first_heartbeat(self) -> float:
        """PX4 power-cycles now; run until its new life's first HEARTBEAT is delivered (and
        nothing after it: the frames the new life sent with it are still in flight)."""
        at = self.now
        self.sim.reboot(at)
        # past the last life's frames still in flight: its new life wakes REBOOT_S later
        self.run(REBOOT_S + 1.0, stop=lambda: self.heard_since(at + REBOOT_S))
        assert self.heard_since(at + REBOOT_S)
        return at

    def heard_since(self, t: float) -> bool:
        return self.core.state.heartbeat_at is not None and self.core.state.heartbeat_at > t


# ---- the vehicle across a reboot ----------------------------------------------------------


def test_readiness_after_a_reboot_does_not_use_the_last_lifes_gps_home_or_landed_state() -> None:
    """Ready on the ground, then PX4 reboots; its new life has no fix and no home for 2 s
    after it wakes. The new life's first HEARTBEAT made the vehicle ready again with the last
    life's GPS fix, home, PREARM and landed state, until the new life's SYS_STATUS said
    otherwise. Now a ``StateReset`` comes first and each fact must be said again.
    [main: a ready verdict at the first HEARTBEAT of the new life]"""
    bench = MavBench(SimConfig(gps_fix_after_s=5.0))
    bench.run(8.0)
    assert bench.core.readiness(bench.now).ready
    before = len(bench.events)
    at = bench.reboot_and_await_first_heartbeat()
    state = bench.core.state
    assert state.gps is None and state.home is None and state.extended is None
    assert not bench.core.readiness(bench.now).ready
    # a StateReset before anything of the new life, after everything of the last
    resets = [t for t, obs in bench.delivered if isinstance(obs, StateReset)]
    assert len(resets) == 1 and resets[0] > at
    assert bench.intake.boot.counts["resets"] == 1
    bench.run(at + 4.5 - bench.now)  # woken at +3 s, no fix before +5 s
    verdicts = [e.verdict for e in bench.events[before:] if isinstance(e, ReadinessChanged)]
    assert verdicts and not any(v.ready for v in verdicts), verdicts
    assert bench.core.state.home is None
    assert bench.core.readiness(bench.now).reason in (Reason.PREARM_FAILED, Reason.NO_3D_FIX)
    bench.run(4.0)  # the new life's fix and home: ready again, on its own facts
    assert bench.core.readiness(bench.now).ready


def test_an_abort_right_after_a_reboot_in_the_air_disarms_or_does_nothing_never_lands() -> None:
    """Flying (IN_AIR), then PX4 reboots and comes back disarmed on the ground. An ABORT
    right after the new life's first HEARTBEAT sent NAV_LAND from the last life's IN_AIR to
    a disarmed vehicle on the ground (the simulator refuses it, as PX4 does). Now the landed
    state is unknown and the HEARTBEAT fresh and disarmed: nothing to do, as over XRCE
    (test_xrce_fresh_state). [main: NAV_LAND sent]"""
    bench = MavBench()
    bench.fly()
    bench.run(0.5)
    assert bench.core.readiness(bench.now).landed_state == "IN_AIR"
    bench.reboot_and_await_first_heartbeat()
    assert bench.core.state.armed is False and bench.core.state.landed_state is None
    abort_at = bench.now
    done = bench.run_task(2, TaskKind.ABORT)
    assert [c.command for t, c in bench.sent_at if t >= abort_at] == []
    assert done.ok and done.reason == ON_GROUND_DISARMED
    assert bench.sim.landed == LandedState.ON_GROUND and not bench.sim.armed


def test_a_takeoff_lifting_when_px4_reboots_waits_then_fails_disarmed() -> None:
    """A reset mid-command, as over XRCE: the take-off (NAV_TAKEOFF confirmed, waiting for
    lift-off) reads the reset as unknown, not as disarmed, and goes on waiting
    (``test_a_state_reset_while_lifting_is_unknown_not_disarmed``); the new life's first
    HEARTBEAT, disarmed, then ends it ``disarmed``. Never a success from the last life's
    armed bit and the new life's landed state. (main ended it the same way; this pins it.)"""
    bench = MavBench()
    bench.run(3.0)
    bench.request(1, TaskKind.TAKEOFF, 10.0)
    seq = bench.core.last_takeoff
    assert seq is not None
    # lifting, and a HEARTBEAT has shown it armed (spooling up: not airborne yet)
    bench.run(10.0, stop=lambda: bench.core.state.armed is True)
    assert seq.phase is TakeoffPhase.LIFTING
    at = bench.now
    bench.sim.reboot(at)
    bench.run(REBOOT_S - 0.5, stop=lambda: bench.finished(1) is not None)
    assert bench.finished(1) is None  # booting: no HEARTBEAT, the take-off's timer runs
    bench.run(2.0, stop=lambda: bench.finished(1) is not None)
    resets = [t for t, obs in bench.delivered if isinstance(obs, StateReset)]
    done = bench.finished(1)
    assert resets and resets[0] > at + REBOOT_S
    assert done is not None and not done.ok and done.reason.startswith("disarmed"), done


def test_a_land_sent_as_px4_reboots_is_never_done_by_the_new_life() -> None:
    """A LAND whose NAV_LAND reaches a PX4 that is rebooting: nothing answers for the 3 s of
    the boot, longer than the LAND's 2 s of retries, so it ends ``no_ack``; the new life's
    state (AUTO.LOITER, on the ground) never confirms it. As over XRCE (``A PX4 that
    reboots``); main ended the same way."""
    bench = MavBench()
    bench.fly()
    bench.request(2, TaskKind.LAND)
    bench.sim.reboot(bench.now)
    bench.run(10.0, stop=lambda: bench.finished(2) is not None)
    done = bench.finished(2)
    assert done is not None and not done.ok and done.reason == "no_ack", done
    bench.run(2.0)
    assert bench.finished(2) == done and bench.intake.boot.counts["resets"] == 1


# ---- only trusted frames reset --------------------------------------------------------------


def _signed_bench() -> tuple[MavBench, bytes]:
    """A signed link heard for 6 s, and a genuine SYSTEM_TIME PX4 signed in its first second."""
    bench = MavBench(key=KEY)
    bench.run(6.0)
    assert bench.core.readiness(bench.now).ready
    early = next(d for m, d in bench.wire_up if isinstance(m, BootClock))
    return bench, early


def _frame(sysid: int, compid: int, key: bytes | None, now: float, boot_ms: int = 5) -> bytes:
    codec = MavlinkCodec(sysid, compid, signing_key=key)
    codec.advance_clock(_clock(now) + 1_000)  # newer than anything PX4 signed so far
    return codec.encode(BootClock("SYSTEM_TIME", boot_ms))


def test_forged_replayed_and_foreign_frames_going_back_in_time_reset_nothing() -> None:
    """Each frame says "PX4 rebooted" (its boot clock back to 5 ms) and none may be believed:
    a forgery without the key, PX4's own first-second frame replayed, the right key from
    another component or system, an unsigned frame. The same frame from PX4 itself does
    reset (the control: this is the message that would). [control fails on main: no reset]"""
    bench, early = _signed_bench()
    wrong_key = bytes(32 - i for i in range(32))
    for data in (
        _frame(1, COMP_ID_AUTOPILOT1, wrong_key, bench.now),  # forged: bad signature
        early,  # replayed: PX4's genuine frame of its first second
        _frame(1, 2, KEY, bench.now),  # another component of the vehicle, with the key
        _frame(2, COMP_ID_AUTOPILOT1, KEY, bench.now),  # another vehicle, with the key
        _frame(1, COMP_ID_AUTOPILOT1, None, bench.now),  # unsigned
    ):
        bench.receive(data, PX4)
        assert bench.intake.boot.counts["resets"] == 0
        assert bench.core.state.home is not None and bench.core.readiness(bench.now).ready
    signing = bench.companion_codec.signing_counts
    assert signing is not None
    assert signing["bad_signature"] == 1 and signing["replayed"] == 1
    assert signing["unsigned"] == 1 and bench.intake.foreign == 2
    bench.receive(_frame(1, COMP_ID_AUTOPILOT1, KEY, bench.now), PX4)  # PX4 itself
    assert bench.intake.boot.counts["resets"] == 1 and bench.core.state.home is None


def test_without_signing_a_frame_from_another_address_resets_nothing() -> None:
    """Unsigned, the pin is the check: a frame from another address is dropped before it is
    decoded; from the pinned address the same frame resets. [control fails on main]"""
    bench = MavBench()
    bench.run(3.0)
    bench.receive(_frame(1, COMP_ID_AUTOPILOT1, None, bench.now), ELSEWHERE)
    assert bench.intake.boot.counts["resets"] == 0 and bench.core.state.home is not None
    bench.receive(_frame(1, COMP_ID_AUTOPILOT1, None, bench.now), PX4)
    assert bench.intake.boot.counts["resets"] == 1 and bench.core.state.home is None


def test_swarmctl_status_counts_the_reboots() -> None:
    bench = MavBench()
    bench.run(6.0)
    bench.reboot_and_await_first_heartbeat()
    stats = {"backend": "mavlink", "connection": "serial:/dev/ttyTHS1:921600",
             "autopilot": None, "signing": {"enabled": False, "ok": 0},
             "boot_clock": bench.intake.boot.stats()}  # fmt: skip
    assert render_px4_backend(stats) == (
        "px4 link: mavlink serial:/dev/ttyTHS1:921600, unsigned, PX4 rebooted 1 times (boot clock)"
    )


# ---- the boot clock rule --------------------------------------------------------------------


def test_the_boot_clock_rule_step_by_step() -> None:
    watch = BootWatch()
    assert watch.batch([("ATTITUDE", 600_000)], 1, 0.0).reset is None
    assert watch.batch([("ATTITUDE", 599_500)], 1, 0.01).reset is None  # late: 0.5 s back
    assert watch.counts["late"] == 1
    assert watch.batch([("GLOBAL_POSITION_INT", 599_900)], 1, 0.02).reset is None
    # each message keeps its own clock: a GLOBAL_POSITION_INT that stopped (fix lost) and
    # comes back 10 s behind the ATTITUDE's is judged against its own last value
    assert watch.batch([("ATTITUDE", 610_000)], 1, 1.0).reset is None
    assert watch.batch([("GLOBAL_POSITION_INT", 600_100)], 1, 1.01).reset is None
    reset = watch.batch([("ATTITUDE", 4_000)], 1, 2.0).reset
    assert reset is not None and "ATTITUDE" in reset  # back by 606 s: a new life
    # the new life's first GLOBAL_POSITION_INT is its own first value, not a second reboot
    assert watch.batch([("GLOBAL_POSITION_INT", 4_010)], 1, 2.01).reset is None
    assert watch.counts["resets"] == 1


def test_the_uint32_wrap_is_not_a_reboot_but_a_reboot_after_25_days_is() -> None:
    watch = BootWatch()
    watch.batch([("ATTITUDE", BOOT_CLOCK_WRAP - 5)], 1, 0.0)
    assert watch.batch([("ATTITUDE", 5)], 1, 0.01).reset is None  # 10 ms later: wrapped
    assert watch.counts["wraps"] == 1
    # 30 days of uptime (more than 2^31 ms: a signed modular difference calls this "forward")
    old = 30 * 86_400_000
    watch = BootWatch()
    watch.batch([("ATTITUDE", old)], 1, 0.0)
    assert watch.batch([("ATTITUDE", 4_000)], 1, 6.0).reset is not None


def test_after_a_silence_frames_wait_for_the_boot_clock() -> None:
    """After a silence of the heartbeat timeout the next life is unknown: a batch without the
    boot clock is dropped until one with it says which life it is; with none for 2 s (a
    firmware that streams no boot clock), the life is unknown and the state is reset."""
    watch = BootWatch()
    assert watch.batch([("SYSTEM_TIME", 60_000)], 1, 0.0).deliver
    assert watch.batch([], 1, 0.5).deliver  # no silence: a HEARTBEAT alone is delivered
    assert not watch.batch([], 1, 3.5).deliver  # after 3 s of silence: whose?
    same = watch.batch([("SYSTEM_TIME", 63_500)], 1, 3.6)
    assert same.deliver and same.reset is None  # the same life: the link was quiet
    assert not watch.batch([], 1, 7.0).deliver
    assert not watch.batch([], 1, 8.0).deliver
    unknown = watch.batch([], 1, 9.0)
    assert unknown.deliver and unknown.reset is not None and "unknown" in unknown.reset
    assert watch.counts["dropped_after_silence"] == 3
    # a life of 2 s, then 3 s of silence and a boot clock at 2.5 s: forward of the last
    # value, so no jump back, but 2.5 s behind where the same life would be: a new life
    watch = BootWatch()
    watch.batch([("SYSTEM_TIME", 2_000)], 1, 0.0)
    short = watch.batch([("SYSTEM_TIME", 2_500)], 1, 3.0).reset
    assert short is not None and "after a silence" in short


def test_after_a_silence_a_message_the_last_life_never_sent_is_judged_by_another() -> None:
    """The last life had no GPS fix, so no GLOBAL_POSITION_INT; the new life's first boot
    clock after the silence is one. Judged against SYSTEM_TIME's clock it is a new life.
    [without the cross-check: taken as the same life, no reset]"""
    watch = BootWatch()
    watch.batch([("SYSTEM_TIME", 600_000)], 1, 0.0)
    reset = watch.batch([("GLOBAL_POSITION_INT", 3_500)], 1, 4.0).reset
    assert reset is not None and "GLOBAL_POSITION_INT" in reset
    # and without a silence a first GLOBAL_POSITION_INT of the same life is no reboot
    watch = BootWatch()
    watch.batch([("SYSTEM_TIME", 600_000)], 1, 0.0)
    assert watch.batch([("GLOBAL_POSITION_INT", 599_990)], 1, 0.5).reset is None
    assert watch.counts["resets"] == 0


def test_frames_that_waited_out_a_stall_of_the_daemon_are_the_same_life() -> None:
    """The link is honest and PX4 never stops; the daemon's loop does (a loaded companion,
    a long callback, a host suspend), for longer than the heartbeat timeout. The frames PX4
    sent meanwhile wait in the socket or UART buffer and are read at once when the loop
    runs again: their boot clock is where it was when they were sent, just past the last
    value, but the silence counted on our clock says it should be 2.7 s on. A new life
    cannot show a boot clock past the silence (it booted within it) and past the last
    life's last value: these are the same life. [on main: a StateReset, which ends a
    take-off still arming (mode_changed) and forgets the vehicle's state]"""
    watch = BootWatch()
    for n in range(51):  # 0.5 s of ATTITUDE at 100 Hz
        assert watch.batch([("ATTITUDE", 600_000 + 10 * n)], 1, n / 100).reset is None
    # the loop stalls from 0.5 s to 3.2 s; the buffered frames are read in a burst
    for n in range(1, 6):
        verdict = watch.batch([("ATTITUDE", 600_500 + 10 * n)], 1, 3.2 + n * 1e-4)
        assert verdict.deliver and verdict.reset is None
    assert watch.counts["resets"] == 0
    # the short life of the rule above is still told apart: its clock is within the silence
    watch = BootWatch()
    watch.batch([("SYSTEM_TIME", 2_000)], 1, 0.0)
    assert watch.batch([("SYSTEM_TIME", 2_500)], 1, 3.0).reset is not None


# One life: a first boot-clock value, then frames every step_ms of PX4's clock, some pairs
# arriving swapped (UDP reordering), several messages each lagging the clock by its own age.
# Every life outlives its successor's boot time by more than the jump (REBOOT_JUMP_MS plus
# the lags and steps here): a shorter one is the limit docs/px4.md names.
_life = st.tuples(
    st.integers(min_value=500, max_value=5_000),  # the first value PX4 sends after boot
    st.integers(min_value=10_000, max_value=60_000),  # how long the life is heard (ms)
    st.integers(min_value=20, max_value=200),  # ms between frames
    st.floats(min_value=0.0, max_value=4.0),  # silent seconds after it, besides the boot
)


@settings(max_examples=150, deadline=None)
@given(
    lives=st.lists(_life, min_size=1, max_size=4),
    first_wraps=st.booleans(),
    lags=st.lists(st.integers(min_value=0, max_value=900), min_size=1, max_size=3),
    swaps=st.sets(st.integers(min_value=0, max_value=2_000), max_size=60),
)
def test_a_reset_exactly_at_each_new_life_whatever_the_jitter_wrap_and_reorder(
    lives: list[tuple[int, int, int, float]],
    first_wraps: bool,
    lags: list[int],
    swaps: set[int],
) -> None:
    """Per message the clock only grows, but frames may arrive one step late (swapped with
    the next), messages lag the clock by up to 0.9 s, and the first life heard may pass the
    uint32 wrap. Each new life is reset exactly once, at its first frame; nothing else is."""
    watch = BootWatch()
    now = 0.0
    frames: list[tuple[float, str, int]] = []
    firsts: list[int] = []
    for index, (first, length, step, quiet) in enumerate(lives):
        if index == 0 and first_wraps:
            # heard from mid-life, across the wrap, with 5 s and more of it after the wrap
            first = BOOT_CLOCK_WRAP - max(1, (length - 10_000) // 2)
        elif index:
            now += first / 1000  # PX4 boots, silent, until its first frame
        firsts.append(len(frames))
        for n, t in enumerate(range(0, length, step)):
            message = n % len(lags)
            value = (first + t - lags[message]) % BOOT_CLOCK_WRAP
            if index and t < lags[message]:
                continue  # that message had no sample yet in the new life
            frames.append((now + t / 1000, f"M{message}", value))
        now += length / 1000 + quiet
    for i in sorted(swaps):  # a frame that arrives after the next one (same arrival times)
        if i + 1 < len(frames) and i + 1 not in firsts and i not in firsts:
            (ta, ma, va), (tb, mb, vb) = frames[i], frames[i + 1]
            frames[i], frames[i + 1] = (ta, mb, vb), (tb, ma, va)
    resets = [
        i for i, (t, m, v) in enumerate(frames) if watch.batch([(m, v)], 1, t).reset is not None
    ]
    assert resets == firsts[1:]
    assert REBOOT_JUMP_MS == 1000


# ---- the asyncio backend and bridge, real UDP on loopback ----------------------------------


class _Log:
    """The bridge's logger, kept: (event, fields) per line."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, dict[str, object]]] = []

    def info(self, event: str, **fields: object) -> None:
        self.lines.append((event, fields))


def test_the_bridge_forgets_a_rebooted_simulator_logs_one_line_and_counts_it() -> None:
    """The MAVLink backend over loopback UDP against ``swarmd-vehicle-sim``'s protocol: the
    simulator reboots (1 s of silence: shorter than the heartbeat timeout, so the boot
    clock going back alone tells it); the bridge logs one ``px4_state_reset`` line, counts
    it in the status, and is ready again on the new life's own facts."""
    bound_s = 20.0

    async def scenario() -> None:
        log = _Log()
        config = Px4Config(connection="udpin:127.0.0.1:0", sysid=1)
        bridge = Px4Bridge.from_config(config, log=log)
        await bridge.start()
        assert isinstance(bridge.backend, MavlinkBackend)
        link = bridge.backend.link
        assert isinstance(link, UdpLink) and link.local_port is not None
        sim = await start_sim(
            SimConfig(gps_fix_after_s=0.3),
            parse_connection(f"udpout:127.0.0.1:{link.local_port}"),
            seed=1,
        )

        async def until(check: Callable[[], bool]) -> None:
            async def poll() -> None:
                while not check():  # noqa: ASYNC110 - a test probe, not protocol logic
                    await asyncio.sleep(0.05)

            await asyncio.wait_for(poll(), bound_s)

        def resets() -> int:
            boot = bridge.status()["backend"]["boot_clock"]
            assert isinstance(boot, dict)
            count = boot["resets"]
            assert isinstance(count, int)
            return count

        try:
            loop = asyncio.get_running_loop()
            # a life of 3 s at least: longer than the next one's boot plus the 1 s jump
            await until(lambda: bridge.readiness().ready and loop.time() > sim.model.boot + 3.0)
            sim.reboot(boot_s=1.0)
            await until(lambda: resets() == 1)
            await until(lambda: bridge.readiness().ready)
            events = [fields for event, fields in log.lines if event == "px4_state_reset"]
            assert len(events) == 1 and events[0]["backend"] == "mavlink"
            assert "SYSTEM_TIME" in str(events[0]["why"])
            line = render_px4_backend(bridge.status()["backend"])
            assert line.endswith("PX4 rebooted 1 times (boot clock)"), line
        finally:
            sim.close()
            await bridge.close()

    asyncio.run(scenario())


def test_docs_state_the_boot_watchs_numbers() -> None:
    """docs/px4.md's rule, read against the constants that set it."""
    root = Path(__file__).resolve().parent.parent
    text = " ".join((root / "docs/px4.md").read_text(encoding="utf-8").split())
    assert f"back by more than {REBOOT_JUMP_MS / 1000:g} s (`REBOOT_JUMP_MS`)" in text
    assert f"After {SILENCE_S:g} s with no trusted frame" in text
    assert f"With no boot clock {UNDECIDED_MAX_S:g} s after the silence" in text
    assert f"power-cycle once after S s: silent {REBOOT_S:g} s" in text
    assert f"a reboot (`SimVehicle.reboot`, `--reboot-after`): silent for {REBOOT_S:g} s" in text
