"""The swarm as a sans-IO core: readiness reports, commands, and a member's execution decisions.

Theory of operation
-------------------
One ``SwarmCore`` per daemon, around the node's ``DataPlane`` (None when the data plane is
disabled). Driving sources, the driver's protocol (``swarmd.driver``):

- ``receive_datagram(data, source, now)``: user data for the data plane; its events move
  the readiness table (commander), the command tracker (commander) and execution (member);
- ``handle_timer(now)``: the data plane's repairs, and the readiness tick: a node that
  reports readiness publishes ``swarm/ready`` every ``readiness_period_s`` (1 Hz, the
  paper's workload, section 5) and at once when its vehicle's verdict changes
  (``vehicle_changed``), so a lost autopilot link reaches the commander within PX4's 2.5 s
  heartbeat timeout rather than up to a period later;
- the commander's validity timers: when a command's validity ends, ``handle_timer``
  withdraws it from the writer (never retransmitted after), and the tracker calls the
  targets that did not answer ``unreachable``; until then a target lost by discovery and
  found again in the same boot epoch is handed the command by the data plane, and one
  found in a new epoch (it restarted) is not, and is ``unreachable`` at once (reason
  ``restarted_before_acknowledging``, docs/dataplane.md "Rejoining while a command is valid");
- calls: ``start``, ``peer_up``/``peer_down`` (discovery), ``vehicle_changed`` and
  ``task_finished`` (the vehicle core), and the commander's requests (``request_takeoff``,
  ``request_command``, ``request_outcomes``; ``RequestInvalid`` on a bad one).

Outputs: ``datagrams_to_send()``, ``get_timer()``, ``next_event()``. Two events are orders
for the driver, in this order for each command: ``PersistExecuted`` (write the state file
before anything moves: a crash then loses a command, never repeats it; docs/dataplane.md,
"Exactly once") and ``px4.vehicle.VehicleRequest`` (what the vehicle should do, tagged with
the command id). Each outcome a member decides is followed by another ``PersistExecuted``
carrying it next to its id. The others are for the log.

After a restart (docs/dataplane.md, "Outcomes across a restart"): the outcomes an earlier
life persisted are re-reported, once, to each commander discovery finds within
``REREPORT_WINDOW_S`` of ``start`` (``_rereport``); they only answer, nothing is executed.
The commander's tracker tells such an answer by the member's boot epoch, higher than the
one the command was sent to, and marks the row ``after_restart``.

A member's decisions (``_execute``): each command id once (the data plane hands each id
once per life, persisted across restarts; the core also refuses an id it already runs, for
the commander's own drone, which bypasses the data plane). A command from the commander
that reaches it after its validity (``swarmd.dataplane.validity.judge``: dated on this
node's own clock from the readiness report the commander echoes in it) is REJECTED
``expired`` and never runs (docs/dataplane.md, "Validity"). One whose echo dates another
life of this node (a report of another boot epoch, ``validity.another_life``: checked
first, its stamp is on a clock that may have started again), or that it cannot prove, by
the same echo on its own clock, was issued after this life began (``start``), is REJECTED
``memory_lost``: an earlier life may have run it, and its record of executed ids (the state
file) may be lost (``validity.issued_in_life``; docs/dataplane.md, "A life runs only its
own commands"). Without a vehicle every command
is REJECTED ``px4_disabled``. TAKEOFF is refused at once (REJECTED, reason = the readiness
code) when the vehicle is not ready *now* (the commander's view is up to one report old),
else ACCEPTED at once (the commander's latency measure) and sent to the vehicle; LAND, HOLD
and ABORT are ACCEPTED and sent. The vehicle's ``TaskFinished`` becomes COMPLETED (reason:
the landed state after a take-off, the command's label after an ABORT) or FAILED (REJECTED
for a take-off refused as not ready). Dispatch is an exhaustive ``match`` on ``CommandKind``
with ``assert_never``: a new kind fails the type check rather than running another's action,
and a kind number this build does not know is REJECTED ``unknown_kind``.

Time is the ``now`` argument; the vehicle's verdict and the link quality are read through
the injected ``verdict(now)`` (None: the node has no vehicle link) and ``link_q()``. No
I/O, no clock, no asyncio.
"""

