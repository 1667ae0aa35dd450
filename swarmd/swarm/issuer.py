"""The commander's side of the swarm core: validate a request, issue the command, track
its outcomes, and withdraw it when its validity ends.

A request names a kind, its targets (``only``), an altitude for a take-off and a validity
(``valid_for_s``, per-kind defaults: ``DEFAULT_VALID_FOR_S``); a bad one raises
``RequestInvalid``. The command is made and dated by the data plane (``make_command`` with
each target's time echo), sent once with one copy per member, and tracked
(``CommandTracker``). When its validity ends the commander withdraws it from the writer
(never retransmitted after), and the tracker calls the targets that did not answer
``unreachable``; until then a target lost by discovery and found again in the same boot
epoch is handed the command by the data plane, and one found in a new epoch (it
restarted) is not, and is ``unreachable`` at once (reason ``restarted_before_acknowledging``,
docs/dataplane.md "Rejoining while a command is valid"). The commander's own drone runs
its commands at issue (``Member.run_own``).

Split out of ``core.py`` by concern; ``SwarmCore`` drives it. Sans-IO; no clock.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, Final

from swarmd.dataplane import CommandIdsExhausted, DataPlane
from swarmd.dataplane.types import (
    MAX_VALID_MS,
    OUTCOME_DISARM_UNCONFIRMED,
    OUTCOME_NOT_SAVED,
    OUTCOME_NOW_SAVED,
    CommandKind,
    CommandOutcome,
)
from swarmd.dataplane.validity import valid_ms_of
from swarmd.dataplane.writer import MAX_HISTORY_DEPTH
from swarmd.px4.takeoff import MAX_TAKEOFF_ALT_M
from swarmd.swarm.commander import RESTARTED, CommandTracker, ReadinessTable
from swarmd.swarm.events import (
    CommandIssued,
    CommandLifeEnded,
    CommandNotDelivered,
    CommandWithdrawn,
    OutcomeRecorded,
    SentBy,
    SwarmEvent,
)
from swarmd.swarm.member import Member
from swarmd.swarm.roles import Roles
from swarmd.tokenbucket import TokenBucket

__all__ = [
    "COMMAND_KINDS",
    "DEFAULT_VALID_FOR_S",
    "MAX_PENDING_WITHDRAWALS",
    "MAX_VALID_FOR_S",
    "UNKNOWN_OUTCOME_REPORTS_PER_S",
    "UNKNOWN_OUTCOME_REPORT_BURST",
    "Issuer",
    "RequestInvalid",
]

COMMAND_KINDS: Final = {k.name.lower(): k for k in CommandKind}
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
DEFAULT_VALID_FOR_S: Final = {
    CommandKind.TAKEOFF: 3.0,
    CommandKind.HOLD: 5.0,
    CommandKind.LAND: 10.0,
    CommandKind.ABORT: 10.0,
}
# Commands awaiting their withdrawal. A writer keeps at most MAX_HISTORY_DEPTH samples, so
# past that many the oldest are gone from it anyway; the cap stops a script hammering the
# control socket with long validities from growing the heap (the earliest is withdrawn now:
# it only stops retransmitting sooner, members still judge its validity themselves).
MAX_PENDING_WITHDRAWALS: Final = MAX_HISTORY_DEPTH
# Outcomes for commands this commander never sent (to that member), reported (and so logged)
# at most this often; the rest are counted. Honest ones are rare (a member re-reporting what
# an earlier life decided for an earlier commander life); a captured member can invent them
# as fast as it writes (docs/security-history.md, "Network paths end to end").
UNKNOWN_OUTCOME_REPORTS_PER_S: Final = 1.0
UNKNOWN_OUTCOME_REPORT_BURST: Final = 10.0


class RequestInvalid(ValueError):
    """A request the commander refuses (bad argument, wrong node); ``str()`` is for the
    client. The daemon's control socket answers it as ``ok: false``."""


