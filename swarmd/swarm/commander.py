"""The commander's bookkeeping: who is ready for take-off, and what became of each command;
and a member's own: what it decided for each command it received (``DecisionLog``).

Sans-IO like the engines: time is a ``now: float`` argument (the daemon's ``loop.time()``),
nothing here sends or sleeps. The daemon feeds it from the data plane's events
(``ReadinessReceived``, ``OutcomeReceived``) and discovery's (``PeerDiscovered``/``PeerLost``);
the control socket reads it (``swarmctl status``, ``swarmctl takeoff``).

A member's *effective* readiness is stricter than what it last said: a member the commander
never heard from, whose SPDP lease ran out, or whose last 1 Hz report is older than
``stale_after_s`` is not ready, whatever its last report said. The order of those reasons is
the order an operator checks things in: is it there at all, is it still there, is it quiet,
and only then what the drone itself says.

``count`` per member is the paper's success measure (section 5: "the 20th 1 Hz message
received from every publisher"); its name and meaning are stable for the benchmarks.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Container, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, NamedTuple

from swarmd.changereports import ChangeReports
from swarmd.dataplane.convert import LANDED_STATES
from swarmd.dataplane.types import CommandResult, Readiness
from swarmd.dataplane.validity import MEMORY_LOST
from swarmd.px4.actions import SUPERSEDED
from swarmd.px4.command_sender import SenderConfig
from swarmd.swarm.events import SentBy

# Commands whose outcomes the commander keeps for swarmctl; an operator issues a handful per
# flight, the cap only stops a runaway script from growing the daemon.
MAX_TRACKED_COMMANDS: Final = 64
# Commands a member keeps its own decision for, for ``swarmctl outcomes`` on the drone. The
# same handful per flight; the cap stops a captured commander's flood of fresh ids from
# growing the list (the data plane's executed set, the durable record, has its own cap).
MAX_DECIDED_COMMANDS: Final = MAX_TRACKED_COMMANDS
# Failed take-offs whose DISARM was never confirmed that a member keeps marked, in memory and
# in its state file (``disarm_unconfirmed``), so a later life's re-report still says the
# vehicle may be armed (docs/dataplane.md, "Outcomes across a restart"). A re-report carries
# at most this many outcomes per commander (``member.MAX_REREPORTED``); the cap stops a run
# of failures (a captured commander's take-offs on a lossy PX4 link) from growing the list.
MAX_DISARM_MARKS: Final = MAX_TRACKED_COMMANDS
LANDED_STATE_NAMES: Final = {v: k for k, v in LANDED_STATES.items()}

# After a command's validity ends, how long the commander still waits for a target's first
# answer before calling it unreachable. A member decides within the validity (its deadline
# is never later than the commander's, docs/dataplane.md "Validity"), but its ACCEPTED may
# still be in flight or under repair (0.2 s, then x1.5 per lost heartbeat): 2 s covers four
# repairs. An answer arriving later still replaces the row (the truth wins). A row made
# unreachable earlier, because the member restarted (RESTARTED), waits as long before it
# counts as settled: the new life's re-report may be under repair just the same.
UNREACHABLE_GRACE_S: Final = 2.0
UNREACHABLE: Final = "unreachable"  # state: no answer while valid; it can no longer start there
NOT_REACHED: Final = "not_reached_while_valid"  # its reason
# Another reason for it, known before the validity ends: the member restarted (a new boot
# epoch) before it acknowledged the command, and its copy, dated on the earlier life's
# clock, is not handed to the new one (docs/dataplane.md, "Rejoining while a command is
# valid"). It may have run before the restart: its readiness rows say what the vehicle did.
RESTARTED: Final = "restarted_before_acknowledging"
# The reason of an ``accepted`` row whose member re-reported, from a later life, that its
# earlier life accepted the command and restarted before the task ended: no completion
# will come (the new life does not run it), and whether the vehicle finished is for its
# readiness rows to say (docs/dataplane.md, "Outcomes across a restart").
RESTARTED_RUNNING: Final = "restarted_before_finishing"
# A FAILED take-off repeats its DISARM for up to the command sender's budget (1 + 3 sends,
# 0.5 s apart: 2 s) and, when it never shows, its member amends the row
# (``OUTCOME_DISARM_UNCONFIRMED``: the vehicle may still be armed). The row counts as
# settled only this long after the failure, so ``swarmctl takeoff`` is still following when
# the amendment comes (1 s more for its transit or repair behind the failure's answer).
# A superseded take-off sends no DISARM: settled at once.
DISARM_WINDOW_S: Final = SenderConfig().budget_s() + 1.0

# Effective-readiness reasons the commander adds to the members' own codes (docs/operations.md)
NO_REPORT: Final = "no_report"  # nothing received from this member yet
PEER_LOST: Final = "peer_lost"  # discovery lost the member (lease expired or it left)
REPORT_STALE: Final = "report_stale"  # reports stopped for longer than stale_after_s
NOT_A_MEMBER: Final = "not_a_member"  # --only named a node that does not report readiness


# A member's readiness changes are logged (``member_readiness``). A captured member writes
# genuine samples as fast as it likes, each flipping the verdict: a log line per sample at
# the commander (review 16, the twin of the outcome flood). At most this many reported a
# second per member (an honest one changes a few times a flight), the rest counted.
READINESS_REPORTS_PER_S: Final = 1.0
READINESS_REPORT_BURST: Final = 10.0

Verdict = tuple[bool, str | None]  # (ready, reason), ``ReadinessTable.verdict``


class ReadinessReports(ChangeReports[str, Verdict]):
    """Which of each member's readiness changes are reported (logged): every one within
    ``READINESS_REPORTS_PER_S`` (burst ``READINESS_REPORT_BURST``), the rest counted
    (``suppressed``). A member whose change was held back is reported again by ``catch_up``
    (the readiness tick) once the budget allows, so the log ends on the table's word.
    One bucket per member the table tracks (bundle-bounded); ``swarmd.changereports``."""

    def __init__(self) -> None:
        super().__init__(READINESS_REPORTS_PER_S, READINESS_REPORT_BURST)

    def held(self) -> list[str]:
        """Members whose latest change was held back (``catch_up`` them)."""
        return sorted(self._held)


@dataclass(slots=True)
class _Member:
    name: str
    local: bool = False  # the commander's own vehicle, fed from its own PX4 bridge
    count: int = 0
    sample: Readiness | None = None
    last_rx: float | None = None
    changed_at: float | None = None  # when (ready, reason) of the reports last changed
    peer_up: bool = False


class ReadinessTable:
    """Per member: its last readiness report, how many arrived, and the effective verdict."""

    def __init__(self, members: Iterable[str], *, stale_after_s: float) -> None:
        self.stale_after_s = stale_after_s
        self._members: dict[str, _Member] = {name: _Member(name) for name in members}

    @property
    def names(self) -> list[str]:
        return list(self._members)

    def add_local(self, name: str) -> None:
        """Track the commander's own vehicle too (it flies with the swarm)."""
        self._members[name] = _Member(name, local=True, peer_up=True)

    def on_report(self, name: str, sample: Readiness, count: int | None, now: float) -> None:
        """A report arrived (``count``: the data plane's tally; None: count here)."""
        member = self._members.get(name)
        if member is None:
            return  # a bundle participant that writes swarm/ready but is not tracked
        previous = member.sample
        if previous is None or (previous.ready, previous.reason) != (sample.ready, sample.reason):
            member.changed_at = now
        member.sample = sample
        member.count = member.count + 1 if count is None else count
        member.last_rx = now
        if member.local:
            member.peer_up = True

    def on_peer(self, name: str, up: bool) -> None:
        member = self._members.get(name)
        if member is not None and not member.local:
            member.peer_up = up

    def verdict(self, name: str, now: float) -> tuple[bool, str | None]:
        """``(ready, reason)`` as the commander sees it now; reason None when ready."""
        member = self._members.get(name)
        if member is None:
            return False, NOT_A_MEMBER
        if member.sample is None or member.last_rx is None:
            return False, NO_REPORT
        if not member.peer_up:
            return False, PEER_LOST
        if now - member.last_rx > self.stale_after_s:
            return False, REPORT_STALE
        if not member.sample.ready:
            return False, member.sample.reason or "not_ready"
        return True, None

    def split(self, targets: Sequence[str], now: float) -> tuple[list[str], dict[str, str]]:
        """``targets`` into (ready, {not ready: reason}), keeping the given order."""
        ready: list[str] = []
        refused: dict[str, str] = {}
        for name in targets:
            ok, reason = self.verdict(name, now)
            if ok:
                ready.append(name)
            else:
                refused[name] = reason or "not_ready"
        return ready, refused

    def rows(self, now: float) -> dict[str, dict[str, Any]]:
        """The JSON table of ``swarmctl status`` (schema: docs/operations.md)."""
        out: dict[str, dict[str, Any]] = {}
        for name, m in self._members.items():
            ready, reason = self.verdict(name, now)
            s = m.sample
            out[name] = {
                "ready": ready,
                "reason": reason,
                "count": m.count,
                "seq": None if s is None else s.seq,
                "age_s": None if m.last_rx is None else round(now - m.last_rx, 3),
                "since_s": None if m.changed_at is None else round(now - m.changed_at, 3),
                "local": m.local,
                "peer_up": m.peer_up,
                "reported_ready": None if s is None else s.ready,
                "armed": None if s is None else s.armed,
                "landed_state": None
                if s is None
                else LANDED_STATE_NAMES.get(s.landed_state, str(s.landed_state)),
                "gps_fix": None if s is None else s.gps_fix,
                "battery_pct": None if s is None or s.battery_pct < 0 else s.battery_pct,
                "link_q": None if s is None else round(s.link_q_permille / 1000, 3),
            }
        return out


