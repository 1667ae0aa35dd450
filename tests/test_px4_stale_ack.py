"""A COMMAND_ACK names only its command number and target (mavlink.io, "Command Protocol":
no request id), so an answer meant for an earlier command can reach a later one of the same
number: the last life's, a retransmission's late answer, another system's. What it may and
may not make the operator be told (docs/security.md, "A stale COMMAND_ACK").

The sans-IO vehicle core on virtual time, and the MAVLink backend's filter on a real
loopback socket. What other tests pin already is named in docs/security.md's table.
"""

from __future__ import annotations

import asyncio
import re
import socket
from collections.abc import Callable

from swarmd.px4 import actions, takeoff
from swarmd.px4.actions import NOT_CONFIRMED
from swarmd.px4.command_sender import MAX_OWED_COMMANDS
from swarmd.px4.constants import (
    COMP_ID_AUTOPILOT1,
    SENSOR_PREARM_CHECK,
    GpsFixType,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
)
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    CommandAck,
    ExtendedSysState,
    GpsRawInt,
    Heartbeat,
    HomePosition,
    Observation,
    Px4Mode,
    SysStatus,
)
from swarmd.px4.transport import UdpLink
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleRequest

BOUND_S = 10.0
GCS = 255  # QGroundControl's system id (component 190): PX4 answers its commands to it


def _heartbeat(mode: Px4Mode) -> Heartbeat:
    return Heartbeat(12, 2, 1 | 128, mode.custom_mode, MavState.ACTIVE)  # armed, custom mode


def _finished(core: VehicleCore) -> list[TaskFinished]:
    return [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]


def _run_until_timer_settles(core: VehicleCore, feed: list[tuple[float, Observation]]) -> None:
    """Feed ``feed`` in time order, firing the core's timer between (bounded)."""
    for _ in range(100):
        timer = core.get_timer()
        nxt = feed[0][0] if feed else None
        if nxt is not None and (timer is None or nxt <= timer):
            t, obs = feed.pop(0)
            core.receive_datagram(obs, None, t)
        elif timer is not None and core.busy():
            core.handle_timer(timer)
        else:
            return


def test_a_last_lifes_land_accepted_before_the_first_heartbeat_is_not_completed() -> None:
    """Case 1. A new life gets LAND and sends NAV_LAND; before any HEARTBEAT the first
    answer on the link is the last life's NAV_LAND ACCEPTED (queued while swarmd restarted).
    PX4 never took this one: the heartbeats say AUTO.LOITER in the air. The operator must not
    be told COMPLETED. [main: believed on the ack alone, COMPLETED at once]"""
    core = VehicleCore()
    core.request(VehicleRequest(1, TaskKind.LAND), 0.0)
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.NAV_LAND]
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.ACCEPTED), None, 0.01)
    assert _finished(core) == []  # not on the ack alone
    feed: list[tuple[float, Observation]] = [
        (0.5 + i, _heartbeat(MODE_LOITER)) for i in range(5)
    ] + [(0.6, ExtendedSysState(LandedState.IN_AIR))]
    feed.sort(key=lambda item: item[0])
    _run_until_timer_settles(core, feed)
    (done,) = _finished(core)
    assert (done.ok, done.reason) == (False, NOT_CONFIRMED)


def test_before_the_first_heartbeat_an_accepted_land_completes_once_the_state_shows_it() -> None:
    """The fix's other side: the real answer, then the first heartbeats in AUTO.LAND."""
    core = VehicleCore()
    core.request(VehicleRequest(1, TaskKind.LAND), 0.0)
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.ACCEPTED), None, 0.01)
    core.receive_datagram(_heartbeat(MODE_LAND), None, 0.5)
    (done,) = _finished(core)
    assert done.ok


