"""The take-off sequence as a sans-IO state machine: arm, NAV_TAKEOFF, confirm by state.

Theory of operation
-------------------
Three sources drive it: ``start(now)``, autopilot observations (``observe(obs, now)``, after
the driver has fed the same observation to the shared ``VehicleState``), and the one timer
(``get_timer()`` / ``handle_timer(now)``). It emits ``VehicleCommand``s through
``commands_to_send()`` and ``TakeoffEvent``s through ``next_event()``; it never sleeps,
never reads a clock and never touches a socket.

Which sequence, and why (reference section 1.5): **(A) ARM, then NAV_TAKEOFF**, MAVSDK's
``arm()`` + ``takeoff()`` for PX4, sent back to back with NAV_TAKEOFF leaving the moment the
arm is confirmed. The alternative, (B) DO_SET_MODE AUTO.TAKEOFF while disarmed then ARM, is
only documented from PX4 1.16 on and carries the altitude in the ``MIS_TAKEOFF_ALT``
parameter (a PARAM_SET round trip that changes the vehicle's stored config); (A) works on
PX4 1.14 to main and puts the altitude in the command itself. (A)'s risk is PX4's pre-flight
auto-disarm (``COM_DISARM_PRFLT`` = 10 s: armed, on the ground, no take-off -> disarm, the
"arms then disarms in a loop" reports). Our worst case from ARM accepted to NAV_TAKEOFF
accepted is (1 + retries) x ack timeout = 2 s with the defaults, well inside 10 s, and
``TakeoffConfig.check`` refuses budgets that are not.

The DISARM after a failure (docs/px4.md, "A failed take-off's DISARM"): once ARM has gone
out, any failure sends DISARM (param1 = 0, never the 21196 force: PX4 refuses a non-forced
disarm in the air, so it can only stop a vehicle sitting armed on the ground). The failure
is usually a lossy link, which loses that DISARM too; then PX4 stays armed on the ground,
props maybe spinning (COM_PREARM_MODE), until COM_DISARM_PRFLT (10 s). So the failure is
reported at once (``outcome``, ``TakeoffFailed``) but the sequence is not ``done``: it
retransmits the DISARM through the sender (confirmation 1, 2, 3; the same ack timeout and
retries: at most 4 sends in 2 s with the defaults) until PX4 answers ACCEPTED or a fresh
HEARTBEAT reads disarmed, and only while the vehicle reads ON_GROUND: any other landed
state (in the air, unknown: a StateReset forgets it) stops the repeats at once, and so does
a link silent for the heartbeat timeout once NAV_TAKEOFF went out (the vehicle may have
lifted off since; before NAV_TAKEOFF only our ARM went out, in a mode that stays on the
ground, so the last ON_GROUND stands). Their end is a ``DisarmRepeatsEnded``
event; ``confirmed`` False (``disarm_unconfirmed``) means the vehicle may still be armed.
A supersede or cancel ends them at once, nothing more sent (the newer request owns the
vehicle: ``VehicleCore`` lets any request supersede these repeats); a supersede by a request
that does not disarm the vehicle itself (all but an ABORT) leaves ``disarm_unconfirmed``.
``cancel`` itself sends its DISARM once, unrepeated: the caller (often the closing driver)
drives nothing more.

Altitude (``alt_m``, metres above the ground): NAV_TAKEOFF param7 is **AMSL** (navigator),
so param7 = ground reference + alt_m. The ground reference (``ground_reference``) is
HOME_POSITION.altitude when PX4 has a home; without one (a vehicle that has never armed
with a fix: PX4 sets home *at arming*, from the position it has then, commander
``HomePosition::setHomePosition``) it is where the vehicle stands now, which is what PX4 will
take as home a moment later: GLOBAL_POSITION_INT.alt (the estimate PX4's navigator compares
param7 with) or else GPS_RAW_INT.alt (``vehicle_gps_position.altitude_msl_m`` over XRCE),
both AMSL and only with a 3D GPS fix (a 2D fix has no altitude). With
neither, a relative altitude is refused ``no_home``. ``alt_m=None`` sends NaN, and PX4 climbs
to ``MIS_TAKEOFF_ALT`` (default 2.5 m above home). Params 1-6 are NaN (PX4: "unused";
lat/lon NaN = take off where you are).

Retries (reference 1.6, MAVSDK mavlink_command_sender) are the shared ``CommandSender``'s
(``command_sender.py``): each command gets 0.5 s for its COMMAND_ACK and at most 3
retransmissions, ``confirmation`` counting 1, 2, 3. TEMPORARILY_REJECTED (PX4's answer to a
denied arm or mode switch) waits ``retry_backoff_s`` and retransmits from the same budget;
IN_PROGRESS stretches the wait to 3 s; any other result ends the sequence. An ACK can be
lost, so every step is also confirmed by state (``CommandSender.confirm``):
the armed bit in HEARTBEAT for ARM, mode AUTO.TAKEOFF or leaving the ground for NAV_TAKEOFF,
and success itself is only declared from state: armed and ``landed_state`` TAKEOFF or
IN_AIR (EXTENDED_SYS_STATE), never from an ACK alone.

The flight mode, at every ARM: PX4 flies on ARM alone in some modes (AUTO.TAKEOFF climbs to
``MIS_TAKEOFF_ALT``, AUTO.MISSION starts its mission, OFFBOARD follows another program's
setpoints), and another ground station or an RC switch may put the disarmed vehicle in one.
``start`` arms only when readiness holds, which includes the mode (readiness
``flight_mode``: one of ``STAYS_ON_GROUND``); a mode switched after the readiness report
the commander saw is refused there, nothing sent (``not_ready``). While ARMING, the state
is judged again before each retransmission of ARM (``_check_state`` runs before the
sender's timer): a mode that left the list, or became unknown (a StateReset), ends the
sequence ``mode_changed`` with no further ARM, and the one DISARM covers the ARMs sent.

NAV_TAKEOFF's confirmation by state must show what only our command produced
(``_takeoff_shows``): state received an ack timeout after its first send (the actions'
"fresh" rule, docs/px4.md "Fresh state"), and a mode or a lift-off after a state, held at
the send, that showed the vehicle armed on the ground in a mode that stays there. Our
state is up to a HEARTBEAT period old: a mode switch to AUTO.TAKEOFF in that window, or
while our ARM is on the wire, is a race readiness cannot close, and PX4 then arms in it
and climbs to ``MIS_TAKEOFF_ALT``. The first armed HEARTBEAT shows AUTO.TAKEOFF either way,
so when the ARM was confirmed by its ACK before any armed HEARTBEAT (the usual case:
NAV_TAKEOFF leaves at once), only NAV_TAKEOFF's ACK confirms it, and no ACK is
``takeoff_no_ack``, never a success at an altitude we did not ask for.

Validity (``not_after``, the command's validity end on our clock; docs/dataplane.md,
"Validity at the vehicle"): it bounds every ARM and NAV_TAKEOFF frame, the last as well as
the first. PX4 cannot tell a retransmission from the first copy, so any copy may be the one
that starts the flight; bounding the first alone let a take-off started just before the end
put a NAV_TAKEOFF on the wire up to ~4 s after it (two budgets of 1 + 3 sends). So a
retransmission due at or after ``not_after``, or a NAV_TAKEOFF whose ARM was confirmed
then, is not sent: ``expired_mid_start``. Before NAV_TAKEOFF went out, the DISARM follows at
once (its ground-only repeats); after, PX4 may have taken the first copy and be climbing,
so the state is read for one ack timeout first, sending nothing, exactly as ``held_up``
does. Answers and state that arrive after ``not_after`` are still read: they are about a
frame that left in time. Each frame carries ``not_after`` (``VehicleCommand``) so that a
backend that repairs frames by itself (XRCE's reliable stream) repairs none past it. A
frame leaves in the step that checked it: ``observe`` empties the sender once the state is
judged (a NAV_TAKEOFF an armed HEARTBEAT released waited for the next input, review 18).

Phases (all transitions are in ``_TRANSITIONS``)::

    IDLE --ready--> ARMING --armed--> TAKING_OFF --accepted--> LIFTING --airborne--> SUCCEEDED
      \\--not ready--> FAILED        any phase --rejected/timeout/disarmed--> FAILED
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Final

from swarmd.px4.actions import fresh
from swarmd.px4.command_sender import (
    AckReceived,
    CommandFinished,
    CommandSent,
    Finish,
    OwedAcks,
    SenderConfig,
    SenderTask,
)
from swarmd.px4.constants import GpsFixType, LandedState, MavCmd
from swarmd.px4.messages import MODE_TAKEOFF, Observation, VehicleCommand
from swarmd.px4.readiness import ReadinessConfig, VehicleState, arm_mode_problem, readiness

COM_DISARM_PRFLT_S: Final = 10.0  # PX4 commander default: pre-flight auto-disarm
MIS_TAKEOFF_ALT_M: Final = 2.5  # PX4 navigator default, used when param7 is NaN
MAX_TAKEOFF_ALT_M: Final = 120.0  # common legal ceiling for small UAS (EU/FAA); a typo guard
AIRBORNE: Final = frozenset({LandedState.TAKEOFF, LandedState.IN_AIR})
# a failed take-off's DISARM repeats ended without seeing the vehicle disarmed (the log's
# and ``swarmctl status``'s name for ``DisarmRepeatsEnded`` with ``confirmed`` False)
DISARM_UNCONFIRMED: Final = "disarm_unconfirmed"


@dataclass(frozen=True, slots=True)
class TakeoffConfig:
    """Timing of the sequence; defaults are MAVSDK's command sender and PX4's parameters."""

    command: SenderConfig = field(default_factory=SenderConfig)  # ack timeout, retries
    liftoff_timeout_s: float = 8.0  # NAV_TAKEOFF accepted -> landed_state TAKEOFF/IN_AIR
    auto_disarm_window_s: float = COM_DISARM_PRFLT_S

    def check(self) -> None:
        """Raise ValueError (one line) when the budget cannot beat PX4's auto-disarm."""
        self.command.check()
        if self.liftoff_timeout_s <= 0:
            raise ValueError("takeoff: liftoff_timeout_s must be > 0")
        step = self.command.budget_s()
        if step >= self.auto_disarm_window_s:
            raise ValueError(
                f"takeoff: NAV_TAKEOFF may need {step:g} s after arming, but PX4 disarms after "
                f"{self.auto_disarm_window_s:g} s (COM_DISARM_PRFLT); fix: fewer retries or "
                "a shorter ack_timeout_s"
            )