@dataclass(slots=True)
class _NodeOutcome:
    accepted_at: float | None = None
    result: CommandResult | None = None  # the final one: COMPLETED, REJECTED or FAILED
    reason: str = ""
    final_at: float | None = None
    not_delivered: str | None = None  # why the command can no longer reach it (RESTARTED)
    not_delivered_at: float = 0.0  # since when (the row settles UNREACHABLE_GRACE_S later)
    epoch_at_issue: int | None = None  # its boot epoch as the commander knew it at issue
    # what it says came from a later life than the one the command was sent to: a
    # re-report of what its earlier life decided (nothing more will come for this command)
    after_restart: bool = False
    # it said its record of this decision could not be written (``OUTCOME_NOT_SAVED``): it
    # ran as said, but after a restart it would neither re-report it nor, with the life
    # rules, need it (docs/dataplane.md, "A failed save"); cleared when it says a later
    # write held it (``OUTCOME_NOW_SAVED``)
    save_failed: bool = False
    # (epoch, save_gen) of the last such word applied: only a newer one moves the mark, so
    # an older mark replayed, repeated or overtaken cannot set it again after a clear
    save_mark: tuple[int, int] = (0, 0)
    # when the commander saw the member in a later boot epoch than the one that accepted
    # the command, with no final answer: that life ended, the new one never runs it
    # (docs/dataplane.md, "Outcomes across a restart"); None while it has not
    life_ended_at: float | None = None
    # its failed take-off's DISARM was never confirmed: the vehicle may still be armed
    # (``OUTCOME_DISARM_UNCONFIRMED``, up to ``DISARM_WINDOW_S`` after the failure)
    disarm_unconfirmed: bool = False


