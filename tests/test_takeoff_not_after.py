"""No ARM or NAV_TAKEOFF frame leaves after the command's validity end (docs/dataplane.md,
"Validity at the vehicle"; session 18).

Session 17 checked ``VehicleRequest.not_after`` only when the request started. The sequence
then retransmits ARM and NAV_TAKEOFF (1 + 3 sends each, 0.5 s apart), so a take-off started
just before its validity end put a NAV_TAKEOFF on the wire up to ~4 s after it, and the
vehicle left the ground after the operator was told the command could no longer start. Now
every ARM and NAV_TAKEOFF copy leaves before ``not_after``, or the take-off fails
``expired_mid_start`` with its DISARM (after NAV_TAKEOFF: once the state had an ack timeout
to show the first copy taken, as ``held_up``). The XRCE reliable stream repairs no such
frame past it either.

Here: the vehicle core on the MAVLink bridge's codec (``VirtualLink``, real MAVLink 2 bytes)
against the simulated PX4, and on the XRCE agent backend against the PX4 stand-in, all on
virtual time; the hold after NAV_TAKEOFF on a scripted PX4. Every test but the controls
fails on main (a frame leaves after ``not_after``, the vehicle flies). No timing asserted
beyond the virtual clock's order.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import cast

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import VirtualLink

from swarmd.px4.constants import LandedState, MavCmd, MavResult
from swarmd.px4.mavlink_codec import Message
from swarmd.px4.messages import (
    CommandAck,
    ExtendedSysState,
    Heartbeat,
    Observation,
    VehicleCommand,
)
from swarmd.px4.readiness import VehicleState
from swarmd.px4.takeoff import TakeoffPhase, TakeoffSequence
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleEvent, VehicleRequest
from tests.test_px4_takeoff import Scripted
from tests.test_px4_vehicle import Bench
from tests.test_xrce_late_command import Edge

EXPIRED_MID_START = "expired_mid_start"  # FailReason.EXPIRED_MID_START (a literal: main lacks it)


def _motion(cmd: VehicleCommand) -> bool:
    """A frame that may start the flight: ARM (param1 1) or NAV_TAKEOFF."""
    arm = cmd.command == MavCmd.COMPONENT_ARM_DISARM and cmd.params[0] == 1.0
    return arm or cmd.command == MavCmd.NAV_TAKEOFF


def _is_disarm(cmd: VehicleCommand) -> bool:
    return cmd.command == MavCmd.COMPONENT_ARM_DISARM and cmd.params[0] == 0.0


# ---- the MAVLink bridge: the vehicle core over the MAVLink codec, virtual time --------------


class _CoreOnLink:
    """A ``VehicleCore`` in the place ``VirtualLink`` drives a take-off sequence from: the
    link's MAVLink codec and simulated PX4, the core's request path (``not_after``)."""

    def __init__(self, core: VehicleCore) -> None:
        self.core = core
        self.request: VehicleRequest | None = None

    def start(self, now: float) -> None:
        if self.request is not None:
            self.core.request(self.request, now)

    def observe(self, obs: Observation, now: float) -> None:
        self.core.receive_datagram(obs, None, now)

    def handle_timer(self, now: float) -> None:
        self.core.handle_timer(now)

    def get_timer(self) -> float | None:
        return self.core.get_timer()

    def commands_to_send(self) -> list[VehicleCommand]:
        return self.core.datagrams_to_send()

    def next_event(self) -> VehicleEvent | None:
        return self.core.next_event()


class MavlinkEdge:
    """The simulated PX4 and a vehicle core joined by ``VirtualLink``; ``lose`` decides
    which of our commands the link loses (the n-th of a kind, counted from 1). Every
    command's send time is kept (``sent``)."""

    def __init__(self, lose: Callable[[VehicleCommand, int], bool]) -> None:
        self.sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(5), 0.0)
        self.lose = lose
        self.sent: list[tuple[float, VehicleCommand]] = []
        self._counts: dict[tuple[int, float], int] = {}
        # the link's own state is unused: the core keeps its own
        self.link = VirtualLink(self.sim, VehicleState(), 0.0, drop=self._drop)
        self.core = VehicleCore()
        self.driven = _CoreOnLink(self.core)
        self.link.attach(cast(TakeoffSequence, self.driven))
        self.link.run_until(5.0)  # GPS fix, home: ready
        assert self.core.readiness(self.link.now).ready

    def _drop(self, msg: Message, direction: str, now: float) -> bool:
        if direction != "down" or not isinstance(msg, VehicleCommand):
            return False
        self.sent.append((now, msg))
        key = (msg.command, msg.params[0])
        self._counts[key] = n = self._counts.get(key, 0) + 1
        return self.lose(msg, n)

    def takeoff(self, valid_s: float) -> float:
        """Request a take-off valid for ``valid_s`` from now; its ``not_after``."""
        not_after = self.link.now + valid_s
        request = VehicleRequest(1, TaskKind.TAKEOFF, 5.0, ("lead", 1), not_after)
        self.driven.request = request
        self.link.start(cast(TakeoffSequence, self.driven))
        self.link.run_until(self.link.now + 15.0)
        return not_after

    def finished(self) -> TaskFinished:
        events: list[object] = list(self.link.events)  # the core's events, not a sequence's
        (done,) = [e for e in events if isinstance(e, TaskFinished)]
        return done

    def late_motion(self, not_after: float) -> list[tuple[float, str, int]]:
        return [(t, c.label, c.confirmation) for t, c in self.sent if _motion(c) and t >= not_after]