class TakeoffPhase(StrEnum):
    IDLE = "idle"
    ARMING = "arming"
    TAKING_OFF = "taking_off"
    LIFTING = "lifting"
    SUCCEEDED = "succeeded"
    FAILED = "failed"


class FailReason(StrEnum):
    """Stable codes for ``TakeoffFailed.reason``."""

    NOT_READY = "not_ready"  # refused before sending anything; ``cause`` = readiness reason
    BAD_ALTITUDE = "bad_altitude"
    ARM_REJECTED = "arm_rejected"  # ``cause`` = the last MAV_RESULT name
    ARM_NO_ACK = "arm_no_ack"
    # while arming, the mode left the modes that stay on the ground (readiness flight_mode),
    # or became unknown: no further ARM, one DISARM (module docstring)
    MODE_CHANGED = "mode_changed"
    TAKEOFF_REJECTED = "takeoff_rejected"
    TAKEOFF_NO_ACK = "takeoff_no_ack"
    # the retransmission of ARM or NAV_TAKEOFF fell due while swarmd's loop did not run (a
    # stall, a suspend): sent that late it would start the flight late; one DISARM instead
    HELD_UP = "held_up"
    DISARMED = "disarmed"  # the vehicle disarmed itself (auto-disarm, failsafe, RC)
    NO_LIFTOFF = "no_liftoff"
    CANCELLED = "cancelled"
    # a later LAND, HOLD or ABORT took the vehicle over (``VehicleCore``; docs/px4.md, "Two
    # requests, one vehicle"): the sequence ended at once and sent nothing more, no DISARM
    SUPERSEDED = "superseded"
    BUSY = "busy"  # another task is running (the vehicle core's answer; never from a sequence)
    # the request reached the vehicle core after its command's validity end (``not_after``:
    # held behind a slow state write): refused before anything was sent (the vehicle core's
    # answer; docs/dataplane.md, "Validity at the vehicle")
    EXPIRED_BEFORE_START = "expired_before_start"
    # started in time, but its next ARM or NAV_TAKEOFF (a retransmission, or NAV_TAKEOFF
    # after an ARM confirmed late) fell at or after ``not_after``: not sent; the DISARM
    # instead (after NAV_TAKEOFF went out, once the state had an ack timeout to show it
    # taken, as ``held_up``: module docstring, "Validity")
    EXPIRED_MID_START = "expired_mid_start"