def test_a_late_refusal_of_an_earlier_land_does_not_fail_a_later_one() -> None:
    """Case 2, the refusal: PX4 answers each of an earlier NAV_LAND's transmissions. The first
    DENIED ends it (FAILED DENIED); the operator sends LAND again, and the DENIED for the
    earlier retransmission arrives while the later NAV_LAND waits. That answer is owed to
    the earlier command, so it pays its debt and the later LAND completes once the state
    shows AUTO.LAND. [main: the later LAND FAILED DENIED while the vehicle lands]"""
    core = VehicleCore()
    for obs in (_heartbeat(MODE_LOITER), SysStatus(SENSOR_PREARM_CHECK, 90, 16000)):
        core.receive_datagram(obs, None, 0.0)
    core.receive_datagram(ExtendedSysState(LandedState.IN_AIR), None, 0.0)
    core.request(VehicleRequest(1, TaskKind.LAND), 0.0)
    core.handle_timer(0.5)  # no answer yet: the retransmission, confirmation 1
    sent = core.datagrams_to_send()
    assert [(c.command, c.confirmation) for c in sent] == [
        (MavCmd.NAV_LAND, 0),
        (MavCmd.NAV_LAND, 1),
    ]
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.DENIED), None, 0.6)
    (first,) = _finished(core)
    assert (first.token, first.ok, first.reason) == (1, False, "DENIED")
    core.request(VehicleRequest(2, TaskKind.LAND), 0.7)
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.DENIED), None, 0.71)  # conf 1's
    assert _finished(core) == []
    # a heartbeat received an ack timeout after the send: state older may predate it
    core.receive_datagram(_heartbeat(MODE_LAND), None, 1.2)
    (later,) = _finished(core)
    assert (later.token, later.ok) == (2, True)
    assert core.owed.stats() == {"paid": 1, "forgotten": 0, "pooled": 0, "evicted": 0}


def test_a_failed_takeoffs_disarm_answer_does_not_arm_the_next_takeoff() -> None:
    """Case 2, the DISARM: a take-off fails after arming (NAV_TAKEOFF DENIED) and sends one
    DISARM, which has ARM's command number. The operator takes off again at once; the
    DISARM's ACCEPTED arrives while the new ARM waits. Taken as the ARM's answer, NAV_TAKEOFF
    would go to a vehicle that is not armed (and PX4 would refuse it). The answer is owed to
    the DISARM: the ARM waits for its own. [main: NAV_TAKEOFF sent on the DISARM's answer]"""
    core = VehicleCore()
    clock = [0.0]

    def feed(*obs: Observation) -> None:
        for o in obs:
            core.receive_datagram(o, None, clock[0])

    def telemetry(armed: bool) -> tuple[Observation, ...]:
        base = 1 | (128 if armed else 0)
        state = MavState.ACTIVE if armed else MavState.STANDBY
        return (
            Heartbeat(12, 2, base, MODE_LOITER.custom_mode, state),
            SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
            ExtendedSysState(LandedState.ON_GROUND),
            GpsRawInt(GpsFixType.FIX_3D, 12),
            HomePosition(0, 0, 488_000),
        )

    feed(*telemetry(False))
    core.request(VehicleRequest(1, TaskKind.TAKEOFF, alt_m=5.0), clock[0])
    clock[0] = 0.05
    feed(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED), *telemetry(True))
    clock[0] = 0.1
    feed(CommandAck(MavCmd.NAV_TAKEOFF, MavResult.DENIED))
    (first,) = _finished(core)
    assert (first.ok, first.reason) == (False, "takeoff_rejected: DENIED")
    sent = core.datagrams_to_send()
    assert [(c.command, c.params[0]) for c in sent][-1] == (MavCmd.COMPONENT_ARM_DISARM, 0.0)
    clock[0] = 0.2
    feed(*telemetry(False))  # PX4 disarmed; its COMMAND_ACK is still on the way
    core.request(VehicleRequest(2, TaskKind.TAKEOFF, alt_m=5.0), clock[0])
    assert [c.params[0] for c in core.datagrams_to_send()] == [1.0]  # the new ARM
    clock[0] = 0.21
    feed(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED))  # the DISARM's answer
    assert core.datagrams_to_send() == []  # no NAV_TAKEOFF to a disarmed vehicle
    clock[0] = 0.25
    feed(CommandAck(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED), *telemetry(True))
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.NAV_TAKEOFF]
    assert _finished(core) == []


