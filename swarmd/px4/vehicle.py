"""One vehicle as a sans-IO core: live state, readiness changes, take-off, LAND/HOLD/ABORT.

Theory of operation
-------------------
Driving sources (the driver's protocol, ``swarmd.driver``): ``receive_datagram(obs, source,
now)`` with each autopilot observation a backend decoded (MAVLink or XRCE-DDS, any
``messages.Observation``), ``handle_timer(now)``, and the requests ``takeoff``, ``land``,
``hold``, ``abort``, each tagged with the caller's ``token`` (the swarm member's own task
number, never a command id: docs/dataplane.md, "Exactly once" 4).
Outputs: ``datagrams_to_send()`` (``VehicleCommand``s for the backend), ``get_timer()`` (the
earliest of the heartbeat-stale deadline and the running tasks' timers) and
``next_event()``: ``ReadinessChanged`` whenever ready/reason changes (including "the link
went quiet", by the timer), ``TaskFinished`` once per request, and the tasks' own events
(phases, commands sent, acks) for the log.

A request of a kind in ``EXPIRES`` (TAKEOFF) that arrives at or after its ``not_after``
(its command's validity end, set by the swarm member) starts nothing: its ``TaskFinished``
says ``expired_before_start`` (docs/dataplane.md, "Validity at the vehicle"). A take-off
started in time gets it too: no ARM or NAV_TAKEOFF leaves at or after it
(``expired_mid_start``, ``takeoff`` module docstring, "Validity").

Tasks: **at most one runs** (docs/px4.md, "Two requests, one vehicle"). A request that
arrives while a task runs meets ``RULES``: a TAKEOFF is refused ``busy`` (a take-off only
starts from quiet, so it never undoes a LAND, HOLD or ABORT implicitly); a LAND, HOLD or
ABORT supersedes the running task, as PX4 itself lets the last mode command win: the old
task ends at once with its own ``TaskFinished`` (reason ``superseded: <new kind>``, the
detail naming the new request for the log) and sends nothing after that, not even a failed
take-off's DISARM; its pending command is cancelled, so the answers it is still owed are
paid from the shared ``OwedAcks`` and cannot settle the new task's command of the same
number. Then the new task starts. A failed take-off still repeating its DISARM (``takeoff``,
module docstring) has reported its failure already: any request, a TAKEOFF too, stops the
repeats and runs, and no second ``TaskFinished`` follows; a ``DisarmUnconfirmed`` does unless
the request is an ABORT (it disarms the vehicle itself; review 18). LAND, HOLD and DISARM are
``actions.VehicleAction``s, all commands through the ``CommandSender``; each confirms only
from state received an ack timeout after its send (``actions``, "fresh"). ABORT lands a
vehicle in the air, disarms one armed on the ground, or one that may be armed without our
state showing it yet: its superseded take-off had sent ARM (also through a LAND, HOLD or
ABORT that superseded it in turn), or the last ARM on the wire (``last_arm_at``) is newer
than the HEARTBEAT we hold, less an ack timeout (PX4 may carry that ARM out before our
DISARM). Never a forced disarm, which PX4 would obey in the air: a DISARM PX4 refuses (it is
in the air after all, our landed state older than its lift-off) is followed by a LAND under
the same request (``_disarm_refused``). A vehicle on the ground and disarmed, by a HEARTBEAT
newer than the last ARM, needs nothing (``on_ground_disarmed``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import StrEnum
from typing import Final, assert_never

from swarmd.px4.actions import (
    SUPERSEDED,
    ActionEvent,
    ActionFinished,
    ActionKind,
    VehicleAction,
    action_command,
    fresh,
)
from swarmd.px4.command_sender import OwedAcks
from swarmd.px4.constants import LandedState, MavCmd, MavResult
from swarmd.px4.messages import CommandAck, Observation, VehicleCommand
from swarmd.px4.readiness import Readiness, ReadinessConfig, VehicleState, readiness
from swarmd.px4.takeoff import (
    FailReason,
    SequenceEvent,
    TakeoffConfig,
    TakeoffFailed,
    TakeoffSequence,
    TakeoffSucceeded,
)

ON_GROUND_DISARMED: Final = "on_ground_disarmed"

TakeoffOutcome = TakeoffSucceeded | TakeoffFailed


class TaskKind(StrEnum):
    TAKEOFF = "takeoff"
    LAND = "land"
    HOLD = "hold"
    ABORT = "abort"


class Meet(StrEnum):
    """What a new request does to the task running when it arrives (``RULES``)."""

    BUSY = "busy"  # the new request is refused; the running task goes on
    SUPERSEDE = "supersede"  # the running task ends ``superseded``; the new one starts


# running task x new request -> what happens (docs/px4.md, "Two requests, one vehicle").
# Every pair is written out so a reader sees the whole rule; a TaskKind without its row and
# column fails test_every_pair_has_a_rule. The last stop command wins, as in PX4 (a mode
# command replaces the mode, whatever set it); a take-off never interrupts anything: after a
# LAND it would undo the operator's stop, after a take-off it is a duplicate.
RULES: Final[dict[tuple[TaskKind, TaskKind], Meet]] = {
    (TaskKind.TAKEOFF, TaskKind.TAKEOFF): Meet.BUSY,
    (TaskKind.TAKEOFF, TaskKind.LAND): Meet.SUPERSEDE,  # stop climbing, land
    (TaskKind.TAKEOFF, TaskKind.HOLD): Meet.SUPERSEDE,  # stop climbing, hold
    (TaskKind.TAKEOFF, TaskKind.ABORT): Meet.SUPERSEDE,  # then land or disarm
    (TaskKind.LAND, TaskKind.TAKEOFF): Meet.BUSY,  # never undo a LAND implicitly
    (TaskKind.LAND, TaskKind.LAND): Meet.SUPERSEDE,  # the later LAND owns the vehicle
    (TaskKind.LAND, TaskKind.HOLD): Meet.SUPERSEDE,  # explicit, as after the LAND confirms
    (TaskKind.LAND, TaskKind.ABORT): Meet.SUPERSEDE,  # ABORT lands (or disarms) itself
    (TaskKind.HOLD, TaskKind.TAKEOFF): Meet.BUSY,
    (TaskKind.HOLD, TaskKind.LAND): Meet.SUPERSEDE,
    (TaskKind.HOLD, TaskKind.HOLD): Meet.SUPERSEDE,
    (TaskKind.HOLD, TaskKind.ABORT): Meet.SUPERSEDE,
    (TaskKind.ABORT, TaskKind.TAKEOFF): Meet.BUSY,  # never undo an ABORT implicitly
    (TaskKind.ABORT, TaskKind.LAND): Meet.SUPERSEDE,
    (TaskKind.ABORT, TaskKind.HOLD): Meet.SUPERSEDE,  # explicit, as after the ABORT confirms
    (TaskKind.ABORT, TaskKind.ABORT): Meet.SUPERSEDE,
}


# The kinds a request's ``not_after`` stops from starting late (docs/dataplane.md, "Validity
# at the vehicle"). A TAKEOFF started after its validity is the flight the operator was
# told can no longer happen. LAND, HOLD and ABORT stop the vehicle: the member accepted
# them, so the operator counts on them, and run late they still only stop it (a later
# TAKEOFF waits behind them, in order); refused, the drone would fly on unstopped.
EXPIRES: Final = frozenset({TaskKind.TAKEOFF})


@dataclass(frozen=True, slots=True)
class VehicleRequest:
    """One task for the vehicle, tagged with the caller's ``token``: the tag its
    ``TaskFinished`` carries back, unique among the caller's tasks."""

    token: int
    kind: TaskKind
    alt_m: float | None = None  # TAKEOFF only: metres above home; None: MIS_TAKEOFF_ALT
    # what the token stands for, for logs and tests (the swarm: the commander and its
    # command id); the vehicle never reads it
    origin: tuple[str, int] | None = None
    # the command's validity end on the core's clock (the member's judgement when it
    # decided); None: no validity (a direct request). A kind in ``EXPIRES`` reaching the
    # core at or after it is refused ``expired_before_start`` (docs/dataplane.md,
    # "Validity at the vehicle")
    not_after: float | None = None