class GroundRef(StrEnum):
    """What a relative take-off altitude is measured from (module docstring, Altitude)."""

    HOME = "home"  # HOME_POSITION / home_position
    GLOBAL_POSITION = "global_position"  # GLOBAL_POSITION_INT, no home yet
    GPS = "gps"  # GPS_RAW_INT / vehicle_gps_position, no home yet


def ground_reference(vehicle: VehicleState) -> tuple[float, GroundRef] | None:
    """The ground's altitude AMSL (metres) and where it came from, or None: no home, no fix."""
    if vehicle.home is not None:
        return vehicle.home.altitude_amsl_m, GroundRef.HOME
    gps = vehicle.gps
    if gps is None or gps.fix_type < GpsFixType.FIX_3D:
        # a 2D fix has no altitude (GPS_FIX_TYPE), whatever readiness was told to accept;
        # without a fix PX4's global estimate is not trusted either
        return None
    if vehicle.position is not None:
        return vehicle.position.alt_mm / 1000.0, GroundRef.GLOBAL_POSITION
    return gps.alt_mm / 1000.0, GroundRef.GPS


_TRANSITIONS: Final[dict[TakeoffPhase, frozenset[TakeoffPhase]]] = {
    TakeoffPhase.IDLE: frozenset({TakeoffPhase.ARMING, TakeoffPhase.FAILED}),
    TakeoffPhase.ARMING: frozenset({TakeoffPhase.TAKING_OFF, TakeoffPhase.FAILED}),
    TakeoffPhase.TAKING_OFF: frozenset(
        {TakeoffPhase.LIFTING, TakeoffPhase.SUCCEEDED, TakeoffPhase.FAILED}
    ),
    TakeoffPhase.LIFTING: frozenset({TakeoffPhase.SUCCEEDED, TakeoffPhase.FAILED}),
    TakeoffPhase.SUCCEEDED: frozenset(),
    TakeoffPhase.FAILED: frozenset(),
}


