"""A member's side of the swarm core: accept a command, prove it valid, run it, answer it,
and re-report after a restart.

Each (commander, command id) runs once (the data plane hands each pair once per life,
persisted across restarts; ``execute`` also refuses a pair it already runs, for the
commander's own drone, which bypasses the data plane). The vehicle's tasks are tagged with
the member's own task number (``VehicleRequest.token``), never with a command id: ids are
unique per commander only, and two commanders of one epoch make the same ones
(docs/dataplane.md, "Exactly once" 4), so no command is ever refused because of another's
id. A command from the commander that reaches it after its
validity (``swarmd.dataplane.validity.judge``: dated on this node's own clock from the
readiness report the commander echoes in it) is REJECTED ``expired`` and never runs
(docs/dataplane.md, "Validity"). One whose echo dates another life of this node (a report
of another boot epoch, ``validity.another_life``: checked first, its stamp is on a clock
that may have started again), or that it cannot prove, by the same echo on its own clock,
was issued after this life began (``start``), is REJECTED ``memory_lost``: an earlier life
may have run it, and its record of executed ids (the state file) may be lost
(``validity.issued_in_life``; docs/dataplane.md, "A life runs only its own commands").
Without a vehicle every command is REJECTED ``px4_disabled``. TAKEOFF is refused at once
(REJECTED, reason = the readiness code) when the vehicle is not ready *now* (the
commander's view is up to one report old), else ACCEPTED at once (the commander's latency
measure) and sent to the vehicle; LAND, HOLD and ABORT are ACCEPTED and sent, always. Each
request carries the command's validity end on our clock (``VehicleRequest.not_after``): it
may wait for the state write, and the vehicle refuses a TAKEOFF reaching it after that,
``expired_before_start`` (REJECTED; docs/dataplane.md, "Validity at the vehicle"). The
vehicle's ``TaskFinished`` becomes COMPLETED (reason: the landed state after a take-off,
the command's label after an ABORT) or FAILED (``superseded: land`` for a task a later LAND,
HOLD or ABORT took over: docs/px4.md, "Two requests, one vehicle"; REJECTED for a take-off
refused as not ready, or ``busy`` while another task runs). Dispatch is an exhaustive
``match`` on ``CommandKind`` with ``assert_never``: a new kind fails the type check rather
than running another's action, and a kind number this build does not know is REJECTED
``unknown_kind``.

Every command received is persisted before anything moves (``PersistExecuted``, the
write-ahead: docs/dataplane.md, "Exactly once"), each outcome after it is decided, with
the member's ``DecisionLog`` (``swarmctl outcomes`` in a later life). The daemon answers
each write (``state_saved``): a failed one marks the decision unsaved and does not stop
the command, which the life rules keep from running twice (docs/dataplane.md, "A failed
save"); its commander is told: the decision's outcome goes again, flagged
``OUTCOME_NOT_SAVED``, and so do its later outcomes while it stays unsaved; when a later
write holds it, it goes once more flagged ``OUTCOME_NOW_SAVED`` and the commander clears
its mark. Each carries ``save_gen``, the writes answered so far in this life, so the
commander applies only the newest word (``state_saved``). The state file keeps which
decisions were told unsaved (``DecisionLog.told_unsaved``): a clear that died with its
life is sent by the next, in its re-report (``rereport``).
After a restart the outcomes an earlier life persisted are re-reported, once, to each
commander found within ``REREPORT_WINDOW_S`` of ``start`` (``rereport``; docs/dataplane.md,
"Outcomes across a restart"); they only answer, nothing is executed. A failed take-off's
amendment (its DISARM never confirmed) is kept and written with its outcome, so the
re-report of that FAILED is flagged ``OUTCOME_DISARM_UNCONFIRMED`` again.

Split out of ``core.py`` by concern; ``SwarmCore`` drives it. Sans-IO; no clock.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Callable, Container, Iterable
from dataclasses import dataclass
from typing import Any, Final, NamedTuple, assert_never

from swarmd.dataplane import DataPlane
from swarmd.dataplane.convert import ReadinessVerdict
from swarmd.dataplane.types import (
    OUTCOME_DISARM_UNCONFIRMED,
    OUTCOME_NOT_SAVED,
    OUTCOME_NOW_SAVED,
    Command,
    CommandKind,
    CommandResult,
    PayloadError,
)
from swarmd.dataplane.validity import (
    EXPIRED,
    MEMORY_LOST,
    ReportLog,
    another_life,
    issued_in_life,
    judge,
)
from swarmd.px4.takeoff import FailReason, TakeoffFailed
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished, TaskKind, VehicleRequest
from swarmd.swarm.commander import (
    MAX_DISARM_MARKS,
    MAX_TRACKED_COMMANDS,
    CommandTracker,
    DecisionLog,
    KeptDecision,
)
from swarmd.swarm.events import (
    CommandBeforeLife,
    CommandExecuting,
    CommandExpired,
    OutcomeReported,
    OutcomesReReported,
    PersistExecuted,
    SwarmEvent,
)
from swarmd.swarm.roles import Roles

__all__ = [
    "ID_IN_USE",
    "MAX_REREPORTED",
    "MAX_RUNNING_IDS",
    "MAX_SAVE_GEN",
    "NO_VEHICLE",
    "PX4_DISABLED",
    "REREPORT_WINDOW_S",
    "UNKNOWN_KIND",
    "Member",
    "NoVehicle",
]

PX4_DISABLED: Final = "px4_disabled"
UNKNOWN_KIND: Final = "unknown_kind"
# A reason this build never sends. Until session 14 the vehicle's tasks were tagged with the
# bare command id, so a member refused another commander's command whose id still ran there
# (two commanders in one boot epoch make the same ids: docs/dataplane.md, "Exactly once" 4),
# an ABORT included. Members of that build still send it; a commander shows it as any
# REJECTED reason (docs/operations.md, "id_in_use"), so the name stays.
ID_IN_USE: Final = "id_in_use"
# command ids a member remembers running: the data plane's executed list is the durable
# record; this only guards the commander's own drone, whose commands bypass it
MAX_RUNNING_IDS: Final = 256
# A restarted member re-reports what its earlier life decided (docs/dataplane.md, "Outcomes
# across a restart") to each commander it finds within this long of its start, once per
# commander per life (the reliable writer repairs it from there), at most this many: the
# commander tracks no more commands than that (and the plane bounds it by the outcome
# writer's history depth too). Five minutes covers a daemon restart and a 30 s blackout
# many times over; past it the operator has long acted on what swarmctl said.
REREPORT_WINDOW_S: Final = 300.0
MAX_REREPORTED: Final = MAX_TRACKED_COMMANDS
# ``save_gen`` is a u32 on the wire: the writes answered in one life stop counting there
# (2^32 - 1 writes, 49 days at one a millisecond). After it a mark still marks (the
# commander applies one at or after the last word) and a clear is not newer and is ignored:
# the row stays marked, the alarm side (tests/test_cmd_review15.py pins it).
MAX_SAVE_GEN: Final = 0xFFFF_FFFF


@dataclass(frozen=True, slots=True)
class NoVehicle:
    """The verdict of a node without a vehicle link: never ready, and says why."""

    ready: bool = False
    reason: str = PX4_DISABLED
    armed: bool | None = None
    landed_state: str | None = None
    gps_fix: int | None = None
    satellites: int | None = None
    battery_pct: int | None = None


NO_VEHICLE: Final = NoVehicle()


class _Task(NamedTuple):
    """The command a vehicle task runs, and when this node received it (its clock)."""

    kind: CommandKind
    commander: str
    command_id: int
    started_at: float


class Member:
    """What this node decides for the commands it receives (see the module docstring).

    ``events`` and ``counters`` are the swarm core's; ``tracker`` is the commander's, which
    takes the outcomes of the commands it gave its own drone (``run_own``)."""

    def __init__(
        self,
        roles: Roles,
        plane: DataPlane | None,
        *,
        verdict: Callable[[float], ReadinessVerdict] | None,
        tracker: CommandTracker,
        events: deque[SwarmEvent],
        counters: dict[str, int],
        earlier: Iterable[KeptDecision] = (),
        told_unsaved: Iterable[tuple[str, int]] = (),
        disarm_unconfirmed: Iterable[tuple[str, int]] = (),
    ) -> None:
        """``earlier``: what this node's earlier lives decided, from the state file
        (``received_at`` already on this life's clock); ``told_unsaved``: which of them
        their commanders were told were not saved (``DecisionLog.told_unsaved``);
        ``disarm_unconfirmed``: the failed take-offs whose DISARM an earlier life never saw
        confirmed (the state file's, ``rereport`` flags them)."""
        self.roles = roles
        self.plane = plane
        self.has_vehicle = verdict is not None
        self._vehicle = verdict
        self._tracker = tracker
        self._events = events
        self._counters = counters  # the core's: outcomes_rereported
        # what this member decided, in this life and, as kept, its earlier ones (swarmctl
        # outcomes); a life is the state file's boot counter, the plane's incarnation
        life = 0 if plane is None else plane.incarnation
        self.decisions = DecisionLog(life, earlier, told_unsaved)
        self.counters: dict[str, int] = {}  # the executor's (``status``)
        # ids of the commands this node's commander gave its own drone: their outcomes go
        # to its tracker, not on the wire; bounded like ``_seen`` (never dropping one still
        # running, whose outcome must not go on the wire)
        self._own: OrderedDict[int, None] = OrderedDict()
        # task token -> the command its task runs, on the vehicle. The token is ours
        # (``_new_token``): ids are unique per commander only
        self._running: OrderedDict[int, _Task] = OrderedDict()
        # task token -> the FAILED take-off it ran, until its DISARM repeats end: their
        # ``DisarmUnconfirmed`` amends that outcome (``disarm_unconfirmed``); bounded like
        # ``_seen`` (the repeats last 2 s, so only a flood of failures evicts one)
        self._failed_takeoffs: OrderedDict[int, tuple[str, int, str]] = OrderedDict()
        # (commander, id) of the failed take-offs whose DISARM was never confirmed, this
        # life's and the earlier lives' (the state file's): kept with the outcome, so a
        # later life's re-report still says the vehicle may be armed; newest
        # ``MAX_DISARM_MARKS``
        self._disarm_marks: OrderedDict[tuple[str, int], None] = OrderedDict()
        for key in disarm_unconfirmed:
            self._keep_disarm_mark(key)
        # task tokens: this life's boot epoch in the high 32 bits, a counter in the low, so
        # a task of an earlier life never answers for one of this life's. The daemon's
        # vehicle core ends with its process (PX4 never sees a token), so only a vehicle
        # core that outlives the swarm core, the tests' played one, can send an earlier
        # life's; ``tests/test_cmd_review14.py`` pins it. Positive, apart from the bridge's
        # own take-offs (negative)
        self._token_base = (0 if plane is None else plane.epoch) << 32
        self._tasks_started = 0
        # (commander, id) started (bounded): ids are unique per commander only
        self._seen: OrderedDict[tuple[str, int], None] = OrderedDict()
        # when this life began (``start``): it runs only commands issued after it
        self._life_start: float | None = None
        # the stamps of our own recent reports: an echo must be one (validity.ReportLog)
        self.reports = ReportLog()
        # re-reporting an earlier life's outcomes: until when, and to which commanders done
        self._rereport_until: float | None = None
        self._rereported: set[str] = set()  # bounded: bundle names only
        # commanders found before this life's start (the daemon replays what discovery
        # found while it was starting): re-reported at the start; bounded: bundle names
        self._rereport_pending: set[str] = set()
        # state-file writes answered (``state_saved``) in this life: orders what the
        # commander is told of a decision's record (``save_gen`` on the wire)
        self._save_gen = 0

    def start(self, now: float) -> None:
        """This life began: it runs only commands issued from now, and re-reports (to the
        commanders already found, now)."""
        self._life_start = now
        self._rereport_until = now + REREPORT_WINDOW_S
        pending, self._rereport_pending = sorted(self._rereport_pending), set()
        for commander in pending:
            self.rereport(commander, now)

    def verdict(self, now: float) -> ReadinessVerdict:
        return NO_VEHICLE if self._vehicle is None else self._vehicle(now)

    def received(self, commander: str, command: Command, now: float) -> None:
        """The data plane handed over ``command`` (its first copy here)."""
        # write-ahead: a crash loses the command, never repeats it
        self._persist(commander, command.command_id)
        self.execute(commander, command, now)

    def run_own(self, command: Command, now: float) -> None:
        """The commander's own drone is a target of ``command``: run it here at issue."""
        self._own[command.command_id] = None
        me = self.roles.me
        running = {t.command_id for t in self._running.values() if t.commander == me}
        for old in [i for i in self._own if i not in running][:-MAX_RUNNING_IDS]:
            del self._own[old]
        self.execute(self.roles.me, command, now)

    def task_finished(self, done: TaskFinished, now: float) -> None:
        """The vehicle ended our task ``done.token``."""
        running = self._running.pop(done.token, None)
        if running is None:
            return  # not ours (a direct take-off through the bridge), or reported already
        kind, commander, command_id, _ = running
        if done.ok:
            result = CommandResult.COMPLETED
        elif isinstance(done.outcome, TakeoffFailed) and (
            done.outcome.reason
            in (FailReason.NOT_READY, FailReason.BUSY, FailReason.EXPIRED_BEFORE_START)
        ):
            # refused before anything was sent: not ready, another task runs (the
            # vehicle's RULES: a take-off never interrupts a LAND, HOLD or ABORT), or it
            # reached the vehicle after its validity end (held for the state write)
            result = CommandResult.REJECTED
        else:
            result = CommandResult.FAILED
            if kind == CommandKind.TAKEOFF:
                self._failed_takeoffs[done.token] = (commander, command_id, done.reason)
                while len(self._failed_takeoffs) > MAX_RUNNING_IDS:
                    self._failed_takeoffs.popitem(last=False)
        self._report(command_id, kind.name, result, done.reason, now, commander)

    def disarm_unconfirmed(self, event: DisarmUnconfirmed, now: float) -> None:
        """A take-off of ours failed and its DISARM was never confirmed: the vehicle may
        still be armed. Its commander is told, on the failure's outcome again (FAILED, the
        same reason) flagged ``OUTCOME_DISARM_UNCONFIRMED``: an amendment the commander
        marks on the row and swarmctl prints, never a second execution (docs/px4.md, "A
        failed take-off's DISARM"). A confirmed DISARM sends nothing."""
        failed = self._failed_takeoffs.pop(event.token, None)
        if failed is None:
            return  # not ours (a direct take-off through the bridge), or evicted
        commander, command_id, reason = failed
        self._count("takeoff_disarm_unconfirmed")
        kind = CommandKind.TAKEOFF.name
        result = CommandResult.FAILED
        if commander == self.roles.me and command_id in self._own:
            told = OutcomeReported(command_id, kind, result, reason, disarm_unconfirmed=True)
            self._events.append(told)
            self._tracker.record(
                command_id, commander, result, reason, now, disarm_unconfirmed=True
            )
            return
        # marked first, so this answer and every later one for it carry the flag
        # (``_flags``); kept with the outcome, written as the outcome is (a write after the
        # answer, not ahead of anything): a later life re-reports the amendment too
        self._keep_disarm_mark((commander, command_id))
        if self._answer(commander, command_id, kind, result, reason, now):
            self._persist(commander, command_id)

    @property
    def disarm_marks(self) -> Container[tuple[str, int]]:
        """(commander, id) of the failed take-offs whose DISARM was never confirmed, this
        life's and the earlier lives' kept (``swarmctl outcomes`` on the drone marks them)."""
        return self._disarm_marks.keys()

    def _keep_disarm_mark(self, key: tuple[str, int]) -> None:
        self._disarm_marks[key] = None
        self._disarm_marks.move_to_end(key)
        while len(self._disarm_marks) > MAX_DISARM_MARKS:
            self._disarm_marks.popitem(last=False)

    def status(self, now: float | None = None) -> dict[str, Any]:
        """``executor`` in ``swarmctl status --json``: how many tasks run, and which
        commands they run (``commands``, oldest first; ``age_s`` since received, None
        without ``now``), so a drone's own status names what it does now (session 17)."""
        return {
            "running": len(self._running),
            "commands": [
                {
                    "command_id": t.command_id,
                    "kind": t.kind.name.lower(),
                    "commander": t.commander,
                    "age_s": None if now is None else round(now - t.started_at, 3),
                    "saved": (t.commander, t.command_id) not in self.decisions.unsaved,
                }
                for t in self._running.values()
            ],
            "counters": dict(sorted(self.counters.items())),
        }

    def execute(self, commander: str, command: Command, now: float) -> None:
        """Decide what the vehicle does with ``command`` (see the module docstring)."""
        try:
            kind = CommandKind(command.kind)
        except ValueError:
            self._count("received_unknown")
            self._report(
                command.command_id,
                str(command.kind),
                CommandResult.REJECTED,
                UNKNOWN_KIND,
                now,
                commander,
            )
            return
        key = (commander, command.command_id)
        if key in self._seen:
            return  # exactly once: this id runs already, or ran
        self._seen[key] = None
        while len(self._seen) > MAX_RUNNING_IDS:
            self._seen.popitem(last=False)
        self._count(f"received_{kind.name.lower()}")
        if commander != self.roles.me and not self._may_run(commander, command, kind, now):
            return  # our own drone runs its commands at issue
        takeoff = kind == CommandKind.TAKEOFF
        self._events.append(
            CommandExecuting(
                commander, command.command_id, kind, command.altitude_m if takeoff else None
            )
        )
        if not self.has_vehicle:
            self._report(
                command.command_id, kind.name, CommandResult.REJECTED, PX4_DISABLED, now, commander
            )
            return
        match kind:
            case CommandKind.TAKEOFF:
                verdict = self.verdict(now)
                if not verdict.ready:
                    reason = str(verdict.reason)
                    self._report(
                        command.command_id,
                        kind.name,
                        CommandResult.REJECTED,
                        reason,
                        now,
                        commander,
                    )
                    return
                task = TaskKind.TAKEOFF
            case CommandKind.LAND:
                task = TaskKind.LAND
            case CommandKind.HOLD:
                task = TaskKind.HOLD
            case CommandKind.ABORT:
                task = TaskKind.ABORT
            case _:
                assert_never(kind)
        self._report(command.command_id, kind.name, CommandResult.ACCEPTED, "", now, commander)
        # our own tag, not the id: another commander's command with the same id may run
        # here too, and an ABORT or a LAND must never wait for, or be refused by, it
        token = self._new_token()
        self._running[token] = _Task(kind, commander, command.command_id, now)
        alt = float(command.altitude_m) if takeoff else None
        origin = (commander, command.command_id)
        not_after = self._not_after(commander, command, now)
        self._events.append(VehicleRequest(token, task, alt, origin, not_after))

    def _not_after(self, commander: str, command: Command, now: float) -> float | None:
        """The command's validity end on our clock, for the vehicle to check again when the
        request actually reaches it (it may wait for the state write: docs/dataplane.md,
        "Validity at the vehicle"). Our own drone's command is issued ``now``; another
        commander's is dated by its echo (``judge``, valid here: ``_may_run`` passed).
        None: no validity to keep (``valid_ms`` 0, only our own drone's can be)."""
        if command.valid_ms == 0:
            return None
        if commander == self.roles.me:
            return now + command.valid_ms / 1000.0
        return now + judge(command, self.roles.me, now).remaining_ms / 1000.0

    def _new_token(self) -> int:
        """A tag for a vehicle task, unique in this life (``_token_base``); 2^32 − 1 tasks
        before the counter comes round, none of them still running by then."""
        self._tasks_started = self._tasks_started % 0xFFFF_FFFF + 1
        return self._token_base | self._tasks_started

    def _may_run(self, commander: str, command: Command, kind: CommandKind, now: float) -> bool:
        """Whether a command from another node may run now, else refuse it (REJECTED) for
        good: its id is already persisted as executed, so no later copy can run it either
        (docs/dataplane.md, "Validity" and "A life runs only its own commands")."""
        # First the life the echo dates: a report of another boot epoch of ours is on a
        # clock that may have started again (an OS reboot), so neither its lateness nor its
        # issue can be read on ours; it was issued to that life, which may have run it.
        plane = self.plane
        other = (
            "no data plane" if plane is None else another_life(command, self.roles.me, plane.epoch)
        )
        if other is not None:
            self._count("refused_memory_lost")
            self._events.append(CommandBeforeLife(commander, command.command_id, kind, other))
            self._report(
                command.command_id, kind.name, CommandResult.REJECTED, MEMORY_LOST, now, commander
            )
            return False
        judgement = judge(command, self.roles.me, now)
        if not judgement.valid:  # too late, or undatable
            self._count("refused_expired")
            event: CommandExpired | CommandBeforeLife = CommandExpired(
                commander, command.command_id, kind, judgement.detail
            )
            reason = EXPIRED
        else:
            # issued before this life began (or not started: nothing proves it): this life
            # cannot know whether an earlier one ran it, its record may be lost
            start = self._life_start
            life = None if start is None else issued_in_life(command, self.roles.me, start, now)
            if life is not None and life.valid:
                # read modulo 2^32 as valid and of this life: is the echo a report we sent
                # within the span any runnable command's can be (validity.ReportLog)?
                unknown = self.reports.unknown(command, self.roles.me, now)
                if unknown is None:
                    return True
                self._count("refused_expired")
                self._events.append(CommandExpired(commander, command.command_id, kind, unknown))
                self._report(
                    command.command_id, kind.name, CommandResult.REJECTED, EXPIRED, now, commander
                )
                return False
            self._count("refused_memory_lost")
            detail = "not started" if life is None else life.detail
            event = CommandBeforeLife(commander, command.command_id, kind, detail)
            reason = MEMORY_LOST
        self._events.append(event)
        self._report(command.command_id, kind.name, CommandResult.REJECTED, reason, now, commander)
        return False

    def _report(
        self,
        command_id: int,
        kind: str,
        result: CommandResult,
        reason: str,
        now: float,
        commander: str,
    ) -> None:
        self._count(f"outcome_{result.name.lower()}")
        if commander == self.roles.me and command_id in self._own:
            self._events.append(OutcomeReported(command_id, kind, result, reason))
            self._tracker.record(command_id, self.roles.me, result, reason, now)
            return
        self.decisions.decided(commander, command_id, kind, result, reason, now)
        if self._answer(commander, command_id, kind, result, reason, now):
            # the second write: the outcome next to its id, for a re-report after a restart
            self._persist(commander, command_id)

    def _answer(
        self,
        commander: str,
        command_id: int,
        kind: str,
        result: CommandResult,
        reason: str,
        now: float,
        flags: int = 0,
    ) -> bool:
        """Send ``commander`` this outcome, with ``flags`` (``_tell``'s save word) and the
        flags ``_flags`` adds; False without a plane. A decision whose record a write
        already failed to keep says so in each outcome; a save word carries ``save_gen``."""
        saved = (commander, command_id) not in self.decisions.unsaved
        flags = self._flags(commander, command_id, result, flags)
        armed = bool(flags & OUTCOME_DISARM_UNCONFIRMED)
        told = OutcomeReported(command_id, kind, result, reason, saved, disarm_unconfirmed=armed)
        self._events.append(told)
        if self.plane is None:
            return False
        if not saved:
            flags |= OUTCOME_NOT_SAVED
        gen = self._save_gen if flags & (OUTCOME_NOT_SAVED | OUTCOME_NOW_SAVED) else 0
        self.plane.report_outcome(
            command_id, result, now, reason, commander=commander, flags=flags, save_gen=gen
        )
        return True

    def _flags(self, commander: str, command_id: int, result: CommandResult, flags: int) -> int:
        """``flags`` and ``OUTCOME_DISARM_UNCONFIRMED`` on a FAILED this drone marks (its
        DISARM never confirmed, ``_disarm_marks``): the one place that decides it, so every
        outcome sent for that failure says so (the amendment, a "not saved" or "saved after
        all" word, a later life's re-report), and no later line tells the operator
        ``disarm_unconfirmed: false`` (docs/operations.md, the mark)."""
        if result == CommandResult.FAILED and (commander, command_id) in self._disarm_marks:
            flags |= OUTCOME_DISARM_UNCONFIRMED
        return flags

    def _persist(self, commander: str, command_id: int) -> None:
        assert self.plane is not None  # noqa: S101 - callers checked it
        plane = self.plane
        self._events.append(
            PersistExecuted(
                tuple(plane.executed_command_ids),
                tuple(plane.executed_outcomes),
                self.decisions.kept(),
                (commander, command_id),
                tuple(sorted(self.decisions.told_unsaved)),
                tuple(self._disarm_marks),
            )
        )

    def state_saved(self, command: tuple[str, int] | None, error: str | None, now: float) -> None:
        """The daemon wrote a ``PersistExecuted`` (``error`` None) or failed to. A failed
        write does not stop the command: no sequence of restarts, resends or replays can
        run it a second time without the record, and refusing a LAND or an ABORT on a full
        disk would leave a drone in the air (docs/dataplane.md, "A failed save"). What it
        loses is the answer across a restart, so the decision is marked unsaved for
        ``swarmctl outcomes`` (``saved: false``) until a later write holds it, and its
        commander is told (``_tell``): unsaved at the failure, saved again at the next
        write that succeeds (every write holds the whole record). Each word carries the
        count of writes answered so far in this life (``save_gen``): the commander applies
        one only if it is newer than the last it applied, so an older mark replayed,
        repeated or overtaken never sets it again after the clear."""
        self._save_gen = min(self._save_gen + 1, MAX_SAVE_GEN)
        if error is None:
            for key in self.decisions.saved():
                self._tell(*key, now, OUTCOME_NOW_SAVED)
            return
        self._count("state_save_failed")
        if command is not None and self.decisions.save_failed(*command):
            self._tell(*command, now, OUTCOME_NOT_SAVED)

    def _tell(self, commander: str, command_id: int, now: float, flag: int) -> None:
        """Send ``commander`` the decision's outcome again, flagged ``flag``:
        ``OUTCOME_NOT_SAVED`` (a write that should have held it failed) or
        ``OUTCOME_NOW_SAVED`` (a later write held it), with ``save_gen``.

        The outcome went before the write's result was known (ACCEPTED at once is the
        commander's latency measure), so the word comes after it, on the same result: the
        commander's dedup keys it by its flags and generation too, and its row keeps what
        it had and sets or clears the mark (``save_failed``). Once per decision that turns
        unsaved, and once when it is saved again: a write that fails again finds it
        unsaved already; after a successful write, a new failure is told again. Nothing
        is decided, persisted or run."""
        current = self.decisions.current(commander, command_id)
        if current is None or self.plane is None or commander == self.roles.me:
            return  # evicted, no plane, or our own drone's (never written)
        kind, state, reason = current
        saved = flag == OUTCOME_NOW_SAVED
        self._count("told_saved" if saved else "told_not_saved")
        if not saved:
            self.decisions.told(commander, command_id)  # kept in the file: ``rereport``
        # ``_answer``: the decision is unsaved (the word's ``saved``) exactly when ``flag``
        # is ``OUTCOME_NOT_SAVED``, and a marked failure's word carries the mark (``_flags``)
        self._answer(
            commander, command_id, kind.upper(), CommandResult[state.upper()], reason, now, flag
        )

    def rereport(self, commander: str, now: float) -> None:
        """``commander`` was found: if this is a new life (restarted with its state file)
        within ``REREPORT_WINDOW_S`` of its start, send it, once, the outcomes its earlier
        lives decided for its commands, on the outcome writer it already authenticates.
        Only an answer: nothing is executed (docs/dataplane.md, "Outcomes across a
        restart").

        A decision whose commander an earlier life told it was not saved, held here with
        its final answer (``DecisionLog.clear_owed``), goes flagged ``OUTCOME_NOW_SAVED``:
        that life's clear may have died with it (sent after the write that held the
        decision, on a writer that lives in memory), and the commander's mark would stay
        for good. Its ``save_gen`` is at least 1: ``statefile.boot`` wrote the file this
        life loaded before anything was sent, this life's first write, and a later life's
        word is newer than any of an earlier life at the commander (``_mark``: by epoch)."""
        if self.plane is None or commander in self._rereported:
            return
        if self._rereport_until is None:
            # found before this life started: under load the daemon's replay of discovery
            # came first and the re-report was lost (a CI run); sent at ``start``
            self._rereport_pending.add(commander)
            return
        if now > self._rereport_until:
            return
        earlier = self.plane.earlier_outcomes(commander, MAX_REREPORTED)
        if not earlier:
            return
        self._rereported.add(commander)
        ids: list[int] = []
        for _, command_id, result, reason in earlier:
            clear = result != CommandResult.ACCEPTED.value and self.decisions.clear_owed(
                commander, command_id
            )
            flags, gen = (OUTCOME_NOW_SAVED, max(self._save_gen, 1)) if clear else (0, 0)
            try:
                # an earlier life's amendment (``_flags``): its DISARM was never confirmed,
                # and the commander (restarted, or the amendment lost with that life) must
                # hear it
                outcome = CommandResult(result)
                self.plane.report_outcome(
                    command_id,
                    outcome,
                    now,
                    reason,
                    commander=commander,
                    flags=self._flags(commander, command_id, outcome, flags),
                    save_gen=gen,
                )
            except (ValueError, PayloadError):  # a state file edited by hand: skip it
                self._count("rereport_invalid")
                continue
            if clear:
                self._count("told_saved")
            ids.append(command_id)
        self._counters["outcomes_rereported"] += len(ids)
        self._events.append(OutcomesReReported(commander, tuple(ids)))

    def _count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1