class Issuer:
    """The commander's commands: issued, tracked, withdrawn (see the module docstring).

    ``table`` (readiness), ``events`` and ``counters`` are the swarm core's, ``tracker`` is
    shared with ``member``, which runs the commands this node gives its own drone and
    records their outcomes in it."""

    def __init__(
        self,
        roles: Roles,
        plane: DataPlane | None,
        *,
        table: ReadinessTable,
        tracker: CommandTracker,
        member: Member,
        takeoff_alt_m: float,
        events: deque[SwarmEvent],
        counters: dict[str, int],
    ) -> None:
        self.roles = roles
        self.plane = plane
        self.tracker = tracker
        self._table = table
        self._member = member
        self._takeoff_alt_m = takeoff_alt_m
        self._events = events
        self._counters = counters  # the core's: unknown_outcomes_suppressed
        self._unknown_outcome_reports = TokenBucket(
            UNKNOWN_OUTCOME_REPORTS_PER_S, UNKNOWN_OUTCOME_REPORT_BURST, 0.0
        )
        # (commander clock when the validity ends, command id, writer SN): the commander
        # withdraws each from its writer then, so repair never carries it late
        self.expiries: list[tuple[float, int, int]] = []

    def next_expiry(self) -> float | None:
        return self.expiries[0][0] if self.expiries else None

    # ---- the requests -------------------------------------------------------------------

    def request_takeoff(
        self, request: Mapping[str, Any], now: float, sent_by: SentBy | None
    ) -> dict[str, Any]:
        """``SwarmCore.request_takeoff``."""
        plane = self._require_commander()
        alt = self._altitude(request)
        targets = self._targets(request.get("only"))
        ready, refused = self._table.split(targets, now)
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
        self, request: Mapping[str, Any], now: float, sent_by: SentBy | None
    ) -> dict[str, Any]:
        """``SwarmCore.request_command``."""
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

    # ---- what the data plane reports ----------------------------------------------------

    def withdraw_expired(self, now: float) -> None:
        """The commander stops retransmitting commands whose validity ended."""
        while self.expiries and self.expiries[0][0] <= now:
            _, command_id, sn = heapq.heappop(self.expiries)
            if self.plane is not None and self.plane.withdraw_command(sn):
                self._events.append(CommandWithdrawn(command_id))

    def outcome_received(self, node: str, outcome: CommandOutcome, epoch: int, now: float) -> None:
        not_saved = bool(outcome.flags & OUTCOME_NOT_SAVED)  # the other bits: reserved
        armed = bool(outcome.flags & OUTCOME_DISARM_UNCONFIRMED)
        known = self.tracker.record(
            outcome.command_id,
            node,
            outcome.result,
            outcome.reason,
            now,
            epoch=epoch,
            not_saved=not_saved,
            now_saved=bool(outcome.flags & OUTCOME_NOW_SAVED),
            save_gen=outcome.save_gen,
            disarm_unconfirmed=armed,
        )
        if not known and not self._unknown_outcome_reports.take(now):
            # an answer to no command we sent: counted by the tracker, reported at a
            # bounded rate (a captured member inventing them: a log line each)
            self._counters["unknown_outcomes_suppressed"] += 1
            return
        self._events.append(
            OutcomeRecorded(
                node,
                outcome.command_id,
                outcome.result,
                outcome.reason,
                known,
                not not_saved,
                disarm_unconfirmed=armed,
            )
        )

    def member_seen(self, member: str, epoch: int, now: float) -> None:
        """Discovery authenticated ``member`` in boot ``epoch``: the rows an earlier life of
        it accepted and never finished will not finish (``CommandTracker.member_restarted``)."""
        for command_id in self.tracker.member_restarted(member, epoch, now):
            self._events.append(CommandLifeEnded(member, command_id))

    def copy_voided(self, member: str, command_id: int, now: float) -> None:
        # its copy is dated on the earlier life's clock: never handed over
        self.tracker.not_delivered(command_id, member, RESTARTED, now)
        self._events.append(CommandNotDelivered(member, command_id, RESTARTED))

    # ---- internals ----------------------------------------------------------------------

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
        known = self._table.names if self._table.names else list(self.roles.targets_remote)
        everyone = list(dict.fromkeys([*known, *self.roles.targets_remote]))
        if self._member.has_vehicle and self.roles.me not in everyone:
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
            return self._takeoff_alt_m
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
            heapq.heappush(self.expiries, expiry)
            while len(self.expiries) > MAX_PENDING_WITHDRAWALS:
                _, early_id, early_sn = heapq.heappop(self.expiries)
                if plane.withdraw_command(early_sn):
                    self._events.append(CommandWithdrawn(early_id))
        if self.roles.me in targets:
            self._member.run_own(command, now)
        return command.command_id