@dataclass(frozen=True, slots=True)
class TakeoffEvent:
    """Base of the sequence's own events (``SequenceEvent`` adds the sender's)."""


@dataclass(frozen=True, slots=True)
class TakeoffPhaseChanged(TakeoffEvent):
    old: TakeoffPhase
    new: TakeoffPhase
    why: str


@dataclass(frozen=True, slots=True)
class TakeoffSucceeded(TakeoffEvent):
    elapsed_s: float  # start() to airborne confirmed by state
    landed_state: str
    mode: str
    target_amsl_m: float | None  # None: PX4's MIS_TAKEOFF_ALT
    altitude_ref: str | None = None  # what target_amsl_m is above: a ``GroundRef``


@dataclass(frozen=True, slots=True)
class TakeoffFailed(TakeoffEvent):
    reason: FailReason
    cause: str | None  # readiness reason or MAV_RESULT name, when there is one
    detail: str
    elapsed_s: float


@dataclass(frozen=True, slots=True)
class DisarmRepeatsEnded(TakeoffEvent):
    """The failed take-off's DISARM repeats are over (module docstring). ``confirmed``:
    PX4 accepted it or a fresh HEARTBEAT read disarmed; False (``disarm_unconfirmed``): the
    vehicle may still be armed on the ground, or it is not there (``why`` says which)."""

    confirmed: bool
    stopped: bool  # a newer request or a cancel ended them: neither confirmed nor unconfirmed
    why: str


TakeoffOwnEvent = TakeoffPhaseChanged | TakeoffSucceeded | TakeoffFailed | DisarmRepeatsEnded
SequenceEvent = TakeoffOwnEvent | CommandSent | AckReceived
"""What ``TakeoffSequence.next_event`` returns: its phases and outcome, and the sender's
``CommandSent``/``AckReceived`` for each step's command."""


