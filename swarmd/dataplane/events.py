"""What the data plane tells its owner: frozen, slotted, past-tense events with one base."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.dataplane.types import Command, CommandOutcome, Readiness


@dataclass(frozen=True, slots=True)
class Event:
    """Base of every data-plane event."""


@dataclass(frozen=True, slots=True)
class ReadinessReceived(Event):
    """A member's readiness sample reached this (commander) node.

    ``count`` is how many distinct samples of ``node`` arrived so far, this one included:
    the paper's success criterion is ``count == 20`` for every publisher (section 5).
    """

    node: str
    sample: Readiness
    count: int


@dataclass(frozen=True, slots=True)
class CommandReceived(Event):
    """A command to execute. Emitted once per command id for this node's lifetime (and
    across restarts if the owner persists ``DataPlane.executed_command_ids``)."""

    commander: str
    command: Command


@dataclass(frozen=True, slots=True)
class OutcomeReceived(Event):
    """A member's report on a command; once per (node, boot epoch, command id, result,
    flags). ``epoch``: the boot epoch of the member's life that sent it (its authenticated
    datagram's), so the commander can tell a later life's re-report of an earlier life's
    outcome (docs/dataplane.md, "Outcomes across a restart")."""

    node: str
    outcome: CommandOutcome
    epoch: int = 0


@dataclass(frozen=True, slots=True)
class CommandCopyVoided(Event):
    """Commander side: ``member`` came back in another boot epoch (it restarted) before it
    acknowledged its copy of command ``command_id``, still held because still valid. The
    copy is dated by an echo of the member's earlier life, so it is not handed to the new
    one (fail closed): the command will not run there (docs/dataplane.md, "Rejoining while
    a command is valid")."""

    member: str
    command_id: int


@dataclass(frozen=True, slots=True)
class PacketDropped(Event):
    """Input that was not acted on; ``reason`` is a short snake_case tag also counted in
    ``DataPlane.status()``."""

    reason: str
    source: tuple[str, int] | None = None
    detail: str = ""


DataPlaneEvent = (
    ReadinessReceived | CommandReceived | OutcomeReceived | CommandCopyVoided | PacketDropped
)