from __future__ import annotations

import heapq
import math
from collections import OrderedDict, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, assert_never

from swarmd.dataplane import (
    TOPIC_READY,
    CommandCopyVoided,
    CommandIdsExhausted,
    CommandReceived,
    DataPlane,
    OutcomeReceived,
    PacketDropped,
    ReadinessReceived,
)
from swarmd.dataplane.convert import ReadinessVerdict, readiness_sample
from swarmd.dataplane.types import (
    MAX_VALID_MS,
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
    stamp_ms,
    valid_ms_of,
)
from swarmd.dataplane.writer import MAX_HISTORY_DEPTH
from swarmd.px4.takeoff import MAX_TAKEOFF_ALT_M, FailReason, TakeoffFailed
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleRequest
from swarmd.swarm.commander import (
    MAX_TRACKED_COMMANDS,
    RESTARTED,
    CommandTracker,
    DecisionLog,
    ReadinessTable,
)
from swarmd.swarm.events import (
    CommandBeforeLife,
    CommandExecuting,
    CommandExpired,
    CommandIssued,
    CommandNotDelivered,
    CommandWithdrawn,
    MemberReadinessChanged,
    OutcomeRecorded,
    OutcomeReported,
    OutcomesReReported,
    PeerTrafficVerified,
    PersistExecuted,
    SentBy,
    SwarmEvent,
    UserDataDropped,
)
from swarmd.swarm.roles import Roles, reads
from swarmd.tokenbucket import TokenBucket

__all__ = [
    "SwarmCore",
    "SwarmSettings",
    "RequestInvalid",
    "NoVehicle",
    "NO_VEHICLE",
    "PX4_DISABLED",
    "UNKNOWN_KIND",
    "ID_IN_USE",
    "COMMAND_KINDS",
    "DEFAULT_VALID_FOR_S",
    "MAX_REREPORTED",
    "MAX_RUNNING_IDS",
    "MAX_VALID_FOR_S",
    "MAX_PENDING_WITHDRAWALS",
    "REREPORT_WINDOW_S",
    "UNKNOWN_OUTCOME_REPORTS_PER_S",
    "UNKNOWN_OUTCOME_REPORT_BURST",
]

PX4_DISABLED: Final = "px4_disabled"
UNKNOWN_KIND: Final = "unknown_kind"
# Another commander's command with the same id still runs here (two commanders in the same
# boot epoch make the same ids: docs/dataplane.md, "Exactly once" 4); the vehicle's tasks
# are tagged with the id, so this one is refused and its commander told at once.
ID_IN_USE: Final = "id_in_use"
COMMAND_KINDS: Final = {k.name.lower(): k for k in CommandKind}
# command ids a member remembers running: the data plane's executed list is the durable
# record; this only guards the commander's own drone, whose commands bypass it
MAX_RUNNING_IDS: Final = 256
# The longest validity an operator may give a command (the wire allows MAX_VALID_MS).
MAX_VALID_FOR_S: Final = MAX_VALID_MS / 1000.0
# Default validity per kind (docs/operations.md, "Validity"). TAKEOFF is the dangerous one
# to run late and gets the shortest: 3 s covers the repairs of a 30 %-loss link (all 10
# members within 1.8 s at worst, docs/dataplane.md "Numbers") and equals the commander's
# stale_after_s, so a take-off never outlives the readiness report it was sent on. HOLD
# (freeze where you are) run late would undo whatever the operator ordered since: 5 s.
# LAND and ABORT are the safe direction and may need a worse link to get through: 10 s,
# still short of swarmctl's 20 s wait, so swarmctl outlives the validity and can say
# which drones it did not reach rather than "timeout".
# Commands awaiting their withdrawal. A writer keeps at most MAX_HISTORY_DEPTH samples, so
# past that many the oldest are gone from it anyway; the cap stops a script hammering the
# control socket with long validities from growing the heap (the earliest is withdrawn now:
# it only stops retransmitting sooner, members still judge its validity themselves).
MAX_PENDING_WITHDRAWALS: Final = MAX_HISTORY_DEPTH
# A restarted member re-reports what its earlier life decided (docs/dataplane.md, "Outcomes
# across a restart") to each commander it finds within this long of its start, once per
# commander per life (the reliable writer repairs it from there), at most this many: the
# commander tracks no more commands than that (and the plane bounds it by the outcome
# writer's history depth too). Five minutes covers a daemon restart and a 30 s blackout
# many times over; past it the operator has long acted on what swarmctl said.
REREPORT_WINDOW_S: Final = 300.0
MAX_REREPORTED: Final = MAX_TRACKED_COMMANDS
# Outcomes for commands this commander never sent (to that member), reported (and so logged)
# at most this often; the rest are counted. Honest ones are rare (a member re-reporting what
# an earlier life decided for an earlier commander life); a captured member can invent them
# as fast as it writes (docs/security-history.md, "Network paths end to end").
UNKNOWN_OUTCOME_REPORTS_PER_S: Final = 1.0
UNKNOWN_OUTCOME_REPORT_BURST: Final = 10.0
DEFAULT_VALID_FOR_S: Final = {
    CommandKind.TAKEOFF: 3.0,
    CommandKind.HOLD: 5.0,
    CommandKind.LAND: 10.0,
    CommandKind.ABORT: 10.0,
}


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