@dataclass(slots=True)
class _Tracked:
    command_id: int
    kind: str
    altitude_m: float | None
    targets: tuple[str, ...]
    refused: dict[str, str]
    sent_at: float
    outcomes: dict[str, _NodeOutcome] = field(default_factory=dict)
    valid_for_s: float | None = None  # None: no validity (a command tracked by hand)
    sent_by: SentBy | None = None  # the control socket client that asked for it


FINAL_RESULTS: Final = (CommandResult.COMPLETED, CommandResult.REJECTED, CommandResult.FAILED)


def _disarm_may_follow(t: _Tracked, o: _NodeOutcome, now: float) -> bool:
    """A FAILED take-off row whose member may still amend it (``DISARM_WINDOW_S``)."""
    return (
        t.kind == "takeoff"
        and o.result == CommandResult.FAILED
        and not o.disarm_unconfirmed
        and not o.reason.startswith(SUPERSEDED)
        and o.final_at is not None
        and now < o.final_at + DISARM_WINDOW_S
    )


class CommandTracker:
    """What each targeted member answered to each command (commander side)."""

    def __init__(self) -> None:
        self._commands: OrderedDict[int, _Tracked] = OrderedDict()
        self.evicted = 0
        self.unknown_outcomes = 0

    def sent(
        self,
        command_id: int,
        kind: str,
        targets: Sequence[str],
        now: float,
        *,
        altitude_m: float | None = None,
        refused: dict[str, str] | None = None,
        valid_for_s: float | None = None,
        epochs: Mapping[str, int] | None = None,
        sent_by: SentBy | None = None,
    ) -> None:
        """``epochs``: each target's boot epoch as the data plane knew it at issue (the
        life the command is sent to), for telling a later life's answer in ``record``.
        ``sent_by``: who asked for it (shown with its outcomes)."""
        known = epochs or {}
        self._commands[command_id] = _Tracked(
            command_id,
            kind,
            altitude_m,
            tuple(targets),
            dict(refused or {}),
            now,
            {name: _NodeOutcome(epoch_at_issue=known.get(name)) for name in targets},
            valid_for_s,
            sent_by,
        )
        while len(self._commands) > MAX_TRACKED_COMMANDS:
            self._commands.popitem(last=False)
            self.evicted += 1

    def record(
        self,
        command_id: int,
        node: str,
        result: CommandResult,
        reason: str,
        now: float,
        *,
        epoch: int | None = None,
        not_saved: bool = False,
        now_saved: bool = False,
        save_gen: int = 0,
        disarm_unconfirmed: bool = False,
    ) -> bool:
        """A member's outcome; False when it answers no command we track (or not to it).
        ``not_saved``: flagged ``OUTCOME_NOT_SAVED`` (sets the row's ``save_failed``);
        ``now_saved``: flagged ``OUTCOME_NOW_SAVED`` (clears it); either only when its
        ``(epoch, save_gen)`` is newer than the last word applied (``_mark``).

        ``epoch``: the boot epoch of the member's life that sent it. Higher than the one
        the command was sent to: a later life re-reporting what the earlier one decided
        (the command never reaches a later life, docs/dataplane.md "Rejoining while a
        command is valid"). It fills only what the row does not know yet, and marks the
        row ``after_restart``; a row with a final result keeps it (a replayed or repeated
        old outcome cannot change it). A later life's ``memory_lost`` (it refused a copy
        it could not date into its own life) fills only a row with no answer yet.

        ``disarm_unconfirmed``: flagged ``OUTCOME_DISARM_UNCONFIRMED``, the amendment of a
        FAILED take-off whose DISARM was not confirmed: marks the row (for good: nothing
        unmarks a vehicle that may be armed but the operator's look at it)."""
        tracked = self._commands.get(command_id)
        if tracked is None or node not in tracked.outcomes:
            self.unknown_outcomes += 1
            return False
        entry = tracked.outcomes[node]
        later = (
            epoch is not None and entry.epoch_at_issue is not None and epoch > entry.epoch_at_issue
        )
        if later and reason == MEMORY_LOST and entry.accepted_at is not None:
            # the later life refused a resend it could not date into its own life: that
            # says nothing of what the earlier life, which accepted it, did
            return True
        if later and entry.result is None:
            entry.after_restart = True
        _mark(entry, epoch, not_saved, now_saved, save_gen)
        if disarm_unconfirmed and result == CommandResult.FAILED:
            entry.disarm_unconfirmed = True
        if result == CommandResult.ACCEPTED:
            if entry.accepted_at is None:
                entry.accepted_at = now
        elif entry.result is None:
            entry.result, entry.reason, entry.final_at = result, reason, now
            if entry.accepted_at is None and result == CommandResult.COMPLETED:
                entry.accepted_at = now  # the ACCEPTED report was overtaken or lost
        return True

    def member_restarted(self, node: str, epoch: int, now: float) -> list[int]:
        """Discovery authenticated ``node`` in boot ``epoch``. Every row of ``node`` that
        was accepted by an earlier life and has no final answer will get none: that life
        ended, and a later one never runs its commands ("Exactly once", "A life runs only
        its own commands"). Such a row says ``restarted_before_finishing`` at once and is
        settled ``UNREACHABLE_GRACE_S`` later (a re-report of what the earlier life kept
        may still be under repair, and fills it). The ids of the rows so marked."""
        marked: list[int] = []
        for t in self._commands.values():
            entry = t.outcomes.get(node)
            if entry is None or entry.epoch_at_issue is None or epoch <= entry.epoch_at_issue:
                continue
            if entry.accepted_at is None or entry.result is not None:
                continue  # not accepted (its copy is voided: ``not_delivered``) or answered
            if entry.life_ended_at is None:
                entry.life_ended_at = now
                marked.append(t.command_id)
        return marked

    def not_delivered(self, command_id: int, node: str, reason: str, now: float) -> bool:
        """The command can no longer reach ``node`` (``reason``); an answer it gave before,
        or gives later, still wins. False when the command or the node is not tracked."""
        tracked = self._commands.get(command_id)
        if tracked is None or node not in tracked.outcomes:
            return False
        entry = tracked.outcomes[node]
        entry.not_delivered, entry.not_delivered_at = reason, now
        return True

    def snapshot(self, command_id: int, now: float) -> dict[str, Any] | None:
        """The JSON view of one command (``swarmctl`` polls it), None if unknown."""
        t = self._commands.get(command_id)
        if t is None:
            return None
        nodes: dict[str, Any] = {}
        lapsed = self._lapsed(t, now)
        settled = True
        for name, o in t.outcomes.items():
            state = "pending" if o.accepted_at is None else "accepted"
            reason = o.reason
            if o.result is not None:
                state = str(o.result.name).lower()
            elif o.accepted_at is not None and o.after_restart:
                reason = RESTARTED_RUNNING  # accepted, then restarted: no final will come
            elif o.accepted_at is not None and o.life_ended_at is not None:
                # accepted, and its life ended with nothing re-reported yet: no final will
                # come from it; settled once a re-report under repair had its grace
                reason = RESTARTED_RUNNING
                if now < o.life_ended_at + UNREACHABLE_GRACE_S:
                    settled = False
            elif o.accepted_at is None and o.not_delivered is not None:
                state, reason = UNREACHABLE, o.not_delivered
                # Said at once, settled only after the grace an answer in flight gets: the
                # restarted member's re-report of what its earlier life did may still be
                # under repair (docs/dataplane.md, "Outcomes across a restart")
                if now < o.not_delivered_at + UNREACHABLE_GRACE_S:
                    settled = False
            elif o.accepted_at is None and lapsed:
                state, reason = UNREACHABLE, NOT_REACHED
            else:
                settled = False
            if _disarm_may_follow(t, o, now):
                settled = False
            nodes[name] = {
                "state": state,
                "reason": reason,
                "latency_s": None if o.accepted_at is None else round(o.accepted_at - t.sent_at, 4),
                "done_s": None if o.final_at is None else round(o.final_at - t.sent_at, 4),
                "after_restart": o.after_restart,
                "save_failed": o.save_failed,
                "disarm_unconfirmed": o.disarm_unconfirmed,
            }
        for name, reason in t.refused.items():
            nodes[name] = {
                "state": "refused",
                "reason": reason,
                "latency_s": None,
                "done_s": None,
                "after_restart": False,
                "save_failed": False,
                "disarm_unconfirmed": False,
            }
        return {
            "command_id": t.command_id,
            "kind": t.kind,
            "altitude_m": t.altitude_m,
            "targets": list(t.targets),
            "age_s": round(now - t.sent_at, 3),
            "valid_for_s": t.valid_for_s,
            # how long the command may still start on a drone that has not answered
            "valid_left_s": None
            if t.valid_for_s is None
            else round(max(0.0, t.sent_at + t.valid_for_s - now), 3),
            "done": settled,
            "sent_by": None if t.sent_by is None else t.sent_by.as_json(),
            "nodes": nodes,
        }

    @staticmethod
    def _lapsed(t: _Tracked, now: float) -> bool:
        """The validity ended, and the grace for answers in flight too."""
        if t.valid_for_s is None:
            return False
        return now >= t.sent_at + t.valid_for_s + UNREACHABLE_GRACE_S

    def recent(self, now: float, limit: int = 8) -> list[dict[str, Any]]:
        ids = list(self._commands)[-limit:]
        return [s for i in ids if (s := self.snapshot(i, now)) is not None]


