"""The commander's side of the command topic: this life's command ids, their dating, the
per-member copies written, and their withdrawal when a validity ends.

Command ids carry the commander's boot epoch in their high 32 bits, so a restarted
commander never reuses one, even when its state file (the boot counter) was lost
(docs/dataplane.md, "Exactly once"). An id is dated once: a resend carries its first
send's validity and echoes (``ledger.CommandLedger.dated``), and an id this life neither
made nor sent is refused (``ForeignCommandId``: docs/security.md, "A re-dated id").
A command goes out as one sample (one SN, one id) with one copy per target, each naming
only that member and carrying only its echo (docs/dataplane.md, "One copy per member").

Split out of ``plane.py`` by concern: the plane keeps the peers and the wire and queues
what ``write`` returns; this keeps the id counter. Sans-IO; no clock.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping

from swarmd.auth.freshness import U32_MAX
from swarmd.bundle.model import Bundle, Participant
from swarmd.dataplane.endpoints import TOPIC_COMMAND, Endpoints
from swarmd.dataplane.ledger import CommandLedger, command_copies
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.types import Command, CommandKind, TimeEcho
from swarmd.dataplane.writer import ReliableWriter
from swarmd.rtps.types import GuidPrefix

__all__ = ["CommandIdsExhausted", "Commands", "ForeignCommandId"]


class ForeignCommandId(ValueError):
    """``send_command`` was given an id this life neither made nor sent (nothing sent)."""


class CommandIdsExhausted(ValueError):
    """``make_command`` gave out every counter of this life (2^32 - 1): restart for more."""


class Commands:
    """This life's command ids (``life << 32 | counter``) and what the commander writes on
    ``swarm/command``; the writer, ledger and counters are the plane's."""

    __slots__ = (
        "_bundle",
        "_counters",
        "_endpoints",
        "_ledger",
        "_local",
        "_participants",
        "issued",
        "life",
    )

    def __init__(
        self,
        bundle: Bundle,
        local: Participant,
        endpoints: Endpoints,
        ledger: CommandLedger,
        counters: Counter[str],
        *,
        life: int,
    ) -> None:
        self._bundle = bundle
        self._local = local
        self._endpoints = endpoints
        self._ledger = ledger
        self._counters = counters
        self._participants: Mapping[str, Participant] = {p.name: p for p in bundle.participants}
        self.life = life  # the high 32 bits of our command ids: this life's, never an earlier's
        self.issued = 0  # the counter of the last id given out

    def make(
        self,
        kind: CommandKind,
        altitude_m: float,
        targets: Iterable[str],
        valid_ms: int,
        echoes: Iterable[TimeEcho],
    ) -> Command:
        """A command with a fresh id (``DataPlane.make_command``)."""
        if self.issued >= U32_MAX:  # more would carry into the epoch's bits
            raise CommandIdsExhausted(f"all {U32_MAX} command ids of this life are used")
        self.issued += 1
        command_id = (self.life << 32) | self.issued
        return Command(command_id, kind, float(altitude_m), list(targets), valid_ms, list(echoes))

    def made_here(self, command_id: int) -> bool:
        """Whether ``make`` of this life gave out ``command_id``."""
        return command_id >> 32 == self.life and 0 < command_id & 0xFFFF_FFFF <= self.issued

    def dated(self, command: Command) -> Command:
        """``command`` with the dating it is sent with (``DataPlane.dated``)."""
        return self._ledger.dated(command, self.made_here(command.command_id))

    def write(self, command: Command, now: float) -> tuple[int, list[Outgoing]]:
        """Write ``command``'s copies (``DataPlane.send_command``): its SN and what to
        queue. Raises ``ForeignCommandId`` (nothing written) for an id this life did not
        make and has no dating of."""
        writer = self._endpoints.by_topic.get(TOPIC_COMMAND)
        if writer is None:
            raise ValueError(f"{self._local.name!r} has no writer on {TOPIC_COMMAND!r}")
        if not self.made_here(command.command_id) and not self._ledger.has_dating(
            command.command_id
        ):
            self._counters["command_id_not_ours"] += 1
            raise ForeignCommandId(
                f"command id {command.command_id} is not of this life (epoch "
                f"{self.life}, ids up to {self.life << 32 | self.issued}) "
                "and was never sent by it: issue a new command (make_command)"
            )
        command = self.dated(command)
        sn, out = writer.write(self._copies(command), now)
        self._ledger.command_written(sn, command.command_id)
        return sn, out

    def withdraw(self, sn: int) -> bool:
        """Stop (re)sending the command written as ``sn`` (``DataPlane.withdraw_command``)."""
        writer = self._endpoints.by_topic.get(TOPIC_COMMAND)
        if not isinstance(writer, ReliableWriter):
            return False
        self._ledger.command_withdrawn(sn)
        return writer.withdraw(sn)

    def _copies(self, command: Command) -> dict[GuidPrefix, bytes]:
        """One encoded copy of ``command`` per target (``ledger.command_copies``)."""
        names = list(command.targets) or self._readers()
        return command_copies(command, names, self._participants, self._local.name, self._counters)

    def _readers(self) -> list[str]:
        """Every bundle participant with a reader matching our command writer."""
        writer = self._endpoints.by_topic[TOPIC_COMMAND]
        entity = next(e for e, (_, w) in self._endpoints.writers.items() if w is writer)
        return [
            p.name
            for p in self._bundle.participants
            if p.name != self._local.name
            and any(m.local.entity_id == entity for m in self._bundle.matches(self._local, p))
        ]
