"""The data plane's command bookkeeping: which commands ran here, which outcomes arrived,
which writer SN carries which command, and the per-member copies of a command.

Sans-IO and clock-free: plain bounded tables the plane (``plane.py``) consults after a
sample passed authentication and decoding. Split out of ``plane.py`` by concern (the
plane keeps the wire: matching, authentication, readers and writers).

- Member side, exactly once (docs/dataplane.md, "Exactly once"): the executed
  ``(commander, command id)`` pairs. The reliable reader delivers each SN of a writer life
  at most once; this set turns re-deliveries of an id (a commander resending it, a proxy
  reset after ``peer_down``/``peer_up``, a restart with the state file kept) into no-ops.
  Next to each id, the outcome this node decided for it (``KeptOutcome``), persisted with
  the ids, so a restarted member can tell its commander what it did before the restart
  (docs/dataplane.md, "Outcomes across a restart"); the ids restored at start-up, with
  their outcomes, are the earlier lives' (``earlier_outcomes``).
- Commander side: the ``(node, boot epoch, command id, result, flags)`` outcomes already
  reported up (the epoch: a member's later life may re-report what its earlier one said), and the
  command SNs still in the writer's history (so a member's copies that will not be handed
  over can be named by command id, ``CommandCopyVoided``), and the first dating of each
  command it sent (validity and per-target echoes), which every later send of the same id
  carries (docs/dataplane.md, "A life runs only its own commands").
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from collections.abc import Iterable, Mapping
from typing import Any, Final

from swarmd.bundle.model import Participant
from swarmd.dataplane.types import Command, TimeEcho, encode_sample
from swarmd.dataplane.writer import MAX_HISTORY_DEPTH
from swarmd.rtps.types import GuidPrefix

# Executed (commander, command id) pairs remembered for dedup. A reliable writer keeps at most
# MAX_HISTORY_DEPTH samples, so an id older than this many commands can no longer be resent by
# an honest commander; the cap stops a flood of fresh ids from growing memory without bound.
MAX_EXECUTED_COMMANDS: Final = max(1024, MAX_HISTORY_DEPTH)
# (node, epoch, command id, result, flags, save gen) outcomes already reported up, same reasoning on
# the commander.
MAX_SEEN_OUTCOMES: Final = 4096

# Commands whose first dating (validity, echoes) the commander keeps for a resend of the
# same id. The tracker keeps no more commands (swarm.commander.MAX_TRACKED_COMMANDS); a
# resend of an id made in this life but dated longer ago goes without echoes (refused
# ``expired``: fail closed). Memory: 64 x one echo per target.
MAX_DATED_COMMANDS: Final = 64

# (commander, command id, CommandResult value, reason): what this node decided for a command
KeptOutcome = tuple[str, int, int, str]


class CommandLedger:
    """The bounded command tables of one node's data plane (see the module docstring).

    ``counters`` is the plane's: evictions are counted there (``dedup_evicted``)."""

    def __init__(
        self,
        counters: Counter[str],
        executed: Iterable[tuple[str, int]] = (),
        outcomes: Iterable[KeptOutcome] = (),
    ) -> None:
        """``executed`` and ``outcomes``: what an earlier life persisted (``executed``,
        ``outcomes``). An outcome whose id is not among ``executed`` is ignored: it can only
        be older than the cap (evicted) or not this node's."""
        self._counters = counters
        # (commander, id) -> (result, reason) once decided, None until then (write-ahead)
        self._executed: OrderedDict[tuple[str, int], tuple[int, str] | None] = OrderedDict()
        for key in executed:
            self._remember(self._executed, key, MAX_EXECUTED_COMMANDS)
        for commander, command_id, result, reason in outcomes:
            if (commander, command_id) in self._executed:
                self._executed[commander, command_id] = (result, reason)
        self._earlier: tuple[KeptOutcome, ...] = tuple(self.outcomes)
        self._outcomes: OrderedDict[tuple[str, int, int, int, int, int], None] = OrderedDict()
        # The commander's command SNs still in its writer's history -> command id.
        self._command_ids: OrderedDict[int, int] = OrderedDict()
        # command id -> (valid_ms, echoes) as first sent (the commander's)
        self._datings: OrderedDict[int, tuple[int, tuple[TimeEcho, ...]]] = OrderedDict()
        self._undated_up_to = -1  # the highest id whose dating was evicted

    # --- member side ------------------------------------------------------------------------

    def first_run(self, commander: str, command_id: int) -> bool:
        """True the first time ``commander``'s ``command_id`` is seen here (it is then
        remembered as executed); False for every later copy."""
        key = (commander, command_id)
        if key in self._executed:
            return False
        self._remember(self._executed, key, MAX_EXECUTED_COMMANDS)
        return True

    @property
    def executed(self) -> list[tuple[str, int]]:
        """The executed pairs, oldest first."""
        return list(self._executed)

    def decided(self, commander: str, command_id: int, result: int, reason: str) -> bool:
        """Keep ``result`` (and ``reason``) next to an executed id; False (nothing kept)
        when the id is not, or no longer, in the executed set."""
        key = (commander, command_id)
        if key not in self._executed:
            return False
        self._executed[key] = (result, reason)
        return True

    @property
    def outcomes(self) -> list[KeptOutcome]:
        """The decided outcomes, in the executed set's order (oldest first)."""
        return [(c, i, kept[0], kept[1]) for (c, i), kept in self._executed.items() if kept]

    def earlier_outcomes(self, commander: str, limit: int) -> list[KeptOutcome]:
        """The newest ``limit`` outcomes restored at start-up for ``commander``'s ids,
        oldest first: what this node's earlier lives decided."""
        if limit <= 0:
            return []
        return [kept for kept in self._earlier if kept[0] == commander][-limit:]

    # --- commander side ---------------------------------------------------------------------

    def new_outcome(
        self,
        node: str,
        epoch: int,
        command_id: int,
        result: int,
        flags: int = 0,
        save_gen: int = 0,
    ) -> bool:
        """True the first time ``node`` in boot ``epoch`` reports ``result`` for
        ``command_id`` with ``flags`` and ``save_gen``: the same result flagged
        ``OUTCOME_NOT_SAVED`` after it is the member's word that its record of it could not
        be written, ``OUTCOME_NOW_SAVED`` that a later write held it, and each such word
        at a later ``save_gen`` is news (docs/dataplane.md, "A failed save")."""
        key = (node, epoch, command_id, result, flags, save_gen)
        if key in self._outcomes:
            return False
        self._remember(self._outcomes, key, MAX_SEEN_OUTCOMES)
        return True

    def command_written(self, sn: int, command_id: int) -> None:
        self._command_ids[sn] = command_id
        while len(self._command_ids) > MAX_HISTORY_DEPTH:  # older ones left the history
            self._command_ids.popitem(last=False)

    def command_at(self, sn: int) -> int | None:
        """The command id written as ``sn``, while the writer may still hold it."""
        return self._command_ids.get(sn)

    def has_dating(self, command_id: int) -> bool:
        """Whether this life sent ``command_id`` and still keeps its first dating."""
        return command_id in self._datings

    def dated(self, command: Command, made_here: bool) -> Command:
        """``command`` as it is sent: the first time its id is sent, as given (and its
        dating is kept); later, with the first send's validity and echoes (those of its
        targets), whatever the caller put in: a resend can neither outlive the first
        validity nor pass, at a member, as issued later than it was. ``made_here``: the id
        was made by this life (``DataPlane.make_command``); such an id whose dating is no
        longer kept (ids grow: at most the highest evicted) goes without echoes (its
        members refuse it, fail closed)."""
        first = self._datings.get(command.command_id)
        if first is None:
            if made_here and command.command_id <= self._undated_up_to:
                self._counters["command_resent_undated"] += 1
                first = (command.valid_ms, ())
            else:
                self._datings[command.command_id] = (command.valid_ms, tuple(command.echoes))
                while len(self._datings) > MAX_DATED_COMMANDS:
                    evicted, _ = self._datings.popitem(last=False)
                    self._undated_up_to = max(self._undated_up_to, evicted)
                return command
        self._counters["command_resent"] += 1
        valid_ms, echoes = first
        targets = set(command.targets)
        return Command(
            command.command_id,
            command.kind,
            command.altitude_m,
            list(command.targets),
            valid_ms,
            [e for e in echoes if not targets or e.node in targets],
        )

    def command_withdrawn(self, sn: int) -> None:
        self._command_ids.pop(sn, None)

    # --- internals --------------------------------------------------------------------------

    def _remember(self, table: OrderedDict[Any, Any], key: Any, cap: int) -> None:
        table[key] = None
        while len(table) > cap:
            table.popitem(last=False)
            self._counters["dedup_evicted"] += 1


def command_copies(
    command: Command,
    names: Iterable[str],
    participants: Mapping[str, Participant],
    local_name: str,
    counters: Counter[str],
) -> dict[GuidPrefix, bytes]:
    """One encoded copy of ``command`` per target in ``names``, keyed by the target's GUID
    prefix, each naming only that member and carrying only its own time echo
    (docs/dataplane.md, "One copy per member"). Names that are not participants, or this
    node, are skipped (counted ``command_target_unknown``).

    Encoded here, at issue, so a bad field raises ``PayloadError`` to the caller now
    and never later inside a repair (``receive_datagram`` never raises)."""
    echoes = {echo.node: echo for echo in command.echoes}
    copies: dict[GuidPrefix, bytes] = {}
    for name in names:
        target = participants.get(name)
        if target is None or target.name == local_name:
            counters["command_target_unknown"] += 1
            continue
        echo = echoes.get(name)
        copy = Command(
            command.command_id,
            command.kind,
            command.altitude_m,
            [name],
            command.valid_ms,
            [] if echo is None else [echo],
        )
        copies[target.guid_prefix] = encode_sample(copy)
    return copies