def _mark(
    entry: _NodeOutcome, epoch: int | None, not_saved: bool, now_saved: bool, save_gen: int
) -> None:
    """The member's word on its record of this decision, applied only if newer than the
    last (``save_mark``): a mark (``not_saved``) at or after it, a clear (``now_saved``)
    strictly after it, with a generation (a session-14 member sends marks at 0 and never
    clears). A member's generations grow within a life, and a later life has a higher
    epoch, so an older mark delivered after a clear (a repeat, a replay the MAC let
    through, a reordered copy) leaves the clear standing (docs/dataplane.md, "A failed
    save"). A word with both bits set counts as a mark: the alarm side."""
    at = (epoch or 0, save_gen)
    if not_saved and at >= entry.save_mark:
        entry.save_failed, entry.save_mark = True, at
    elif now_saved and not not_saved and save_gen > 0 and at > entry.save_mark:
        entry.save_failed, entry.save_mark = False, at


# One decision as the state file keeps it (``statefile``, key ``decisions``): the life
# (the state file's boot counter, ``DataPlane.incarnation``) that decided it, the command,
# what was decided and when. ``received_at`` is on the clock of whoever holds it: the
# core's ``now`` in memory, Unix seconds in the file (the daemon converts both ways,
# ``SwarmApp``: a later life's monotonic clock cannot read an earlier one's);
# ``done_s`` is how long the final answer took, on the deciding life's clock.
class KeptDecision(NamedTuple):
    life: int
    commander: str
    command_id: int
    kind: str
    state: str
    reason: str
    received_at: float
    done_s: float | None