@dataclass(frozen=True, slots=True)
class ReadinessChanged:
    verdict: Readiness


@dataclass(frozen=True, slots=True)
class TaskFinished:
    """A request's end. ``outcome`` is the take-off's, the action's, or None for an ABORT
    that had nothing to do; ``reason`` the stable code an outcome line carries."""

    token: int
    ok: bool
    reason: str
    outcome: TakeoffOutcome | ActionFinished | None


@dataclass(frozen=True, slots=True)
class DisarmUnconfirmed:
    """After a take-off's failure (its ``TaskFinished`` went first): its DISARM repeats
    ended without PX4 accepting the DISARM or a fresh HEARTBEAT reading disarmed, so the
    vehicle may still be armed (``takeoff``, "disarm_unconfirmed"). An amendment of the
    task's end for the operator, never a second end: nothing runs again. Up to the sender's
    budget (2 s with the defaults) after the failure."""

    token: int
    reason: str  # the failure's code, as its TaskFinished said it
    why: str  # how the repeats ended (``DisarmRepeatsEnded.why``)


VehicleEvent = ReadinessChanged | TaskFinished | DisarmUnconfirmed | SequenceEvent | ActionEvent


@dataclass(slots=True)
class _Task:
    token: int
    kind: TaskKind
    runner: TakeoffSequence | VehicleAction
    abort: bool = False  # an ABORT's action: reason = the command's label on success
    superseded_by: TaskKind | None = None  # the later request's kind, for the reason code
    # a take-off this task superseded, directly or through the tasks between, sent ARM:
    # PX4 may arm after the state we hold was sent, so an ABORT superseding this task
    # disarms even when our state says disarmed (``_abort``)
    armed_maybe: bool = False
    reported: bool = False  # its TaskFinished is out (a failed take-off may still run)