class RequestInvalid(ValueError):
    """A request the commander refuses (bad argument, wrong node); ``str()`` is for the
    client. The daemon's control socket answers it as ``ok: false``."""


@dataclass(frozen=True, slots=True)
class SwarmSettings:
    readiness_period_s: float = 1.0
    stale_after_s: float = 3.0
    takeoff_alt_m: float = 10.0  # a take-off request without ``alt_m``


class SwarmCore:
    """See the module docstring."""

    def __init__(
        self,
        roles: Roles,
        plane: DataPlane | None,
        *,
        verdict: Callable[[float], ReadinessVerdict] | None,
        link_q: Callable[[], float],
        settings: SwarmSettings | None = None,
    ) -> None:
        self.roles = roles
        self.plane = plane
        self.has_vehicle = verdict is not None
        self.settings = settings or SwarmSettings()
        self._vehicle = verdict
        self._link_q = link_q
        self.table = ReadinessTable(roles.members, stale_after_s=self.settings.stale_after_s)
        if roles.is_commander and self.has_vehicle:
            self.table.add_local(roles.me)  # the commander's own drone flies with the swarm
        self.tracker = CommandTracker()
        self.decisions = DecisionLog()  # what this member decided (swarmctl outcomes)
        self.counters: dict[str, int] = {
            "readiness_published": 0,
            "outcomes_rereported": 0,
            "unknown_outcomes_suppressed": 0,
        }
        self._unknown_outcome_reports = TokenBucket(
            UNKNOWN_OUTCOME_REPORTS_PER_S, UNKNOWN_OUTCOME_REPORT_BURST, 0.0
        )
        self.executor_counters: dict[str, int] = {}
        self._tick_at: float | None = None
        self._seq = 0
        self._last_key: tuple[bool, str | None] | None = None
        self._readers_up: set[str] = set()  # peers up that read our readiness (peer_up)
        self._local_commands: set[int] = set()
        # (commander clock when the validity ends, command id, writer SN): the commander
        # withdraws each from its writer then, so repair never carries it late
        self._expiries: list[tuple[float, int, int]] = []
        # id -> (kind, commander), on the vehicle
        self._running: OrderedDict[int, tuple[CommandKind, str]] = OrderedDict()
        # (commander, id) started (bounded): ids are unique per commander only
        self._seen: OrderedDict[tuple[str, int], None] = OrderedDict()
        self._events: deque[SwarmEvent] = deque()
        # when this life began (``start``): it runs only commands issued after it
        self._life_start: float | None = None
        # the stamps of our own recent reports: an echo must be one (validity.ReportLog)
        self._reports = ReportLog()
        # re-reporting an earlier life's outcomes: until when, and to which commanders done
        self._rereport_until: float | None = None
        self._rereported: set[str] = set()  # bounded: bundle names only

    # ---- driving protocol ---------------------------------------------------------------

    def start(self, now: float) -> None:
        """Publish the first readiness report now, then every period."""
        self._tick_at = now
        self._life_start = now
        self._rereport_until = now + REREPORT_WINDOW_S

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        if self.plane is None:
            return
        self.plane.receive_datagram(data, source, now)
        self._drain_plane(now)

    def handle_timer(self, now: float) -> None:
        self._withdraw_expired(now)
        if self.plane is not None:
            self.plane.handle_timer(now)
            self._drain_plane(now)
        if self._tick_at is not None and now >= self._tick_at:
            self._tick(now)

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        return [] if self.plane is None else self.plane.datagrams_to_send()

    def get_timer(self) -> float | None:
        deadlines = [
            self._tick_at,
            None if self.plane is None else self.plane.get_timer(),
            self._expiries[0][0] if self._expiries else None,
        ]
        return min((d for d in deadlines if d is not None), default=None)

    def next_event(self) -> SwarmEvent | None:
        return self._events.popleft() if self._events else None

    # ---- discovery ----------------------------------------------------------------------

    def peer_up(self, name: str, locator: tuple[str, int] | None, epoch: int, now: float) -> None:
        """Discovery heard ``name`` (authenticated SPDP) in boot ``epoch``; its user-data
        locator, or None when no address is known (the data plane then keeps it down)."""
        self.table.on_peer(name, True)
        if self.plane is not None and locator is not None:
            self.plane.peer_up(name, locator, now, epoch=epoch)
            self._drain_plane(now)
            self._rereport(name, now)
            came = name not in self._readers_up
            if came and reads(self.plane.bundle.participant(name), TOPIC_READY):
                self._readers_up.add(name)  # bounded: bundle names only (participant())
                if self.roles.reports_readiness and self._tick_at is not None:
                    # A reader of our readiness (the commander) came, or came back after a
                    # loss: it gets our report now, not up to a period later, as a DDS
                    # writer hands a late-joining reader its last sample (DDS 2.2.3.4
                    # DURABILITY TRANSIENT_LOCAL). After a 30 s blackout that period was a
                    # third of the samples lost between the re-discovery and the first
                    # report (issue 20). One extra report per reader per (re)discovery.
                    self._tick_at = min(self._tick_at, now)

    def peer_down(self, name: str, now: float) -> None:
        self.table.on_peer(name, False)
        self._readers_up.discard(name)
        if self.plane is not None:
            self.plane.peer_down(name, now)
            self._drain_plane(now)

    # ---- the vehicle --------------------------------------------------------------------

    def vehicle_changed(self, ready: bool, reason: str | None, now: float) -> None:
        """The vehicle's verdict changed: tell the commander now, not up to a period later."""
        key = (ready, reason)
        if self._last_key is not None and key != self._last_key and self._tick_at is not None:
            self._tick(now)
        self._last_key = key

    def task_finished(self, done: TaskFinished, now: float) -> None:
        """The vehicle ended the task of command ``done.token``."""
        running = self._running.pop(done.token, None)
        if running is None:
            return  # not ours (a direct take-off through the bridge), or reported already
        kind, commander = running
        if done.ok:
            result = CommandResult.COMPLETED
        elif isinstance(done.outcome, TakeoffFailed) and (
            done.outcome.reason == FailReason.NOT_READY
        ):
            result = CommandResult.REJECTED
        else:
            result = CommandResult.FAILED
        self._report(done.token, kind.name, result, done.reason, now, commander)

    # ---- the commander's requests -------------------------------------------------------

    def request_takeoff(
        self, request: Mapping[str, Any], now: float, *, sent_by: SentBy | None = None
    ) -> dict[str, Any]:
        """Take-off of the targeted nodes that are ready now; ``require_all``: all or none.
        ``sent_by``: who asked (kept with the command, and in ``CommandIssued``)."""
        plane = self._require_commander()
        alt = self._altitude(request)
        targets = self._targets(request.get("only"))
        ready, refused = self.table.split(targets, now)
        valid_for = self._valid_for(request, CommandKind.TAKEOFF)
        if refused and request.get("require_all"):
            return {"sent": False, "command_id": None, "ready": ready, "refused": refused}
        if not ready:
            return {"sent": False, "command_id": None, "ready": [], "refused": refused}
        command_id = self._send(
            plane, CommandKind.TAKEOFF, ready, alt, refused, valid_for, now, sent_by
        )
        return {
            "sent": True,
            "command_id": command_id,
            "ready": ready,
            "refused": refused,
            "valid_for_s": valid_for,
        }

    def request_command(
        self, request: Mapping[str, Any], now: float, *, sent_by: SentBy | None = None
    ) -> dict[str, Any]:
        """Any command to the targets as they are: members judge for themselves."""
        plane = self._require_commander()
        kind = COMMAND_KINDS.get(str(request.get("kind", "")).lower())
        if kind is None:
            raise RequestInvalid(f"kind must be one of: {', '.join(COMMAND_KINDS)}")
        alt = self._altitude(request) if kind == CommandKind.TAKEOFF else 0.0
        targets = self._targets(request.get("only"))
        valid_for = self._valid_for(request, kind)
        command_id = self._send(plane, kind, targets, alt, {}, valid_for, now, sent_by)
        return {
            "sent": True,
            "command_id": command_id,
            "ready": targets,
            "refused": {},
            "valid_for_s": valid_for,
        }

    def request_outcomes(self, request: Mapping[str, Any], now: float) -> dict[str, Any]:
        """One command's snapshot by ``command_id``; without one, every command this daemon
        keeps: ``issued`` (the commander's, newest first) and ``ran`` (what this drone
        decided for the commands it received, newest first): ``swarmctl outcomes``
        (docs/operations.md, "What became of each command")."""
        if "command_id" not in request:
            return {
                "role": self.roles.role,
                "issued": self.tracker.recent(now, limit=MAX_TRACKED_COMMANDS)[::-1],
                "issued_evicted": self.tracker.evicted,
                "ran": self.decisions.recent(now),
                "ran_evicted": self.decisions.evicted,
            }
        command_id = request.get("command_id")
        if not isinstance(command_id, int) or isinstance(command_id, bool):
            raise RequestInvalid('"command_id" must be an integer')
        snap = self.tracker.snapshot(command_id, now)
        if snap is None:
            raise RequestInvalid(f"unknown command id {command_id}")
        return snap

    # ---- status (pure: evaluated when asked) --------------------------------------------

    def executor_status(self) -> dict[str, Any]:
        return {
            "running": len(self._running),
            "counters": dict(sorted(self.executor_counters.items())),
        }

    # ---- internals: data plane ----------------------------------------------------------

    def _withdraw_expired(self, now: float) -> None:
        """The commander stops retransmitting commands whose validity ended."""
        while self._expiries and self._expiries[0][0] <= now:
            _, command_id, sn = heapq.heappop(self._expiries)
            if self.plane is not None and self.plane.withdraw_command(sn):
                self._events.append(CommandWithdrawn(command_id))

    def _drain_plane(self, now: float) -> None:
        assert self.plane is not None  # noqa: S101 - callers checked it
        while (event := self.plane.next_event()) is not None:
            match event:
                case ReadinessReceived(node=node, sample=sample, count=count):
                    self._events.append(PeerTrafficVerified(node))
                    before = self.table.verdict(node, now)
                    self.table.on_report(node, sample, count, now)
                    after = self.table.verdict(node, now)
                    if before != after:
                        self._events.append(MemberReadinessChanged(node, after[0], after[1]))
                case CommandReceived(commander=commander, command=command):
                    self._events.append(PeerTrafficVerified(commander))
                    # write-ahead: a crash loses the command, never repeats it
                    self._persist()
                    self._execute(commander, command, now)
                case OutcomeReceived(node=node, outcome=outcome, epoch=epoch):
                    self._events.append(PeerTrafficVerified(node))
                    known = self.tracker.record(
                        outcome.command_id, node, outcome.result, outcome.reason, now, epoch=epoch
                    )
                    if not known and not self._unknown_outcome_reports.take(now):
                        # an answer to no command we sent: counted by the tracker, reported
                        # at a bounded rate (a captured member inventing them: a log line each)
                        self.counters["unknown_outcomes_suppressed"] += 1
                        continue
                    self._events.append(
                        OutcomeRecorded(
                            node, outcome.command_id, outcome.result, outcome.reason, known
                        )
                    )
                case CommandCopyVoided(member=member, command_id=command_id):
                    # its copy is dated on the earlier life's clock: never handed over
                    self.tracker.not_delivered(command_id, member, RESTARTED, now)
                    self._events.append(CommandNotDelivered(member, command_id, RESTARTED))
                case PacketDropped(reason=reason, source=source, detail=detail):
                    self._events.append(UserDataDropped(reason, source, detail))
                case _:
                    assert_never(event)

    def _tick(self, now: float) -> None:
        self._tick_at = now + self.settings.readiness_period_s
        if not (self.roles.reports_readiness or self.table.names):
            return
        self._seq += 1
        sample = readiness_sample(
            self.roles.me, self._seq, self._verdict(now), self._link_q(), stamp_ms(now)
        )
        if self.roles.reports_readiness and self.plane is not None:
            self.plane.publish_readiness(sample, now)
            self._reports.sent(sample.stamp_ms, now)
            self.counters["readiness_published"] += 1
        if self.roles.me in self.table.names:
            self.table.on_report(self.roles.me, sample, None, now)

    # ---- internals: a member's execution ------------------------------------------------

    def _execute(self, commander: str, command: Command, now: float) -> None:
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
                verdict = self._verdict(now)
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
        if command.command_id in self._running:  # another commander's, same id: its tag
            self._report(
                command.command_id, kind.name, CommandResult.REJECTED, ID_IN_USE, now, commander
            )
            return
        self._report(command.command_id, kind.name, CommandResult.ACCEPTED, "", now, commander)
        self._running[command.command_id] = (kind, commander)
        alt = float(command.altitude_m) if takeoff else None
        self._events.append(VehicleRequest(command.command_id, task, alt))

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
                unknown = self._reports.unknown(command, self.roles.me, now)
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
        self._events.append(OutcomeReported(command_id, kind, result, reason))
        if commander == self.roles.me and command_id in self._local_commands:
            self.tracker.record(command_id, self.roles.me, result, reason, now)
            return
        self.decisions.decided(commander, command_id, kind, result, reason, now)
        if self.plane is not None:
            self.plane.report_outcome(command_id, result, now, reason, commander=commander)
            # the second write: the outcome next to its id, for a re-report after a restart
            self._persist()

    def _persist(self) -> None:
        assert self.plane is not None  # noqa: S101 - callers checked it
        plane = self.plane
        self._events.append(
            PersistExecuted(tuple(plane.executed_command_ids), tuple(plane.executed_outcomes))
        )

    def _rereport(self, commander: str, now: float) -> None:
        """``commander`` was found: if this is a new life (restarted with its state file)
        within ``REREPORT_WINDOW_S`` of its start, send it, once, the outcomes its earlier
        lives decided for its commands, on the outcome writer it already authenticates.
        Only an answer: nothing is executed (docs/dataplane.md, "Outcomes across a
        restart")."""
        if (
            self.plane is None
            or self._rereport_until is None
            or now > self._rereport_until
            or commander in self._rereported
        ):
            return
        earlier = self.plane.earlier_outcomes(commander, MAX_REREPORTED)
        if not earlier:
            return
        self._rereported.add(commander)
        ids: list[int] = []
        for _, command_id, result, reason in earlier:
            try:
                self.plane.report_outcome(
                    command_id, CommandResult(result), now, reason, commander=commander
                )
            except (ValueError, PayloadError):  # a state file edited by hand: skip it
                self._count("rereport_invalid")
                continue
            ids.append(command_id)
        self.counters["outcomes_rereported"] += len(ids)
        self._events.append(OutcomesReReported(commander, tuple(ids)))

    def _verdict(self, now: float) -> ReadinessVerdict:
        return NO_VEHICLE if self._vehicle is None else self._vehicle(now)

    def _count(self, name: str) -> None:
        self.executor_counters[name] = self.executor_counters.get(name, 0) + 1

    # ---- internals: the commander -------------------------------------------------------

    def _require_commander(self) -> DataPlane:
        if not self.roles.is_commander:
            raise RequestInvalid(
                f"{self.roles.me} is not a commander in swarm {self.roles.swarm!r}; "
                "run swarmctl on the commander's drone"
            )
        if self.plane is None:
            raise RequestInvalid("the data plane is disabled (dataplane.enabled: false)")
        return self.plane

    def _targets(self, only: object) -> list[str]:
        known = self.table.names if self.table.names else list(self.roles.targets_remote)
        everyone = list(dict.fromkeys([*known, *self.roles.targets_remote]))
        if self.has_vehicle and self.roles.me not in everyone:
            everyone.insert(0, self.roles.me)
        if only is None or only == []:
            return everyone
        if not isinstance(only, list) or not all(isinstance(n, str) for n in only):
            raise RequestInvalid('"only" must be a list of node names')
        unknown = [n for n in only if n not in everyone]
        if unknown:
            raise RequestInvalid(
                f"not a commandable node: {', '.join(unknown)}; known: {', '.join(everyone)}"
            )
        return list(dict.fromkeys(only))

    def _altitude(self, request: Mapping[str, Any]) -> float:
        alt = request.get("alt_m")
        if alt is None:
            return self.settings.takeoff_alt_m
        if isinstance(alt, bool) or not isinstance(alt, int | float) or not math.isfinite(alt):
            raise RequestInvalid(f"alt_m {alt!r} is not a number")
        # px4's one take-off ceiling (the wire's MAX_ALTITUDE_M is only a garbage cap)
        if not 0 < alt <= MAX_TAKEOFF_ALT_M:
            raise RequestInvalid(f"alt_m {alt} is outside (0, {MAX_TAKEOFF_ALT_M:g}] m")
        return float(alt)

    def _valid_for(self, request: Mapping[str, Any], kind: CommandKind) -> float:
        value = request.get("valid_for_s")
        if value is None:
            return DEFAULT_VALID_FOR_S[kind]
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise RequestInvalid(f"valid_for_s {value!r} is not a number")
        if not (math.isfinite(value) and 0.001 <= value <= MAX_VALID_FOR_S):
            raise RequestInvalid(f"valid_for_s {value} is outside [0.001, {MAX_VALID_FOR_S:g}] s")
        return float(value)

    def _send(
        self,
        plane: DataPlane,
        kind: CommandKind,
        targets: Sequence[str],
        alt: float,
        refused: dict[str, str],
        valid_for_s: float,
        now: float,
        sent_by: SentBy | None = None,
    ) -> int:
        remote = [n for n in targets if n != self.roles.me]
        valid_ms = valid_ms_of(valid_for_s)
        try:
            command = plane.make_command(
                kind,
                altitude_m=alt,
                targets=remote,
                valid_ms=valid_ms,
                echoes=plane.time_echoes(remote, now),
            )
        except CommandIdsExhausted as exc:  # 2^32 - 1 commands in one life
            raise RequestInvalid(str(exc)) from None
        takeoff_alt = alt if kind == CommandKind.TAKEOFF else None
        epochs = {name: e for name in remote if (e := plane.peer_epoch(name)) is not None}
        self.tracker.sent(
            command.command_id,
            kind.name.lower(),
            targets,
            now,
            altitude_m=takeoff_alt,
            refused=refused,
            valid_for_s=valid_ms / 1000.0,
            epochs=epochs,
            sent_by=sent_by,
        )
        self._events.append(
            CommandIssued(
                command.command_id, kind, takeoff_alt, tuple(targets), dict(refused), sent_by
            )
        )
        if remote:  # an empty target list would mean "every member" on the wire
            sn = plane.send_command(command, now)
            expiry = (now + valid_ms / 1000.0, command.command_id, sn)
            heapq.heappush(self._expiries, expiry)
            while len(self._expiries) > MAX_PENDING_WITHDRAWALS:
                _, early_id, early_sn = heapq.heappop(self._expiries)
                if plane.withdraw_command(early_sn):
                    self._events.append(CommandWithdrawn(early_id))
        if self.roles.me in targets:
            self._local_commands.add(command.command_id)
            self._execute(self.roles.me, command, now)
        return command.command_id