def test_acks_for_another_system_or_from_another_sender_never_reach_the_core() -> None:
    """Case 4 on a real loopback socket (signing off, so only the pin and the filters act):
    PX4's answer to the GCS, an ack from another component or system of the link, and one
    from another port (a local user) are dropped and counted; PX4's answer to us passes."""
    asyncio.run(_acks_filtered())


async def _acks_filtered() -> None:
    seen: list[Observation] = []
    be = MavlinkBackend("udpin:127.0.0.1:0", sysid=1)
    await be.start(lambda obs, now: seen.append(obs))
    px4 = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        link = be.link
        assert isinstance(link, UdpLink) and link.local_port is not None
        to = ("127.0.0.1", link.local_port)
        autopilot = MavlinkCodec(1, COMP_ID_AUTOPILOT1)
        px4.sendto(autopilot.encode(_heartbeat(MODE_LOITER)), to)  # pins px4's port
        await _until(lambda: len(seen) == 1)
        land = MavCmd.NAV_LAND
        px4.sendto(autopilot.encode(CommandAck(land, MavResult.DENIED, 0, GCS, 190)), to)
        camera = MavlinkCodec(1, 100)
        px4.sendto(camera.encode(CommandAck(land, MavResult.ACCEPTED, 0, 1, 191)), to)
        drone2 = MavlinkCodec(2, COMP_ID_AUTOPILOT1)
        px4.sendto(drone2.encode(CommandAck(land, MavResult.ACCEPTED, 0, 1, 191)), to)
        other.sendto(autopilot.encode(CommandAck(land, MavResult.ACCEPTED, 0, 1, 191)), to)
        ours = CommandAck(land, MavResult.IN_PROGRESS, 0, 1, 191)
        px4.sendto(autopilot.encode(ours), to)  # the last, so all others were read before it
        await _until(lambda: len(seen) == 2)
        assert seen[1] == ours
        assert be.intake.foreign == 3
        pin = be.stats()["autopilot"]
        assert isinstance(pin, dict) and pin["dropped_address"] == 1
    finally:
        px4.close()
        other.close()
        await be.close()


async def _until(check: Callable[[], bool]) -> None:
    async def poll() -> None:
        while not check():  # noqa: ASYNC110 - a test probe, bounded by BOUND_S
            await asyncio.sleep(0.01)

    await asyncio.wait_for(poll(), BOUND_S)


def _in_the_air(core: VehicleCore, now: float) -> None:
    for obs in (_heartbeat(MODE_LOITER), SysStatus(SENSOR_PREARM_CHECK, 90, 16000)):
        core.receive_datagram(obs, None, now)
    core.receive_datagram(ExtendedSysState(LandedState.IN_AIR), None, now)


def test_late_refusals_beyond_four_owed_answers_do_not_fail_the_last_land() -> None:
    """One vehicle owes more than ``MAX_OWED_PER_COMMAND`` answers of one number: the
    operator sends LAND six times within 0.25 s (each supersedes the one before, whose one
    NAV_LAND is owed its answer: five debts). PX4's five answers to them come late, each
    DENIED, then its ACCEPTED to the last, and it lands. Every refusal pays a debt; the
    last LAND completes. [main: the table kept four and dropped the oldest; the fifth
    DENIED was credited to the last LAND, FAILED DENIED while the vehicle lands]"""
    core = VehicleCore()
    _in_the_air(core, 0.0)
    for token in range(1, 7):
        core.request(VehicleRequest(token, TaskKind.LAND), (token - 1) * 0.05)
    sent = core.datagrams_to_send()
    assert [(c.command, c.confirmation) for c in sent] == [(MavCmd.NAV_LAND, 0)] * 6
    superseded = _finished(core)
    assert [(d.token, d.ok) for d in superseded] == [(t, False) for t in range(1, 6)]
    for i in range(5):
        core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.DENIED), None, 0.3 + i / 100)
    core.receive_datagram(CommandAck(MavCmd.NAV_LAND, MavResult.ACCEPTED), None, 0.36)
    assert _finished(core) == []
    core.receive_datagram(_heartbeat(MODE_LAND), None, 0.8)  # an ack timeout after the send
    (last,) = _finished(core)
    assert (last.token, last.ok) == (6, True)
    assert core.owed.stats()["paid"] == 5