class VehicleCore:
    """See the module docstring. Never raises on autopilot input."""

    def __init__(
        self,
        *,
        readiness_config: ReadinessConfig | None = None,
        takeoff_config: TakeoffConfig | None = None,
    ) -> None:
        self.readiness_config = readiness_config or ReadinessConfig()
        self.takeoff_config = takeoff_config or TakeoffConfig()
        self.takeoff_config.check()
        self.state = VehicleState()
        # answers ended commands still owe, one table for all the vehicle's tasks: a debt
        # outlives its task (the failed take-off's DISARM owes the next ARM's number)
        self.owed = OwedAcks(self.takeoff_config.command.owed_window_s)
        self.last_takeoff: TakeoffSequence | None = None
        # when the last ARM (a take-off's, retransmissions too) went on the wire: until a
        # HEARTBEAT received an ack timeout later, the vehicle may be armed whatever we hold
        self.last_arm_at: float | None = None
        # failed take-offs whose DISARM repeats ended with the vehicle maybe still armed on
        # the ground (takeoff, "disarm_unconfirmed"): ``swarmctl status`` px4
        self.disarm_unconfirmed = 0
        self._tasks: list[_Task] = []
        self._last_key: tuple[bool, str | None] | None = None
        self._stale_at: float | None = None
        self._out: list[VehicleCommand] = []
        self._events: deque[VehicleEvent] = deque()

    # ---- inputs -------------------------------------------------------------------------

    def receive_datagram(self, data: Observation, source: object, now: float) -> None:
        """One observation from the backend (``source`` is unused: one vehicle per core)."""
        self.state.observe(data, now)
        if isinstance(data, CommandAck):
            # paid here too, so an earlier command's answer arriving while no task runs
            # settles its debt; the tasks' senders see this same verdict (OwedAcks.pay)
            self.owed.pay(data, now)
        for task in list(self._tasks):
            task.runner.observe(data, now)
        self._settle(now)

    def handle_timer(self, now: float) -> None:
        for task in list(self._tasks):
            task.runner.handle_timer(now)
        self._settle(now)

    def request(self, request: VehicleRequest, now: float) -> None:
        """Start the task ``request`` names; its end is a ``TaskFinished`` event. A task
        running meets it by ``RULES``: refused ``busy``, or superseded by it."""
        if request.kind in EXPIRES and request.not_after is not None and now >= request.not_after:
            self._refuse_expired(request, now)
            return
        running = self._tasks[0] if self._tasks else None  # at most one (module docstring)
        armed_maybe = False
        if running is not None:
            # a failed take-off repeating its DISARM (takeoff, module docstring) is over for
            # the operator: any request, a new take-off too, stops the repeats and runs
            tail = isinstance(running.runner, TakeoffSequence) and running.runner.disarming
            if RULES[(running.kind, request.kind)] is Meet.BUSY and not tail:
                self._refuse_busy(request, running)
                return
            runner = running.runner
            # inherited along a chain of supersedes (TAKEOFF, then LAND, then ABORT): the
            # take-off's ARM may still take effect after the LAND superseded it
            armed_maybe = running.armed_maybe or (
                isinstance(runner, TakeoffSequence) and runner.arm_sent
            )
            self._supersede(running, request, now)
        match request.kind:
            case TaskKind.TAKEOFF:
                seq = TakeoffSequence(
                    self.state,
                    request.alt_m,
                    config=self.takeoff_config,
                    readiness_config=self.readiness_config,
                    owed=self.owed,
                    not_after=request.not_after,  # bounds every ARM and NAV_TAKEOFF too
                )
                self.last_takeoff = seq
                self._run(_Task(request.token, TaskKind.TAKEOFF, seq), now)
            case TaskKind.LAND:
                self._action(request, ActionKind.LAND, now, armed_maybe=armed_maybe)
            case TaskKind.HOLD:
                self._action(request, ActionKind.HOLD, now, armed_maybe=armed_maybe)
            case TaskKind.ABORT:
                self._abort(request, armed_maybe, now)
            case _:
                assert_never(request.kind)

    def takeoff(self, token: int, alt_m: float | None, now: float) -> None:
        """Arm and take off to ``alt_m`` above home (None: PX4's MIS_TAKEOFF_ALT)."""
        self.request(VehicleRequest(token, TaskKind.TAKEOFF, alt_m), now)

    def land(self, token: int, now: float) -> None:
        self.request(VehicleRequest(token, TaskKind.LAND), now)

    def hold(self, token: int, now: float) -> None:
        self.request(VehicleRequest(token, TaskKind.HOLD), now)

    def abort(self, token: int, now: float) -> None:
        """Stop what runs; then land in the air, disarm on the ground, or nothing."""
        self.request(VehicleRequest(token, TaskKind.ABORT), now)

    def cancel(self, token: int, now: float, why: str) -> None:
        """End the task of ``token`` (a take-off disarms if it armed); unknown: nothing."""
        for task in list(self._tasks):
            if task.token == token:
                task.runner.cancel(now, why)
        self._settle(now)

    def cancel_all(self, now: float, why: str) -> None:
        """The driver is closing: end every task (a take-off disarms if it armed)."""
        for task in list(self._tasks):
            task.runner.cancel(now, why)
        self._settle(now)

    # ---- outputs ------------------------------------------------------------------------

    def datagrams_to_send(self) -> list[VehicleCommand]:
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float | None:
        deadlines = [t.runner.get_timer() for t in self._tasks]
        deadlines.append(self._stale_at)
        return min((d for d in deadlines if d is not None), default=None)

    def next_event(self) -> VehicleEvent | None:
        return self._events.popleft() if self._events else None

    # ---- queries ------------------------------------------------------------------------

    def readiness(self, now: float) -> Readiness:
        return readiness(self.state, now, self.readiness_config)

    def busy(self) -> bool:
        return bool(self._tasks)

    # ---- internals ----------------------------------------------------------------------

    def _abort(self, request: VehicleRequest, armed_maybe: bool, now: float) -> None:
        # ``armed_maybe``: the take-off it superseded sent ARM, which PX4 may carry out after
        # the state we hold was sent; a DISARM sent after it arrives after it (one link, in
        # order), where before the take-off's own DISARM covered this. Also through the tasks
        # between (TAKEOFF, then LAND or HOLD or ABORT, then this ABORT: review 15, which found
        # it ``on_ground_disarmed`` with nothing sent and the vehicle arming a moment later)
        landed = self.state.landed_state
        if self.last_arm_at is not None:
            # the same rule as an action's confirmation (actions, "fresh"): a HEARTBEAT
            # older than the ARM plus a round trip may predate the ARM taking effect
            since = self.last_arm_at + self.takeoff_config.command.ack_timeout_s
            armed_maybe = armed_maybe or not fresh(self.state.heartbeat_at, since)
        # a state older than the heartbeat timeout says nothing of now (PX4 rebooted, the
        # link fell silent): land, as in the air, rather than report "on the ground" unseen
        recent = self.state.heard_within(now, self.readiness_config.heartbeat_timeout_s)
        if not recent or landed not in (None, LandedState.ON_GROUND):
            self._action(request, ActionKind.LAND, now, abort=True, armed_maybe=armed_maybe)
        elif self.state.armed or armed_maybe:
            self._action(request, ActionKind.DISARM, now, abort=True, armed_maybe=armed_maybe)
        else:
            self._events.append(TaskFinished(request.token, True, ON_GROUND_DISARMED, None))

    def _refuse_busy(self, request: VehicleRequest, running: _Task) -> None:
        why = f"a {running.kind} is running (token {running.token:#x})"
        outcome: TakeoffOutcome | ActionFinished | None = None
        if request.kind is TaskKind.TAKEOFF:
            outcome = TakeoffFailed(FailReason.BUSY, None, why, 0.0)
        self._events.append(TaskFinished(request.token, False, str(FailReason.BUSY), outcome))

    def _refuse_expired(self, request: VehicleRequest, now: float) -> None:
        """The request came after its command's validity end (held for a state write): no
        frame, and its end says so, for the operator (docs/dataplane.md, "Validity at the
        vehicle"). The last check before PX4: every request reaches the vehicle here."""
        assert request.not_after is not None  # noqa: S101 - the caller checked it
        why = f"{now - request.not_after:.3f} s after its validity end"
        reason = FailReason.EXPIRED_BEFORE_START
        outcome = TakeoffFailed(reason, None, why, 0.0)
        self._events.append(TaskFinished(request.token, False, str(reason), outcome))

    def _supersede(self, task: _Task, by: VehicleRequest, now: float) -> None:
        """End ``task`` for ``by``: its TaskFinished first, and nothing of it on the wire."""
        origin = "" if by.origin is None else f", {by.origin[0]} command {by.origin[1]:#x}"
        runner = task.runner
        if not (isinstance(runner, TakeoffSequence) and runner.disarming):
            task.superseded_by = by.kind  # else the take-off's failure stands as its outcome
        why = f"superseded by {by.kind.upper()} (token {by.token:#x}{origin})"
        # a failed take-off's DISARM repeats stopped by a request that does not disarm the
        # vehicle itself leave it maybe armed: said (``DisarmUnconfirmed``); an ABORT does
        if isinstance(runner, TakeoffSequence):
            runner.supersede(now, why, disarms=by.kind is TaskKind.ABORT)
        else:
            runner.supersede(now, why)
        self._settle(now)

    def _action(
        self,
        request: VehicleRequest,
        kind: ActionKind,
        now: float,
        *,
        abort: bool = False,
        armed_maybe: bool = False,
    ) -> None:
        action = VehicleAction(
            self.state,
            kind,
            sender=self.takeoff_config.command,
            owed=self.owed,
            state_max_age_s=self.readiness_config.heartbeat_timeout_s,
        )
        self._run(_Task(request.token, request.kind, action, abort, armed_maybe=armed_maybe), now)

    def _run(self, task: _Task, now: float) -> None:
        assert not self._tasks, "one task at a time (RULES)"  # noqa: S101 - an invariant
        self._tasks.append(task)
        task.runner.start(now)
        self._settle(now)

    def _settle(self, now: float) -> None:
        """Collect the tasks' commands and events, retire finished tasks, re-judge readiness."""
        for task in list(self._tasks):
            runner = task.runner
            sent = runner.commands_to_send()
            if any(_is_arm(c) for c in sent):
                self.last_arm_at = now
            self._out += sent
            while (event := runner.next_event()) is not None:
                self._events.append(event)
            if runner.outcome is not None and not task.reported:
                # reported at its outcome: a failed take-off then still repeats its DISARM
                # (takeoff, module docstring), the task kept until ``done``
                task.reported = True
                if _disarm_refused(task):
                    # PX4 refuses a plain DISARM in the air: our "on the ground" was older
                    # than a lift-off (an ABORT at the moment a superseded take-off's motors
                    # lifted it). Land instead, under the same token: the ABORT still stops
                    # the vehicle, where before it FAILED and PX4 climbed on to the take-off
                    # altitude (review 15). Never a forced disarm (module docstring).
                    self._tasks.remove(task)
                    again = VehicleRequest(task.token, task.kind)
                    self._action(again, ActionKind.LAND, now, abort=True)
                    continue
                self._events.append(_finished(task))
            if runner.done:
                self._tasks.remove(task)
                if isinstance(runner, TakeoffSequence) and runner.disarm_unconfirmed:
                    self.disarm_unconfirmed += 1
                    # the operator is told, not only the counter (docs/px4.md, "A failed
                    # take-off's DISARM"): the failure's code again, with the amendment
                    reason = _finished(task).reason
                    why = runner.disarm_why or ""
                    self._events.append(DisarmUnconfirmed(task.token, reason, why))
        verdict = readiness(self.state, now, self.readiness_config)
        key = (verdict.ready, None if verdict.reason is None else str(verdict.reason))
        if key != self._last_key:
            self._last_key = key
            self._events.append(ReadinessChanged(verdict))
        # when readiness changes by time alone (the heartbeat going stale); a past deadline
        # has already been judged, and would spin the timer
        deadline = self.state.next_deadline(self.readiness_config)
        self._stale_at = deadline if deadline is not None and deadline > now else None


