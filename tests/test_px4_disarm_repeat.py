"""A failed take-off's DISARM must arrive (docs/px4.md, "A failed take-off's DISARM").

The attack is the link itself: a take-off fails because the link loses frames, and the one
DISARM it then sent was lost the same way; PX4 stayed armed on the ground until its own
pre-flight auto-disarm (COM_DISARM_PRFLT, 10 s), props maybe spinning. Now the DISARM is
repeated (confirmation 1, 2, 3) until PX4 accepts it or a fresh HEARTBEAT reads disarmed,
only while the vehicle reads ON_GROUND, bounded by the sender's budget, and any newer
request stops the repeats. The first tests run the MAVLink codec (``VirtualLink``) against
the vehicle simulator on virtual time.
"""

from __future__ import annotations

import random

from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.virtual import VirtualLink

from swarmd.px4.constants import LandedState, MavCmd, MavResult
from swarmd.px4.mavlink_codec import Message
from swarmd.px4.messages import ExtendedSysState, VehicleCommand
from swarmd.px4.readiness import VehicleState
from swarmd.px4.takeoff import (
    DisarmRepeatsEnded,
    FailReason,
    TakeoffFailed,
    TakeoffPhase,
    TakeoffSequence,
)
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished, TaskKind
from tests.test_px4_takeoff import Scripted
from tests.test_px4_vehicle import Bench
from tests.test_xrce_late_command import Edge


def _is_disarm(msg: object) -> bool:
    return (
        isinstance(msg, VehicleCommand)
        and msg.command == MavCmd.COMPONENT_ARM_DISARM
        and msg.params[0] == 0.0
    )


class LoseDisarms:
    """Every NAV_TAKEOFF lost (the take-off fails ``takeoff_no_ack`` with the vehicle armed
    on the ground), and the first ``disarms`` DISARMs lost too."""

    def __init__(self, disarms: int) -> None:
        self.disarms = disarms

    def __call__(self, msg: Message, direction: str, now: float) -> bool:
        if direction != "down" or not isinstance(msg, VehicleCommand):
            return False
        if msg.command == MavCmd.NAV_TAKEOFF:
            return True
        if _is_disarm(msg) and self.disarms > 0:
            self.disarms -= 1
            return True
        return False


def _failed_takeoff(lose: LoseDisarms) -> tuple[VirtualLink, TakeoffSequence, float]:
    """A MAVLink take-off that fails armed on the ground; also when it failed."""
    sim = SimVehicle(SimConfig(gps_fix_after_s=1.0), random.Random(3), 0.0)
    link = VirtualLink(sim, VehicleState(), 0.0, drop=lose)
    link.run_until(5.0)
    seq = TakeoffSequence(link.state, 5.0)
    link.start(seq)
    link.run_until(link.now + 30.0, stop=lambda: seq.phase is TakeoffPhase.FAILED)
    assert seq.phase is TakeoffPhase.FAILED
    assert sim.armed and sim.landed == LandedState.ON_GROUND  # the DISARM's job
    return link, seq, link.now


def _disarms(link: VirtualLink) -> list[int]:
    return [c.confirmation for c in link.sent_down if _is_disarm(c)]


def test_a_lost_disarm_is_repeated_until_the_vehicle_disarms() -> None:
    link, seq, failed_at = _failed_takeoff(LoseDisarms(1))
    # 3 s after the failure, well before PX4's own auto-disarm (10 s after arming)
    link.run_until(failed_at + 3.0)
    assert seq.done
    assert not link.sim.armed  # before: armed on the ground until COM_DISARM_PRFLT
    assert _disarms(link) == [0, 1]  # the retransmission counts its confirmation
    out = seq.outcome
    assert isinstance(out, TakeoffFailed) and out.reason is FailReason.TAKEOFF_NO_ACK
    assert not seq.disarm_unconfirmed
    (ended,) = [e for e in link.events if isinstance(e, DisarmRepeatsEnded)]
    assert ended.confirmed


def test_every_disarm_lost_is_bounded_and_reported_unconfirmed() -> None:
    link, seq, failed_at = _failed_takeoff(LoseDisarms(1000))
    link.run_until(failed_at + 5.0)
    assert seq.done
    assert _disarms(link) == [0, 1, 2, 3]  # 1 + the sender's 3 retries, then no more
    out = seq.outcome
    assert isinstance(out, TakeoffFailed) and out.reason is FailReason.TAKEOFF_NO_ACK
    assert seq.disarm_unconfirmed  # the log's disarm_unconfirmed, the core's counter
    (ended,) = [e for e in link.events if isinstance(e, DisarmRepeatsEnded)]
    assert not ended.confirmed and not ended.stopped
    assert link.sim.armed  # honest: still armed, and said so


def test_no_disarm_is_repeated_to_a_vehicle_in_the_air() -> None:
    v = Scripted()
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)
    for _ in range(4):  # NAV_TAKEOFF never answered: 1 + 3 retries
        v.advance_to_timer()
    assert v.phase() is TakeoffPhase.FAILED and v.seq.disarming
    assert [c.params[0] for c in v.sent if c.command == MavCmd.COMPONENT_ARM_DISARM] == [1.0, 0.0]
    # the vehicle reads in the air (our state older than its lift-off): no further DISARM
    v.feed(ExtendedSysState(LandedState.IN_AIR))
    while (timer := v.seq.get_timer()) is not None:
        v.now = timer
        v.seq.handle_timer(v.now)
        v.sent += v.seq.commands_to_send()
    assert v.seq.done
    assert sum(_is_disarm(c) for c in v.sent) == 1
    assert v.seq.disarm_unconfirmed
    assert v.failure().reason is FailReason.TAKEOFF_NO_ACK