def _nth(command: int, param1: float, *which: int) -> Callable[[VehicleCommand, int], bool]:
    def lose(cmd: VehicleCommand, n: int) -> bool:
        return cmd.command == command and cmd.params[0] == param1 and n in which

    return lose


NAV = float("nan")  # NAV_TAKEOFF's param1


def _lose_nav(*which: int) -> Callable[[VehicleCommand, int], bool]:
    def lose(cmd: VehicleCommand, n: int) -> bool:
        return cmd.command == MavCmd.NAV_TAKEOFF and n in which

    return lose


def test_a_lost_nav_takeoff_is_never_retransmitted_after_the_validity_end() -> None:
    """The first NAV_TAKEOFF is lost 10 ms after the start; its retransmission falls due
    0.5 s later, past a 0.3 s validity. [main: sent at 0.51 s, PX4 climbed after the
    command expired] Now it is not sent; after an ack timeout with nothing showing the
    first copy taken, the take-off fails ``expired_mid_start`` and its DISARM leaves the
    vehicle disarmed on the ground."""
    edge = MavlinkEdge(_lose_nav(1))
    not_after = edge.takeoff(0.3)
    assert edge.late_motion(not_after) == []
    done = edge.finished()
    assert (done.ok, done.reason) == (False, EXPIRED_MID_START)
    assert not edge.sim.armed and edge.sim.landed == LandedState.ON_GROUND
    assert any(_is_disarm(c) for _, c in edge.sent)


def test_arm_retransmissions_stop_at_the_validity_end() -> None:
    """Every ARM lost: the copies at 0 and 0.5 s leave (valid to 0.7 s), the one due at
    1.0 s does not. [main: ARMs at 1.0 and 1.5 s too, then ``arm_no_ack``] The DISARM
    covers the ARMs sent (repeated on the ground)."""
    edge = MavlinkEdge(_nth(MavCmd.COMPONENT_ARM_DISARM, 1.0, 1, 2, 3, 4))
    not_after = edge.takeoff(0.7)
    assert edge.late_motion(not_after) == []
    assert [c.confirmation for _, c in edge.sent if _motion(c)] == [0, 1]
    assert edge.finished().reason == EXPIRED_MID_START
    assert not edge.sim.armed


def test_an_arm_confirmed_after_the_validity_end_sends_no_nav_takeoff() -> None:
    """The first ARM is lost, the second (0.5 s, in time) is accepted 10 ms later, past a
    0.505 s validity: NAV_TAKEOFF would be the flight's first frame after the end. [main:
    sent, the vehicle flew] Not sent; the DISARM at once, nothing climbs."""
    edge = MavlinkEdge(_nth(MavCmd.COMPONENT_ARM_DISARM, 1.0, 1))
    not_after = edge.takeoff(0.505)
    assert edge.late_motion(not_after) == []
    assert not any(c.command == MavCmd.NAV_TAKEOFF for _, c in edge.sent)
    assert edge.finished().reason == EXPIRED_MID_START
    assert not edge.sim.armed and edge.sim.landed == LandedState.ON_GROUND


def test_an_honest_takeoff_on_a_good_link_completes_within_the_default_validity() -> None:
    """The control: nothing lost, the default 3 s: one ARM, one NAV_TAKEOFF, airborne."""
    edge = MavlinkEdge(lambda _c, _n: False)
    edge.takeoff(3.0)
    done = edge.finished()
    assert done.ok, done.reason
    assert [c.label for _, c in edge.sent if _motion(c)] == ["COMPONENT_ARM_DISARM", "NAV_TAKEOFF"]


# ---- the hold after NAV_TAKEOFF: read the state first (as held_up) ---------------------------