def _is_arm(command: VehicleCommand) -> bool:
    return command.command == MavCmd.COMPONENT_ARM_DISARM and command.params[0] == 1.0


def _disarm_refused(task: _Task) -> bool:
    """An ABORT's DISARM that PX4 answered with a refusal (a MAV_RESULT), not superseded,
    cancelled, unanswered or unconfirmed: then the ABORT lands (``_settle``)."""
    runner = task.runner
    if not task.abort or task.superseded_by is not None or isinstance(runner, TakeoffSequence):
        return False
    out = runner.outcome
    return (
        runner.kind is ActionKind.DISARM
        and out is not None
        and not out.ok
        and out.reason in MavResult.__members__
    )


def _finished(task: _Task) -> TaskFinished:
    runner = task.runner
    if task.superseded_by is not None:
        # one code for both runners, the later request's kind after it (docs/px4.md)
        return TaskFinished(
            task.token, False, f"{SUPERSEDED}: {task.superseded_by}", runner.outcome
        )
    if isinstance(runner, TakeoffSequence):
        out = runner.outcome
        assert out is not None  # noqa: S101 - done means an outcome
        if isinstance(out, TakeoffSucceeded):
            return TaskFinished(task.token, True, out.landed_state, out)
        cause = f": {out.cause}" if out.cause else ""
        return TaskFinished(task.token, False, f"{out.reason}{cause}", out)
    action = runner.outcome
    assert action is not None  # noqa: S101 - done means an outcome
    if action.ok:
        reason = action_command(runner.kind).label if task.abort else ""
        return TaskFinished(task.token, True, reason, action)
    return TaskFinished(task.token, False, action.reason, action)
