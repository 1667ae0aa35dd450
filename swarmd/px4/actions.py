"""LAND, HOLD and DISARM as sans-IO actions: one command through the ``CommandSender``,
success confirmed by the vehicle's state.

Theory of operation
-------------------
Each action sends one ``VehicleCommand`` through a ``CommandSender`` (ack, retries,
IN_PROGRESS, TEMPORARILY_REJECTED, final results: ``command_sender.py``) and watches the
shared ``VehicleState`` for the effect:

=======  ===============================================  ====================================
action   command                                          confirmed by state when
=======  ===============================================  ====================================
LAND     NAV_LAND                                         mode AUTO.LAND, or landed_state
                                                          LANDING (PX4 navigator's land)
HOLD     DO_SET_MODE custom AUTO.LOITER (PX4's "Hold")    mode AUTO.LOITER
DISARM   COMPONENT_ARM_DISARM param1 = 0 (never forced:   the armed bit clear in HEARTBEAT
         PX4 refuses it in the air, which is the point)
=======  ===============================================  ====================================

Success is declared from state, not from an ack alone, and only from **fresh** state: a
HEARTBEAT (for LAND also an EXTENDED_SYS_STATE) received at least one ack timeout after the
command was first sent (``fresh_from``). The sender already assumes a round trip within
that time (a later answer is treated as lost), so such a message was sent by PX4 after our
command, and every command we sent before it, reached PX4. An older one, even one received
just after the send (in flight when it left), may predate a command still on its way: the
ARM of a take-off an ABORT supersedes, the LAND a HOLD supersedes; PX4 carries that out,
and if our own command is lost the state we held was never true again (docs/px4.md,
"Fresh state"). The state confirming ends the command at once (a lost ack costs nothing); an
ACK ACCEPTED starts ``confirm_timeout_s``
(3 s: PX4 streams HEARTBEAT at 1 Hz, so one lost heartbeat plus jitter) within which the
state must show the effect, else the action fails ``not_confirmed``. No ack is believed
alone, not even before the first HEARTBEAT: a COMMAND_ACK names only the command number, so
the one that arrives first after a restart may answer the last life's command. Nor is a
state older than the heartbeat timeout (``state_max_age_s``, readiness' 2.5 s) believed:
the last HEARTBEAT of a vehicle that rebooted or fell silent says nothing of now
(docs/security.md, "A stale or foreign COMMAND_ACK", case 6). A refusal
(DENIED, ...) or no ack at all fails the action with the MAV_RESULT name or ``no_ack``,
exactly as the sender reports it.

Driving: ``start(now)``, ``observe(obs, now)`` (after the driver fed the same observation
to ``VehicleState``), ``handle_timer(now)``; outputs ``commands_to_send()``,
``get_timer()``, ``next_event()``. Never sleeps, never reads a clock, never raises on
autopilot input.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Final, assert_never

from swarmd.px4.command_sender import (
    AckReceived,
    CommandFinished,
    CommandSent,
    Finish,
    OwedAcks,
    SenderConfig,
    SenderTask,
)
from swarmd.px4.constants import LandedState, MavCmd, Px4AutoSubMode, Px4MainMode
from swarmd.px4.messages import MODE_LAND, MODE_LOITER, Observation, VehicleCommand
from swarmd.px4.readiness import DEFAULT_HEARTBEAT_TIMEOUT_S, VehicleState

CONFIRM_TIMEOUT_S: Final = 3.0  # ACK ACCEPTED -> the effect in state (1 Hz HEARTBEAT, x2 + jitter)
MODE_FLAG_CUSTOM: Final = 1.0  # DO_SET_MODE param1: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
NOT_CONFIRMED: Final = "not_confirmed"
# a later request took the vehicle over (``VehicleCore``; docs/px4.md, "Two requests, one
# vehicle"); the take-off's ``FailReason.SUPERSEDED`` is the same code
SUPERSEDED: Final = "superseded"


class ActionKind(StrEnum):
    LAND = "land"
    HOLD = "hold"
    DISARM = "disarm"


def action_command(kind: ActionKind) -> VehicleCommand:
    """The one command an action sends (MAVLink ``common``; PX4 mode numbers)."""
    match kind:
        case ActionKind.LAND:
            return VehicleCommand.make(MavCmd.NAV_LAND)
        case ActionKind.HOLD:
            return VehicleCommand.make(
                MavCmd.DO_SET_MODE,
                p1=MODE_FLAG_CUSTOM,
                p2=float(Px4MainMode.AUTO),
                p3=float(Px4AutoSubMode.LOITER),
            )
        case ActionKind.DISARM:
            return VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=0.0)
        case _:
            assert_never(kind)


def fresh(at: float | None, since: float) -> bool:
    """Was a message received at ``at`` (None: never) at or after ``since``?"""
    return at is not None and at >= since


def shows(kind: ActionKind, vehicle: VehicleState, since: float) -> bool:
    """Does the vehicle's state, counting only messages received at or after ``since``,
    show the action's effect? (``since``: the send time plus the ack timeout, module
    docstring.)"""
    hb = vehicle.heartbeat if fresh(vehicle.heartbeat_at, since) else None
    match kind:
        case ActionKind.LAND:
            landing = fresh(vehicle.extended_at, since) and (
                vehicle.landed_state == LandedState.LANDING
            )
            return landing or (hb is not None and hb.mode == MODE_LAND)
        case ActionKind.HOLD:
            return hb is not None and hb.mode == MODE_LOITER
        case ActionKind.DISARM:
            return hb is not None and not hb.armed
        case _:
            assert_never(kind)


@dataclass(frozen=True, slots=True)
class ActionFinished:
    """The action's outcome: ``ok``; ``reason`` a MAV_RESULT name, ``no_ack`` or
    ``not_confirmed`` when not; ``detail`` one line for the log."""

    kind: ActionKind
    ok: bool
    reason: str
    detail: str


ActionEvent = ActionFinished | CommandSent | AckReceived


class VehicleAction(SenderTask[ActionFinished]):
    """One LAND, HOLD or DISARM attempt. Create, ``start(now)``, drive until ``done``."""

    def __init__(
        self,
        vehicle: VehicleState,
        kind: ActionKind,
        *,
        sender: SenderConfig | None = None,
        confirm_timeout_s: float = CONFIRM_TIMEOUT_S,
        owed: OwedAcks | None = None,
        state_max_age_s: float = DEFAULT_HEARTBEAT_TIMEOUT_S,
    ) -> None:
        self.vehicle = vehicle
        self.kind = kind
        self.confirm_timeout_s = confirm_timeout_s
        self.state_max_age_s = state_max_age_s  # older state confirms nothing
        self.outcome: ActionFinished | None = None
        super().__init__(sender, owed)  # owed: the vehicle's, shared by all its tasks
        self._handle: int | None = None
        self._confirm_deadline: float | None = None
        # state received from here on may confirm the action (module docstring, "fresh")
        self.fresh_from: float | None = None

    # ---- inputs -------------------------------------------------------------------------

    def start(self, now: float) -> None:
        if self._handle is not None or self.outcome is not None:
            return
        self.fresh_from = now + self._sender.config.ack_timeout_s
        self._handle = self._sender.send(action_command(self.kind), now)
        self._drain(now)

    def observe(self, obs: Observation, now: float) -> None:
        if self.outcome is not None:
            return
        self._sender.observe(obs, now)
        self._drain(now)
        self._check_state(now)

    def handle_timer(self, now: float) -> None:
        """Call at (or after) ``get_timer()``; early calls are harmless."""
        if self.outcome is not None:
            return
        self._check_state(now)
        self._sender.handle_timer(now)
        self._drain(now)
        deadline = self._confirm_deadline
        if not self._finished() and deadline is not None and now >= deadline:
            self._finish(
                now,
                False,
                NOT_CONFIRMED,
                f"{self.kind} ACCEPTED but the vehicle state did not show it within "
                f"{self.confirm_timeout_s:g} s",
            )

    def cancel(self, now: float, why: str = "cancelled") -> None:
        if self.outcome is None:
            self._finish(now, False, "cancelled", why)

    def supersede(self, now: float, why: str) -> None:
        """A later request took the vehicle over: end now, send nothing more (the pending
        command is cancelled, so its unanswered sends are owed: ``OwedAcks``)."""
        if self.outcome is None:
            self._finish(now, False, SUPERSEDED, why)

    # ---- outputs: SenderTask's commands_to_send, get_timer, next_event, done ------------

    def _finished(self) -> bool:
        return self.outcome is not None

    def _own_deadline(self) -> float | None:
        return self._confirm_deadline

    # ---- internals ----------------------------------------------------------------------

    def _on_finished(self, done: CommandFinished, now: float) -> None:
        if done.handle != self._handle or self._finished():
            return
        match done.finish:
            case Finish.ACCEPTED:
                # no HEARTBEAT yet (a new life's first second) is no reason to believe the ack
                # alone: an ACK names only the command number, so it may answer the last
                # life's command (docs/security.md, "A stale COMMAND_ACK"); wait for the
                # state, a fresh one (a heartbeat in flight may predate an earlier command)
                if self._state_shows(now):
                    self._finish(now, True, "", f"{done.command.label} ACCEPTED, state shows it")
                else:
                    self._confirm_deadline = now + self.confirm_timeout_s
            case Finish.CONFIRMED:
                pass  # _check_state finished the action already
            case Finish.REFUSED | Finish.NO_ACK | Finish.CANCELLED:
                self._finish(now, False, done.cause, f"{done.command.label}: {done.why}")
            case _:
                assert_never(done.finish)

    def _check_state(self, now: float) -> None:
        if self.outcome is not None or self._handle is None:
            return
        if self._state_shows(now):
            self._sender.confirm(self._handle, now, "state shows it")
            self._finish(now, True, "", f"{self.kind}: the vehicle state shows it")

    def _state_shows(self, now: float) -> bool:
        """The effect in a state received after ``fresh_from`` and recent enough to speak
        of now (``state_max_age_s``): the module docstring."""
        if self.fresh_from is None or not self.vehicle.heard_within(now, self.state_max_age_s):
            return False
        return shows(self.kind, self.vehicle, self.fresh_from)

    def _finish(self, now: float, ok: bool, reason: str, detail: str) -> None:
        if self._handle is not None and self._sender.pending(self._handle):
            # now, not 0.0: the cancelled command's unanswered sends are owed from now on
            self._sender.cancel(self._handle, now, detail)
        self._confirm_deadline = None
        self.outcome = ActionFinished(self.kind, ok, reason, detail)
        self._events.append(self.outcome)