@dataclass(slots=True)
class _Decided:
    command_id: int
    kind: str
    commander: str
    state: str
    reason: str
    received_at: float
    final_at: float | None = None
    life: int = 0
    done_s: float | None = None  # an earlier life's, as kept (its final_at is not on our clock)


class DecisionLog:
    """What this member decided for each command it received (member side): ``swarmctl
    outcomes`` on the drone. This life's decisions and, restored from the state file, its
    earlier lives' (``earlier``, each marked with its ``life``). Bounded
    (``MAX_DECIDED_COMMANDS`` over all lives, oldest out, ``evicted`` counts them); the
    commander's ``CommandTracker`` is the one to ask whether every drone ran a command.

    ``unsaved``: the decisions whose record the daemon failed to write to the state file
    (``save_failed``), until a later write succeeds (``saved``): each write holds the
    whole list, so one success saves them all (docs/dataplane.md, "A failed save").

    ``told_unsaved``: the decisions whose commander was told so (``OUTCOME_NOT_SAVED``), by
    this life or, restored from the state file (``told_unsaved`` there), an earlier one.
    Kept while the decision is: the clear that follows goes on the outcome writer, in
    memory, and a restart before it reaches the commander loses it, so every later life
    whose file holds the decision's final answer says it is saved (``clear_owed``)."""

    def __init__(
        self,
        life: int = 0,
        earlier: Iterable[KeptDecision] = (),
        told_unsaved: Iterable[tuple[str, int]] = (),
    ) -> None:
        self.life = life
        self._decided: OrderedDict[tuple[str, int], _Decided] = OrderedDict()
        self.evicted = 0
        self.unsaved: set[tuple[str, int]] = set()  # bounded: keys of ``_decided`` only
        self.told_unsaved: set[tuple[str, int]] = set()  # the same bound
        for kept in earlier:
            self._decided[kept.commander, kept.command_id] = _Decided(
                kept.command_id,
                kept.kind,
                kept.commander,
                kept.state,
                kept.reason,
                kept.received_at,
                life=kept.life,
                done_s=kept.done_s,
            )
            self._decided.move_to_end((kept.commander, kept.command_id))
        self._evict()
        # only an earlier life's decision kept here: the file's list is checked at load,
        # and a hand-made one names nothing else (bounded by the kept decisions)
        self.told_unsaved = {
            (c, i) for c, i in told_unsaved if (d := self._decided.get((c, i))) and d.life != life
        }

    def decided(
        self,
        commander: str,
        command_id: int,
        kind: str,
        result: CommandResult,
        reason: str,
        now: float,
    ) -> None:
        """One decision, as reported up: ACCEPTED first, then the final one replaces it."""
        key = (commander, command_id)
        entry = self._decided.get(key)
        state = str(result.name).lower()
        if entry is not None and entry.life != self.life:
            # an earlier life's id decided again (its record restored, the plane's dedup
            # evicted it): this life's decision is a new row
            del self._decided[key]
            self.unsaved.discard(key)
            self.told_unsaved.discard(key)
            entry = None
        if entry is None:
            self._decided[key] = _Decided(
                command_id, kind.lower(), commander, state, reason, now, life=self.life
            )
            self._evict()
            if result != CommandResult.ACCEPTED:
                self._decided[key].final_at = now
        elif entry.final_at is None:  # a decision, once final, stays as it was reported
            entry.state, entry.reason = state, reason
            if result != CommandResult.ACCEPTED:
                entry.final_at = now

    def save_failed(self, commander: str, command_id: int) -> bool:
        """The state-file write that would have kept ``commander``'s ``command_id`` failed;
        True when that decision was saved until now (its commander is not told yet)."""
        key = (commander, command_id)
        if key not in self._decided or key in self.unsaved:
            return False
        self.unsaved.add(key)
        return True

    def told(self, commander: str, command_id: int) -> None:
        """Its commander was told the record of this decision was not saved."""
        if (commander, command_id) in self._decided:
            self.told_unsaved.add((commander, command_id))

    def clear_owed(self, commander: str, command_id: int) -> bool:
        """Is an earlier life's decision, told unsaved, held here with its final answer (so
        the file this life loaded, and wrote at boot, holds it): its commander may still
        show the mark, and this life tells it the record is saved (``Member.rereport``).
        Not while this life holds it unsaved; never for a decision held only ACCEPTED,
        whose final answer a failed write lost (the mark is then right)."""
        key = (commander, command_id)
        d = self._decided.get(key)
        return (
            d is not None
            and d.life != self.life
            and key in self.told_unsaved
            and key not in self.unsaved
            and d.state != CommandResult.ACCEPTED.name.lower()
        )

    def current(self, commander: str, command_id: int) -> tuple[str, str, str] | None:
        """This life's decision on ``commander``'s ``command_id`` as last reported: (kind,
        state, reason); None if none is kept."""
        d = self._decided.get((commander, command_id))
        if d is None or d.life != self.life:
            return None
        return d.kind, d.state, d.reason

    def saved(self) -> list[tuple[str, int]]:
        """A state-file write succeeded: it held every decision kept here. The decisions
        that were unsaved until now, in order (their commanders are told)."""
        held = sorted(self.unsaved)
        self.unsaved.clear()
        return held

    def kept(self) -> tuple[KeptDecision, ...]:
        """What the state file keeps, oldest first (``received_at`` on the core's clock)."""
        return tuple(
            KeptDecision(
                d.life,
                d.commander,
                d.command_id,
                d.kind,
                d.state,
                d.reason,
                d.received_at,
                _done_s(d),
            )
            for d in self._decided.values()
        )

    def recent(
        self, now: float, disarm_unconfirmed: Container[tuple[str, int]] = ()
    ) -> list[dict[str, Any]]:
        """The JSON view, newest first (``outcomes`` without a command id, ``ran``).
        ``disarm_unconfirmed``: the member's marks (``Member.disarm_marks``), shown on the
        failed take-off each names: an operator on the drone, the one that may be armed,
        reads it there too (session 18). Only on a ``failed`` row: a mark names an earlier
        life's failure, and a later life's row for the same id (``decided``, refused
        ``memory_lost``) is another decision."""
        failed = CommandResult.FAILED.name.lower()
        return [
            {
                "command_id": d.command_id,
                "kind": d.kind,
                "commander": d.commander,
                "state": d.state,
                "reason": d.reason,
                "age_s": round(now - d.received_at, 3),
                "done_s": _done_s(d),
                "life": d.life,
                "saved": (d.commander, d.command_id) not in self.unsaved,
                "disarm_unconfirmed": d.state == failed
                and (d.commander, d.command_id) in disarm_unconfirmed,
            }
            for d in reversed(self._decided.values())
        ]

    def _evict(self) -> None:
        while len(self._decided) > MAX_DECIDED_COMMANDS:
            key, _ = self._decided.popitem(last=False)
            self.unsaved.discard(key)
            self.told_unsaved.discard(key)
            self.evicted += 1


def _done_s(d: _Decided) -> float | None:
    if d.final_at is None:
        return d.done_s
    return round(d.final_at - d.received_at, 4)