def test_a_nav_takeoff_px4_took_is_confirmed_in_the_hold_not_disarmed() -> None:
    """NAV_TAKEOFF left in time; its retransmission falls due past the validity end, so it
    is not sent [main: sent at 0.5 s]. PX4's answer to the first copy comes during the one
    ack timeout the take-off reads before it judges: the take-off goes on and succeeds,
    no DISARM meets the climbing vehicle."""
    v = Scripted()
    v.seq.not_after = 0.3
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)  # NAV_TAKEOFF leaves at 0
    v.advance_to_timer()  # 0.5 s: its retransmission is due, past 0.3 s: held
    assert v.phase() is TakeoffPhase.TAKING_OFF
    v.now += 0.2
    v.ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED)
    assert v.phase() is TakeoffPhase.LIFTING
    v.armed, v.landed = True, LandedState.TAKEOFF
    v.telemetry()
    assert v.phase() is TakeoffPhase.SUCCEEDED
    assert [c.command for c in v.sent] == [MavCmd.COMPONENT_ARM_DISARM, MavCmd.NAV_TAKEOFF]


def test_a_nav_takeoff_unanswered_past_the_validity_fails_after_the_hold() -> None:
    """The same without an answer: after the hold, ``expired_mid_start`` and the DISARM
    (never a NAV_TAKEOFF after 0.3 s)."""
    v = Scripted()
    v.seq.not_after = 0.3
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)
    v.armed = True
    v.feed(ExtendedSysState(LandedState.ON_GROUND))
    while v.phase() is not TakeoffPhase.FAILED:
        v.advance_to_timer()
    assert v.failure().reason == EXPIRED_MID_START
    assert v.now == pytest.approx(1.0)  # due at 0.5 s, read for one ack timeout
    assert [c.params[0] for c in v.sent if c.command == MavCmd.COMPONENT_ARM_DISARM] == [1.0, 0.0]
    assert sum(c.command == MavCmd.NAV_TAKEOFF for c in v.sent) == 1


# ---- the XRCE path: the agent backend and the PX4 stand-in, virtual time ---------------------


class _XrceEdge(Edge):
    """The XRCE edge (``test_xrce_late_command.Edge``) whose first NAV_TAKEOFF is lost:
    dropped as the backend would write it (``cut``: the link goes down as it is written
    instead, so the agent's reliable stream holds it for repair)."""

    def __init__(self, release: str, *, cut: bool) -> None:
        super().__init__(release)
        write = self.core_driver.transmit
        self.navs = 0

        def transmit(cmd: VehicleCommand) -> None:
            if cmd.command == MavCmd.NAV_TAKEOFF:
                self.navs += 1
                if self.navs == 1 and not cut:
                    return
                if self.navs == 1:
                    self.link_up = False
            write(cmd)

        self.core_driver.transmit = transmit

    def takeoff_valid_for(self, valid_s: float) -> float:
        not_after = self.clock.now + valid_s
        request = VehicleRequest(1, TaskKind.TAKEOFF, 5.0, ("lead", 1), not_after)
        self.core_driver.call(lambda now: self.core.request(request, now))
        return not_after

    def late_at_px4(self, not_after: float) -> list[tuple[float, int]]:
        """ARM and NAV_TAKEOFF that reached PX4 at or after ``not_after``."""
        return [
            (t, c)
            for t, c, p1 in self.px4_commands
            if t >= not_after
            and (c == MavCmd.NAV_TAKEOFF or (c == MavCmd.COMPONENT_ARM_DISARM and p1 == 1))
        ]


@pytest.mark.parametrize("release", ["1.14", "1.16"])
def test_xrce_a_lost_nav_takeoff_never_reaches_px4_after_the_validity_end(release: str) -> None:
    """1.14 (best-effort topic) and 1.16 (service on the reliable stream): the first
    NAV_TAKEOFF is lost, its retransmission would leave past a 0.3 s validity. [main: it
    reached PX4 at 0.5 s and the vehicle flew]"""
    edge = _XrceEdge(release, cut=False)
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    not_after = edge.takeoff_valid_for(0.3)
    edge.run(edge.clock.now + 6.0)
    assert edge.late_at_px4(not_after) == []
    done = edge.finished()
    assert done is not None and done.reason == EXPIRED_MID_START
    assert not edge.px4.vehicle.armed and edge.px4.vehicle.landed == LandedState.ON_GROUND