def test_a_failed_takeoffs_four_arms_and_its_disarm_are_all_owed() -> None:
    """One task alone owes five answers of ARM's number: a take-off's ARM goes four times
    (1 + 3 retries) without an answer and fails ``arm_no_ack``, then sends its one DISARM
    (ARM's number). The operator takes off again at once; the five late answers (ARM
    ACCEPTED four times, the DISARM's ACCEPTED) arrive while the new ARM waits, and the
    vehicle is disarmed. None of them may move the new take-off to NAV_TAKEOFF. [main: four
    kept, the fifth answer credited to the new ARM: NAV_TAKEOFF sent to a disarmed
    vehicle]"""
    core = VehicleCore()

    def telemetry(now: float) -> None:
        for obs in (
            Heartbeat(12, 2, 1, MODE_LOITER.custom_mode, MavState.STANDBY),  # disarmed
            SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
            ExtendedSysState(LandedState.ON_GROUND),
            GpsRawInt(GpsFixType.FIX_3D, 12),
            HomePosition(0, 0, 488_000),
        ):
            core.receive_datagram(obs, None, now)

    telemetry(0.0)
    core.request(VehicleRequest(1, TaskKind.TAKEOFF, alt_m=5.0), 0.0)
    for now in (0.5, 1.0, 1.5, 2.0):  # no answer: three retransmissions, then give up
        telemetry(now)
        core.handle_timer(now)
    (first,) = _finished(core)
    assert (first.ok, first.reason) == (False, "arm_no_ack")
    sent = [(c.command, c.params[0]) for c in core.datagrams_to_send()]
    arm = MavCmd.COMPONENT_ARM_DISARM
    assert sent == [(arm, 1.0)] * 4 + [(arm, 0.0)]  # four ARMs, the one DISARM
    core.request(VehicleRequest(2, TaskKind.TAKEOFF, alt_m=5.0), 2.1)
    assert [(c.command, c.params[0]) for c in core.datagrams_to_send()] == [(arm, 1.0)]
    for i in range(5):
        core.receive_datagram(CommandAck(arm, MavResult.ACCEPTED), None, 2.15 + i / 100)
    assert core.datagrams_to_send() == []  # no NAV_TAKEOFF to a disarmed vehicle
    assert _finished(core) == []
    assert core.owed.stats()["paid"] == 5


def test_the_vehicle_sends_fewer_command_numbers_than_the_owed_tables_rows() -> None:
    """``MAX_OWED_COMMANDS`` evicts a whole number's debts (their answers then credited), so
    it must never be reached: the sender's only callers, the take-off and the actions, send
    four numbers (ARM/DISARM, NAV_TAKEOFF, NAV_LAND, DO_SET_MODE)."""
    numbers = set()
    for module in (takeoff, actions):
        assert module.__file__ is not None
        with open(module.__file__, encoding="utf-8") as source:
            numbers |= set(re.findall(r"VehicleCommand\.make\(\s*MavCmd\.(\w+)", source.read()))
    assert numbers == {"COMPONENT_ARM_DISARM", "NAV_TAKEOFF", "NAV_LAND", "DO_SET_MODE"}
    assert len(numbers) < MAX_OWED_COMMANDS
