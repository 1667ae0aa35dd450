"""Session 15's review of the PX4 link's defences: what the vehicle's state may vouch for.

Success of LAND, HOLD and ABORT is judged from the vehicle's state, never from an ack alone
(docs/security.md, "A stale or foreign COMMAND_ACK"). That state is only as good as it is
recent: when PX4 stops talking (it reboots, the UART or mavlink-router drops, PX4 hangs),
the last HEARTBEAT stays in ``VehicleState``. Such state must not confirm a command the
silent vehicle never carried out. The sans-IO vehicle core on virtual time.
"""

from __future__ import annotations

from swarmd.px4.constants import (
    SENSOR_PREARM_CHECK,
    LandedState,
    MavCmd,
    MavResult,
    MavState,
)
from swarmd.px4.messages import (
    MODE_LAND,
    MODE_LOITER,
    CommandAck,
    ExtendedSysState,
    Heartbeat,
    Observation,
    Px4Mode,
    SysStatus,
)
from swarmd.px4.readiness import DEFAULT_HEARTBEAT_TIMEOUT_S
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleRequest

SILENT_S = 10.0  # PX4 rebooting: about 10 s without a word on a Pixhawk 6 (docs/px4.md)


def _telemetry(mode: Px4Mode, landed: LandedState, *, armed: bool = True) -> list[Observation]:
    base = 1 | (128 if armed else 0)
    state = MavState.ACTIVE if armed else MavState.STANDBY
    return [
        Heartbeat(12, 2, base, mode.custom_mode, state),
        SysStatus(SENSOR_PREARM_CHECK, 90, 16000),
        ExtendedSysState(landed),
    ]


def _core_last_heard_at_0(mode: Px4Mode, landed: LandedState, *, armed: bool = True) -> VehicleCore:
    core = VehicleCore()
    for obs in _telemetry(mode, landed, armed=armed):
        core.receive_datagram(obs, None, 0.0)
    list(iter(core.next_event, None))
    return core


def _drive(core: VehicleCore, until: float) -> list[TaskFinished]:
    """Fire the core's timer up to ``until`` (bounded: 100 firings); its task ends."""
    for _ in range(100):
        timer = core.get_timer()
        if timer is None or timer > until or not core.busy():
            break
        core.handle_timer(timer)
    return [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]


def test_a_hold_to_a_silent_vehicle_is_not_completed_on_its_last_heartbeat() -> None:
    """PX4 was holding (AUTO.LOITER, where it goes after a take-off) and then fell silent
    (it rebooted). 10 s later the operator sends HOLD: DO_SET_MODE goes out and nobody
    answers. The last HEARTBEAT, 10 s old, says AUTO.LOITER. The operator must not be told
    COMPLETED: nothing on the link has said anything for 10 s. [main: COMPLETED at the
    first retransmission, 'the vehicle state shows it']"""
    core = _core_last_heard_at_0(MODE_LOITER, LandedState.IN_AIR)
    core.request(VehicleRequest(1, TaskKind.HOLD), SILENT_S)
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.DO_SET_MODE]
    (done,) = _drive(core, SILENT_S + 30.0)
    assert not done.ok
    assert done.reason == "no_ack"


def test_a_land_to_a_silent_vehicle_is_not_completed_on_its_last_landed_state() -> None:
    """The same for LAND: the last word, 10 s ago, was AUTO.LAND (an earlier LAND, before
    PX4 rebooted). [main: COMPLETED on that old heartbeat]"""
    core = _core_last_heard_at_0(MODE_LAND, LandedState.LANDING)
    core.request(VehicleRequest(1, TaskKind.LAND), SILENT_S)
    (done,) = _drive(core, SILENT_S + 30.0)
    assert (done.ok, done.reason) == (False, "no_ack")


def test_an_abort_to_a_silent_vehicle_last_seen_disarmed_is_not_completed() -> None:
    """ABORT chooses from the state: on the ground and disarmed, nothing to do, done at
    once. With that state 10 s old it says nothing of now: the abort lands (what it does
    in the air), and with nobody answering it fails. [main: COMPLETED 'on the ground,
    disarmed' with nothing sent]"""
    core = _core_last_heard_at_0(MODE_LOITER, LandedState.ON_GROUND, armed=False)
    core.request(VehicleRequest(1, TaskKind.ABORT), SILENT_S)
    assert [c.command for c in core.datagrams_to_send()] == [MavCmd.NAV_LAND]
    (done,) = _drive(core, SILENT_S + 30.0)
    assert (done.ok, done.reason) == (False, "no_ack")


def test_once_the_vehicle_speaks_again_its_state_confirms_as_before() -> None:
    """The control: the same HOLD, and PX4 back (a fresh HEARTBEAT in AUTO.LOITER within
    the heartbeat timeout of the command) completes it; a fresh on-ground, disarmed state
    ends an ABORT at once, as before."""
    core = _core_last_heard_at_0(MODE_LOITER, LandedState.IN_AIR)
    core.request(VehicleRequest(1, TaskKind.HOLD), SILENT_S)
    # received an ack timeout (0.5 s) after the send: newer than the command (docs/px4.md,
    # "Fresh state"); sooner, it may have been in flight when the command left
    for obs in _telemetry(MODE_LOITER, LandedState.IN_AIR):
        core.receive_datagram(obs, None, SILENT_S + 0.6)
    done = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(d.token, d.ok) for d in done] == [(1, True)]

    fresh = _core_last_heard_at_0(MODE_LOITER, LandedState.ON_GROUND, armed=False)
    fresh.request(VehicleRequest(2, TaskKind.ABORT), DEFAULT_HEARTBEAT_TIMEOUT_S / 2)
    done = [e for e in iter(fresh.next_event, None) if isinstance(e, TaskFinished)]
    assert [(d.token, d.ok) for d in done] == [(2, True)]
    assert fresh.datagrams_to_send() == []


def test_an_accepted_hold_waits_for_a_fresh_heartbeat_to_confirm() -> None:
    """An ACK ACCEPTED from the silent vehicle's link (the last life's, queued) while the
    state is old: not believed, and not believed from the old state either; a fresh
    HEARTBEAT in the mode within the confirm time completes it."""
    core = _core_last_heard_at_0(MODE_LOITER, LandedState.IN_AIR)
    core.request(VehicleRequest(1, TaskKind.HOLD), SILENT_S)
    core.receive_datagram(CommandAck(MavCmd.DO_SET_MODE, MavResult.ACCEPTED), None, SILENT_S)
    assert [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)] == []
    core.receive_datagram(_telemetry(MODE_LOITER, LandedState.IN_AIR)[0], None, SILENT_S + 1.0)
    done = [e for e in iter(core.next_event, None) if isinstance(e, TaskFinished)]
    assert [(d.token, d.ok) for d in done] == [(1, True)]