def test_xrce_the_reliable_stream_repairs_no_nav_takeoff_past_the_validity_end() -> None:
    """1.16: the link goes down as the first NAV_TAKEOFF is written, and comes back past the
    validity end but inside the frame's own life (``COMMAND_LIFE_S``, 0.5 s). [main: the
    agent repaired the NAV_TAKEOFF on the link's return, after the end, and PX4 climbed]
    Now its life ends at ``not_after``: a stand-in goes, the take-off sends no copy of its
    own, fails ``expired_mid_start``, and its DISARM (no life: repaired as itself) leaves
    the vehicle disarmed."""
    edge = _XrceEdge("1.16", cut=True)
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    not_after = edge.takeoff_valid_for(0.1)
    edge.run(not_after + 0.15)
    edge.link_up = True
    edge.run(edge.clock.now + 6.0)
    assert edge.navs == 1
    assert edge.late_at_px4(not_after) == []
    assert edge.backend.stats()["commands_expired"] >= 1
    done = edge.finished()
    assert done is not None and done.reason == EXPIRED_MID_START
    assert not edge.px4.vehicle.armed and edge.px4.vehicle.landed == LandedState.ON_GROUND


# ---- a NAV_TAKEOFF the state confirmed the ARM for leaves then, not at the next input --------


class _SilentAfterArmed:
    """The link up from PX4: every COMMAND_ACK lost (the ARM is confirmed by state), and
    nothing at all once the first armed HEARTBEAT is through (an outage, or a quiet link)."""

    def __init__(self) -> None:
        self.armed_at: float | None = None

    def __call__(self, msg: object, direction: str) -> bool:
        if direction != "up" or self.armed_at is not None:
            return direction == "up"
        if isinstance(msg, Heartbeat) and msg.armed:
            self.armed_at = -1.0  # the last message through; delivered at once (1 ms)
            return False
        return isinstance(msg, CommandAck)


def _state_confirmed(valid_s: float | None) -> tuple[Bench, list[tuple[float, VehicleCommand]]]:
    """A take-off whose ARM only the state confirms, the link up silent right after; every
    command with the time it left the vehicle core (``datagrams_to_send``)."""
    b = Bench(latency_s=0.001)
    b.run(3.0)
    b.drop = _SilentAfterArmed()
    sent: list[tuple[float, VehicleCommand]] = []
    pump = b._pump_core  # noqa: SLF001 - the bench's one exit for the core's frames

    def timed() -> None:
        before = len(b.sent)
        pump()
        sent.extend((b.now, c) for c in b.sent[before:])

    b._pump_core = timed  # type: ignore[method-assign]  # noqa: SLF001
    not_after = None if valid_s is None else b.now + valid_s
    b.core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0, ("lead", 1), not_after), b.now)
    timed()
    b.run(10.0)
    return b, sent


def _armed_confirmed_at(b: Bench) -> float:
    """When the sequence took the armed HEARTBEAT as the ARM's confirmation."""
    seq = b.core.last_takeoff
    assert seq is not None and seq.phase is not TakeoffPhase.ARMING
    heard = b.core.state.heartbeat_at
    assert heard is not None
    return heard


def test_a_nav_takeoff_after_an_arm_confirmed_by_state_leaves_at_once() -> None:
    """Review 18: the armed HEARTBEAT confirms ARM (its ACK lost) in time, and the link goes
    quiet. The sequence decided NAV_TAKEOFF then, but left it in its command sender until
    the next input that drained it, so it first went out with the next timer, after the
    validity end, just before the DISARM of the ``expired_mid_start`` it caused. [main:
    NAV_TAKEOFF left 1 s after the ARM was confirmed and 0.95 s after ``not_after``]"""
    probe, _ = _state_confirmed(None)  # when does the armed HEARTBEAT arrive? (seeded sim)
    confirmed = _armed_confirmed_at(probe)
    b, sent = _state_confirmed(confirmed + 0.05 - 3.0)  # valid until 50 ms after it
    assert _armed_confirmed_at(b) == confirmed
    not_after = confirmed + 0.05
    navs = [t for t, c in sent if c.command == MavCmd.NAV_TAKEOFF]
    assert navs and navs[0] == confirmed  # decided and sent in the same step
    assert [t for t, c in sent if _motion(c) and t >= not_after] == []


def test_without_a_validity_the_first_nav_takeoff_is_not_held_back_either() -> None:
    """The same take-off with no validity (a direct take-off): its first NAV_TAKEOFF leaves
    when the state confirms the ARM. [main: it left an ack timeout later, with its own
    first retransmission]"""
    b, sent = _state_confirmed(None)
    confirmed = _armed_confirmed_at(b)
    navs = [(t, c.confirmation) for t, c in sent if c.command == MavCmd.NAV_TAKEOFF]
    assert navs[0] == (confirmed, 0)