class TakeoffSequence(SenderTask[TakeoffOwnEvent]):
    """One take-off attempt. Create, ``start(now)``, then drive until ``done``.

    Driven by ``start``, ``observe`` and ``handle_timer``; outputs ``commands_to_send``,
    ``get_timer`` and ``next_event``. Never raises on autopilot input.
    """

    def __init__(
        self,
        vehicle: VehicleState,
        alt_m: float | None = None,
        *,
        config: TakeoffConfig | None = None,
        readiness_config: ReadinessConfig | None = None,
        owed: OwedAcks | None = None,
        not_after: float | None = None,
    ) -> None:
        """``not_after``: the command's validity end on the caller's clock (the request's,
        ``VehicleRequest.not_after``); no ARM or NAV_TAKEOFF leaves at or after it. None:
        no validity (a direct take-off)."""
        self.vehicle = vehicle
        self.alt_m = alt_m
        self.not_after = not_after
        self.config = config or TakeoffConfig()
        self.config.check()
        super().__init__(self.config.command, owed)  # owed: the vehicle's, shared
        self.readiness_config = readiness_config or ReadinessConfig()
        self.phase = TakeoffPhase.IDLE
        self.target_amsl_m: float | None = None
        self.altitude_ref: GroundRef | None = None
        self.outcome: TakeoffSucceeded | TakeoffFailed | None = None
        self._t0 = 0.0
        self._handle: int | None = None  # the step's command in the sender
        self._lift_deadline: float | None = None
        self._arm_sent = False
        self._seen_armed = False
        # NAV_TAKEOFF: state received from here on may confirm it (``_takeoff_shows``), only
        # if the state at its send showed the vehicle armed on the ground in a mode that stays
        # there: then a take-off mode or a lift-off can only be our command's
        self._takeoff_fresh_from: float | None = None
        self._state_may_confirm = False
        # NAV_TAKEOFF's retransmission fell due while the loop was held up: until then the
        # answer and state that waited are read before the take-off is judged held_up
        self._held_until: float | None = None
        self._hold_reason: FailReason | None = None  # held_up or expired_mid_start
        # the failure's DISARM, repeated until it shows (module docstring): its sender handle
        # and when a HEARTBEAT may confirm it ("fresh")
        self._disarm_handle: int | None = None
        self._repeating = False
        self._disarm_fresh_from = 0.0
        self.disarm_unconfirmed = False  # the repeats ended with the vehicle maybe armed
        self.disarm_why: str | None = None  # how they ended (``DisarmRepeatsEnded.why``)

    # ---- inputs -------------------------------------------------------------------------

    def start(self, now: float) -> None:
        """Check readiness and altitude; send ARM or fail at once (nothing sent)."""
        if self.phase is not TakeoffPhase.IDLE:
            return
        self._t0 = now
        if self._past_validity(now):
            # the vehicle core refuses such a request before it builds a sequence; a caller
            # driving the sequence itself gets the same answer
            why = f"started {now - (self.not_after or now):.3f} s after its validity end"
            self._fail(now, FailReason.EXPIRED_BEFORE_START, None, why)
            return
        verdict = readiness(self.vehicle, now, self.readiness_config)
        if not verdict.ready:
            cause = None if verdict.reason is None else str(verdict.reason)
            self._fail(now, FailReason.NOT_READY, cause, verdict.detail)
            return
        if self.alt_m is not None:
            if not (math.isfinite(self.alt_m) and 0.0 < self.alt_m <= MAX_TAKEOFF_ALT_M):
                self._fail(
                    now,
                    FailReason.BAD_ALTITUDE,
                    None,
                    f"altitude {self.alt_m} m above home is outside (0, {MAX_TAKEOFF_ALT_M:g}]",
                )
                return
            ground = ground_reference(self.vehicle)
            if ground is None:
                self._fail(
                    now,
                    FailReason.NOT_READY,
                    "no_home",
                    "a relative altitude needs HOME_POSITION, or a GPS fix, to become "
                    "NAV_TAKEOFF's AMSL",
                )
                return
            self.target_amsl_m = ground[0] + self.alt_m
            self.altitude_ref = ground[1]
        target = (
            ""
            if self.target_amsl_m is None
            else f"; NAV_TAKEOFF to {self.target_amsl_m:.1f} m AMSL ({self.altitude_ref} + "
            f"{self.alt_m:g} m)"
        )
        self._set_phase(TakeoffPhase.ARMING, now, f"ready ({verdict.detail}){target}")
        self._arm_sent = True
        self._send(VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=1.0), now)
        self._drain(now)

    def observe(self, obs: Observation, now: float) -> None:
        """An autopilot message (already fed to the shared ``VehicleState``)."""
        if self._finished():
            return
        if self.disarming:
            self._sender.observe(obs, now)
            self._drain(now)
            self._check_disarm(now)
            return
        self._sender.observe(obs, now)
        self._drain(now)
        if not self._finished():
            self._check_state(now)
            # what the state just decided leaves now: a NAV_TAKEOFF after an ARM the state
            # confirmed, checked against ``not_after`` at this ``now``. Left in the sender, it
            # went out at the next input that drained it, unchecked: after the validity end
            # on a quiet link, just ahead of the DISARM of the failure it caused (review 18)
            self._drain(now)

    def handle_timer(self, now: float) -> None:
        """Call at (or after) ``get_timer()``; early calls are harmless."""
        if self._finished():
            return
        if self.disarming:
            # a DISARM sent late is harmless (on the ground only): no held-up rule here
            self._check_disarm(now)
            if self.disarming:
                self._sender.handle_timer(now)
                self._drain(now)
            return
        self._check_state(now)
        if self._finished():
            return
        due = self._sender.get_timer()
        late = self.config.command.ack_timeout_s
        reason = self._not_now(due, now)
        if due is not None and reason is not None:
            # Not sent: a retransmission due after the loop was held up for an ack timeout
            # (a stall, a host suspended), or one that would leave at or after the
            # command's validity end (module docstring, "Validity"). ARM or NAV_TAKEOFF sent
            # now would start the flight late (docs/security.md, "A command frame delivered
            # late"); the DISARM instead
            if self.phase is TakeoffPhase.TAKING_OFF and self._held_until is None:
                # but PX4 may have taken the first NAV_TAKEOFF: its answer and its state
                # wait behind this timer (asyncio runs a due timer after at most one
                # datagram), and a DISARM now meets a vehicle spooling up or already in the
                # air (refused there: FAILED while it climbs). Read them for one ack
                # timeout, sending nothing, then judge (review 17)
                self._held_until = now + late
                self._hold_reason = reason
                return
            if self._held_until is not None and now < self._held_until:
                return
            reason = self._hold_reason or reason
            if reason is FailReason.HELD_UP:
                detail = (
                    f"swarmd's loop was held up {now - due:.1f} s past the retransmission of "
                    f"{self._step_label()}: not sent that late"
                )
            else:
                detail = (
                    f"the next {self._step_label()} fell due {due - (self.not_after or due):.3f}"
                    " s after the command's validity end: not sent"
                )
            self._fail(now, reason, None, detail)
            return
        self._held_until = None  # an answer moved the deadline (IN_PROGRESS): on time
        self._hold_reason = None
        self._sender.handle_timer(now)
        self._drain(now)
        if self._finished():
            return
        if self._lift_deadline is not None and now >= self._lift_deadline:
            landed = self.vehicle.landed_state
            self._fail(
                now,
                FailReason.NO_LIFTOFF,
                None,
                f"landed_state still {landed.name if landed else 'unknown'} "
                f"{self.config.liftoff_timeout_s:g} s after NAV_TAKEOFF was accepted",
            )

    def cancel(self, now: float, why: str = "cancelled by caller") -> None:
        """End now; a take-off that sent ARM sends its DISARM once, never repeated (the
        caller, often the closing driver, drives nothing more)."""
        if self.disarming:
            self._end_disarm(now, f"stopped: {why}", confirmed=False, stopped=True)
        elif not self._finished():
            self._fail(now, FailReason.CANCELLED, None, why, repeat=False)

    def supersede(self, now: float, why: str, *, disarms: bool = False) -> None:
        """A later request took the vehicle over: end now and send nothing more, not even the
        DISARM a failure sends (PX4 obeys the last command: ours must be the later one's).
        During the failure's DISARM repeats the failure stands, and the repeats stop, the
        DISARM unconfirmed (``disarm_unconfirmed``: the operator is told) unless the later
        request ``disarms`` the vehicle itself (an ABORT, whose own outcome says how that
        went). A HOLD, LAND or TAKEOFF does not: a HOLD left the vehicle armed on the ground
        with nothing said (review 18)."""
        if self.disarming:
            self._end_disarm(now, f"stopped: {why}", confirmed=False, stopped=disarms)
        elif not self._finished():
            self._fail(now, FailReason.SUPERSEDED, None, why, disarm=False)

    @property
    def disarming(self) -> bool:
        """Failed (reported), and still repeating the failure's DISARM (module docstring)."""
        return self._repeating

    @property
    def arm_sent(self) -> bool:
        """ARM went out: the vehicle may arm whatever the state shows yet (ABORT's cue)."""
        return self._arm_sent

    def _step_label(self) -> str:
        return "ARM" if self.phase is TakeoffPhase.ARMING else "NAV_TAKEOFF"

    def _past_validity(self, now: float) -> bool:
        return self.not_after is not None and now >= self.not_after

    def _not_now(self, due: float | None, now: float) -> FailReason | None:
        """Why the step's retransmission due at ``due`` may not leave now, if it may not:
        the loop held up an ack timeout past it (``held_up``), or the command's validity
        over (``expired_mid_start``, only when the sender would send a frame: a spent
        budget gives up as usual)."""
        if due is None or due > now:
            return None
        if now - due >= self.config.command.ack_timeout_s:
            return FailReason.HELD_UP
        if self._past_validity(now) and self._sender.would_send(now):
            return FailReason.EXPIRED_MID_START
        return None

    # ---- outputs: SenderTask's commands_to_send, get_timer, next_event, done ------------

    def _finished(self) -> bool:
        ended = self.phase in (TakeoffPhase.SUCCEEDED, TakeoffPhase.FAILED)
        return ended and not self.disarming

    def get_timer(self) -> float | None:
        due = super().get_timer()
        if due is None or self._held_until is None:
            return due
        return max(due, self._held_until)  # the sender's past deadline: not sent (held_up)

    def _own_deadline(self) -> float | None:
        return self._lift_deadline

    # ---- internals ----------------------------------------------------------------------

    def _send(self, command: VehicleCommand, now: float) -> None:
        # ARM and NAV_TAKEOFF carry the validity end, for a backend that repairs frames by
        # itself (XRCE's reliable stream: none repaired past it)
        self._handle = self._sender.send(replace(command, not_after=self.not_after), now)

    def _on_finished(self, done: CommandFinished, now: float) -> None:
        if done.handle == self._disarm_handle:
            self._disarm_handle = None
            if done.finish is Finish.ACCEPTED:
                self._end_disarm(now, "DISARM ACCEPTED", confirmed=True)
            elif done.finish in (Finish.REFUSED, Finish.NO_ACK):
                self._end_disarm(now, f"DISARM {done.why}", confirmed=False)
            return
        if done.handle != self._handle or self._finished():
            return  # a command the sequence settled, or cancelled, already
        self._handle = None
        if done.finish is Finish.ACCEPTED:
            self._step_done(now, "COMMAND_ACK ACCEPTED")
        elif done.finish in (Finish.REFUSED, Finish.NO_ACK):
            self._give_up(done, now)

    def _give_up(self, done: CommandFinished, now: float) -> None:
        arm = done.command.command == MavCmd.COMPONENT_ARM_DISARM
        result = done.result
        said = self.vehicle.last_warning
        tail = f"; PX4 says {said.text!r}" if said is not None else ""
        if result is None:
            reason = FailReason.ARM_NO_ACK if arm else FailReason.TAKEOFF_NO_ACK
            detail = f"no COMMAND_ACK for {done.command.label} after {done.sends} sends"
        else:
            reason = FailReason.ARM_REJECTED if arm else FailReason.TAKEOFF_REJECTED
            detail = f"{done.command.label} answered {result.name} after {done.sends} sends"
        self._fail(now, reason, None if result is None else result.name, detail + tail)

    def _check_state(self, now: float) -> None:
        """Confirm steps by what the vehicle reports, whatever happened to the ACKs."""
        v = self.vehicle
        if self.phase is TakeoffPhase.ARMING and not v.armed:
            # before any retransmission of ARM (handle_timer checks state first): only in a
            # mode that stays on the ground, the rule readiness applied at start
            problem = arm_mode_problem(v.heartbeat)
            if problem is not None:
                self._fail(now, FailReason.MODE_CHANGED, None, f"while arming: {problem}")
                return
        if v.armed is None:
            # no HEARTBEAT since a StateReset (a new PX4 life): unknown, not disarmed;
            # nothing is confirmed or failed on it, the timers still run
            return
        armed = v.armed
        if armed:
            self._seen_armed = True
        elif self._seen_armed and self.phase in (TakeoffPhase.TAKING_OFF, TakeoffPhase.LIFTING):
            self._fail(
                now,
                FailReason.DISARMED,
                None,
                "the vehicle disarmed before lifting off (PX4 auto-disarms "
                f"{self.config.auto_disarm_window_s:g} s after arming without take-off)",
            )
            return
        airborne = v.landed_state in AIRBORNE
        if self.phase is TakeoffPhase.ARMING and armed:
            self._step_done(now, "armed bit set in HEARTBEAT")
        elif self.phase is TakeoffPhase.TAKING_OFF and armed and self._takeoff_shows():
            mode = v.heartbeat.mode if v.heartbeat is not None else None
            self._step_done(now, f"mode {mode}, landed_state {_name(v.landed_state)}")
        if self.phase is TakeoffPhase.LIFTING and armed and airborne:
            self._succeed(now)

    def _step_done(self, now: float, why: str) -> None:
        if self.phase is TakeoffPhase.ARMING:
            self._settle(now, why)
            if self._past_validity(now):
                # the vehicle armed on an ARM sent in time, but NAV_TAKEOFF would leave after
                # the validity end: not sent, the DISARM instead (nothing climbs yet)
                late = now - (self.not_after or now)
                detail = (
                    f"ARM confirmed ({why}) {late:.3f} s after the command's validity end: "
                    "NAV_TAKEOFF not sent"
                )
                self._fail(now, FailReason.EXPIRED_MID_START, None, detail)
                return
            self._set_phase(TakeoffPhase.TAKING_OFF, now, f"arm confirmed: {why}")
            alt = math.nan if self.target_amsl_m is None else self.target_amsl_m
            self._takeoff_fresh_from = now + self.config.command.ack_timeout_s
            self._state_may_confirm = self._armed_where_it_stays()
            self._send(VehicleCommand.make(MavCmd.NAV_TAKEOFF, p7=alt), now)
        elif self.phase is TakeoffPhase.TAKING_OFF:
            self._settle(now, why)
            self._lift_deadline = now + self.config.liftoff_timeout_s
            self._set_phase(TakeoffPhase.LIFTING, now, f"NAV_TAKEOFF confirmed: {why}")
            self._check_state(now)

    def _armed_where_it_stays(self) -> bool:
        """Armed (a HEARTBEAT sent after our ARM took effect: readiness pinned disarmed, and
        links deliver in order), still on the ground, in a mode of ``STAYS_ON_GROUND``."""
        v = self.vehicle
        return (
            v.armed is True
            and v.landed_state not in AIRBORNE
            and arm_mode_problem(v.heartbeat) is None
        )

    def _takeoff_shows(self) -> bool:
        """Does the state show what only our NAV_TAKEOFF produced (module docstring)? Mode
        AUTO.TAKEOFF in a fresh HEARTBEAT, or TAKEOFF/IN_AIR in a fresh EXTENDED_SYS_STATE,
        where the state held at the send showed the vehicle armed, on the ground, in a mode
        of ``STAYS_ON_GROUND``; any other state at the send leaves it to the ACK."""
        v, since = self.vehicle, self._takeoff_fresh_from
        if since is None or not self._state_may_confirm:
            return False
        mode = v.heartbeat is not None and v.heartbeat.mode == MODE_TAKEOFF
        airborne = v.landed_state in AIRBORNE
        return (fresh(v.heartbeat_at, since) and mode) or (fresh(v.extended_at, since) and airborne)

    def _succeed(self, now: float) -> None:
        v = self.vehicle
        landed = _name(v.landed_state)
        self.outcome = TakeoffSucceeded(
            elapsed_s=now - self._t0,
            landed_state=landed,
            # AUTO.TAKEOFF, or AUTO.LOITER once PX4 reached the altitude; another mode means
            # a pilot took over, and the vehicle is still off the ground: a success
            mode="unknown" if v.heartbeat is None else v.heartbeat.mode.name,
            target_amsl_m=self.target_amsl_m,
            altitude_ref=None if self.altitude_ref is None else str(self.altitude_ref),
        )
        self._set_phase(TakeoffPhase.SUCCEEDED, now, f"airborne: landed_state {landed}")
        self._events.append(self.outcome)

    def _settle(self, now: float, why: str) -> None:
        """The step's command needs no more sends: its effect shows (or it was accepted)."""
        if self._handle is not None:
            self._sender.confirm(self._handle, now, why)
            self._handle = None

    def _fail(
        self,
        now: float,
        reason: FailReason,
        cause: str | None,
        detail: str,
        *,
        disarm: bool = True,
        repeat: bool = True,
    ) -> None:
        if self._handle is not None:
            self._sender.cancel(self._handle, now, f"{reason}")
            self._handle = None
        self._lift_deadline = None
        self._held_until = None
        self._hold_reason = None
        if self._arm_sent and disarm:
            # leave nothing armed on the ground (module docstring, the DISARM after a failure).
            # Its answer has ARM's number and may answer the next take-off's ARM (mavlink.io,
            # "Command Protocol": an ack has no request id); a DISARM ended unanswered is owed
            # by the sender (command_sender, "Answers still owed")
            handle = self._sender.send(
                VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=0.0), now
            )
            if repeat:
                self._disarm_handle = handle
                self._repeating = True
                self._disarm_fresh_from = now + self.config.command.ack_timeout_s
            else:
                self._sender.cancel(handle, now, "the cancelled take-off's one DISARM")
            self._drain(now)
        self.outcome = TakeoffFailed(reason, cause, detail, now - self._t0)
        self._set_phase(TakeoffPhase.FAILED, now, f"{reason}: {detail}")
        self._events.append(self.outcome)
        if self._repeating:
            self._check_disarm(now)  # on the ground? (the first DISARM went out regardless)

    def _check_disarm(self, now: float) -> None:
        """During the repeats: a fresh HEARTBEAT reading disarmed ends them; a vehicle not
        read ON_GROUND gets no further DISARM (module docstring)."""
        v = self.vehicle
        if v.armed is False and fresh(v.heartbeat_at, self._disarm_fresh_from):
            self._end_disarm(now, "a HEARTBEAT reads disarmed", confirmed=True)
        elif v.landed_state != LandedState.ON_GROUND:
            why = f"not repeated: landed_state {_name(v.landed_state)}"
            self._end_disarm(now, why, confirmed=False)
        elif self._takeoff_fresh_from is not None and not v.heard_within(
            now, self.readiness_config.heartbeat_timeout_s
        ):
            # NAV_TAKEOFF went out: "on the ground" from a link silent since may predate a
            # lift-off (readiness' rule). Before it, only our ARM went, in a mode that stays
            # on the ground (checked before every send of ARM), so an older ON_GROUND stands
            self._end_disarm(now, "not repeated: no recent state", confirmed=False)

    def _end_disarm(self, now: float, why: str, *, confirmed: bool, stopped: bool = False) -> None:
        """The repeats are over: say how (``DisarmRepeatsEnded``)."""
        if not self._repeating:
            return
        self._repeating = False
        if self._disarm_handle is not None:
            handle, self._disarm_handle = self._disarm_handle, None
            self._sender.cancel(handle, now, why)
            self._drain(now)
        self.disarm_unconfirmed = not (confirmed or stopped)
        self.disarm_why = why
        self._events.append(DisarmRepeatsEnded(confirmed, stopped, why))

    def _set_phase(self, new: TakeoffPhase, now: float, why: str) -> None:
        if new not in _TRANSITIONS[self.phase]:
            raise AssertionError(f"takeoff: illegal transition {self.phase} -> {new}")
        self._events.append(TakeoffPhaseChanged(self.phase, new, why))
        self.phase = new


def _name(landed: LandedState | None) -> str:
    return "unknown" if landed is None else landed.name
