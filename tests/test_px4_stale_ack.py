"""A COMMAND_ACK names only its command number and target (mavlink.io, "Command Protocol":
no request id), so an answer meant for an earlier command can reach a later one of the same
number: the last life's, a retransmission's late answer, another system's. What it may and
may not make the operator be told (docs/security.md, "A stale COMMAND_ACK").

The sans-IO vehicle core on virtual time, and the MAVLink backend's filter on a real
loopback socket. What other tests pin already is named in docs/security.md's table.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

from swarmd.px4.actions import NOT_CONFIRMED
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
    assert core.owed.stats() == {"paid": 1, "forgotten": 0, "evicted": 0}


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