def _bench_in_repeats() -> Bench:
    """A vehicle core whose take-off failed armed on the ground, its DISARMs lost."""

    def drop(msg: object, direction: str) -> bool:
        nav = isinstance(msg, VehicleCommand) and msg.command == MavCmd.NAV_TAKEOFF
        return direction == "down" and (nav or _is_disarm(msg))

    b = Bench(drop=drop)
    b.run(3.0)
    b.request(1, TaskKind.TAKEOFF, 4.0)
    b.run(10.0, stop=lambda: any(_is_disarm(c) for c in b.sent))
    # the failure is reported at once; its DISARM repeats run on behind it
    first = b.finished(1)
    assert first is not None and first.reason == FailReason.TAKEOFF_NO_ACK
    assert b.core.busy()
    return b


def test_a_land_stops_the_repeats_and_the_failure_stands() -> None:
    b = _bench_in_repeats()
    n = len(b.sent)
    b.request(2, TaskKind.LAND)
    b.run(5.0)
    assert [e.token for e in b.events if isinstance(e, TaskFinished)] == [1, 2]  # one each
    assert not any(_is_disarm(c) for c in b.sent[n:])  # never fights the LAND
    assert b.sent[n].command == MavCmd.NAV_LAND
    # the LAND does not disarm: the DISARM stays unconfirmed, and the operator is told
    # (review 18; an ABORT, which disarms itself, is not: test_cmd_disarm_unconfirmed.py)
    assert b.core.disarm_unconfirmed == 1
    (told,) = [e for e in b.events if isinstance(e, DisarmUnconfirmed)]
    assert (told.token, told.reason) == (1, "takeoff_no_ack")
    assert "superseded by LAND" in told.why


def test_a_new_takeoff_stops_the_repeats_not_refused_busy() -> None:
    b = _bench_in_repeats()
    n = len(b.sent)
    b.request(2, TaskKind.TAKEOFF, 4.0)
    b.run(5.0)
    second = b.finished(2)
    assert second is not None and second.reason != FailReason.BUSY
    assert not any(_is_disarm(c) for c in b.sent[n:])


def test_the_vehicle_core_counts_an_unconfirmed_disarm() -> None:
    b = _bench_in_repeats()
    b.run(5.0, stop=lambda: not b.core.busy())
    assert not b.core.busy()
    assert b.core.disarm_unconfirmed == 1


class _LosingEdge(Edge):
    """The XRCE edge losing every NAV_TAKEOFF and the first DISARM: dropped as the backend
    would write them, which on PX4 1.14's best-effort stream is what a datagram lost on the
    wire costs (nothing repairs it); the session and the telemetry stay healthy."""

    def __init__(self, release: str) -> None:
        super().__init__(release)
        self.lose = LoseDisarms(1)
        write = self.core_driver.transmit

        def transmit(cmd: VehicleCommand) -> None:
            if not self.lose(cmd, "down", self.clock.now):
                write(cmd)

        self.core_driver.transmit = transmit


def test_xrce_best_effort_repeats_the_lost_disarm() -> None:
    """PX4 1.14 reads commands on the best-effort stream: nothing repairs a lost DISARM but
    our own repeats. Every NAV_TAKEOFF is lost (``takeoff_no_ack``, armed on the ground) and
    the failure's first DISARM too. [main: armed on the ground until PX4's auto-disarm]"""
    edge = _LosingEdge("1.14")
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    done = edge.takeoff_until_done()
    assert done.reason == FailReason.TAKEOFF_NO_ACK
    assert edge.px4.vehicle.armed  # the DISARM's job
    edge.run(edge.clock.now + 3.0)
    vehicle = edge.px4.vehicle
    assert not vehicle.armed and vehicle.landed == LandedState.ON_GROUND
    assert edge.core.disarm_unconfirmed == 0


def _run_out(v: Scripted) -> list[float]:
    """Drive the sequence's timers with no further telemetry; the DISARMs' send times."""
    times: list[float] = []
    while (timer := v.seq.get_timer()) is not None:
        v.now = timer
        v.seq.handle_timer(v.now)
        sent = v.seq.commands_to_send()
        times += [v.now for c in sent if _is_disarm(c)]
        v.sent += sent
    return times


def test_a_link_silent_after_nav_takeoff_stops_the_repeats() -> None:
    """NAV_TAKEOFF went out, then nothing from PX4: our last ON_GROUND may predate a
    lift-off, so the DISARM is not repeated once the state is older than the heartbeat
    timeout (2.5 s)."""
    v = Scripted()
    v.start()
    v.ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED)  # NAV_TAKEOFF leaves at 0
    for _ in range(4):
        v.advance_to_timer()  # unanswered: takeoff_no_ack at 2 s, the first DISARM
    times = [v.now] + _run_out(v)
    assert v.failure().reason is FailReason.TAKEOFF_NO_ACK
    assert all(t <= 2.5 for t in times)  # the state (t = 0) went stale at 2.5 s
    assert v.seq.done and v.seq.disarm_unconfirmed


def test_before_nav_takeoff_an_older_on_ground_still_gets_the_repeats() -> None:
    """Only our ARM went out (no answer, no telemetry since t = 0): the vehicle cannot have
    left the ground on our commands, so the DISARM is repeated in full."""
    v = Scripted()
    v.start()
    for _ in range(4):
        v.advance_to_timer()  # ARM unanswered: arm_no_ack at 2 s
    first = v.now
    times = [first] + _run_out(v)
    assert v.failure().reason is FailReason.ARM_NO_ACK
    assert [round(t - first, 3) for t in times] == [0.0, 0.5, 1.0, 1.5]
    assert v.seq.done and v.seq.disarm_unconfirmed
