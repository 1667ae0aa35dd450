"""The swarm core's events (``SwarmCore.next_event``): frozen, past-tense dataclasses.

Split out of ``core.py`` by concern. Two are orders for the driver, in this order for each
command: ``PersistExecuted`` (write the state file before anything moves) and
``swarmd.px4.vehicle.VehicleRequest``; the others are for the log.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

from swarmd.dataplane.ledger import KeptOutcome
from swarmd.dataplane.types import CommandKind, CommandResult
from swarmd.px4.vehicle import VehicleRequest

if TYPE_CHECKING:  # commander.py imports this module (SentBy)
    from swarmd.swarm.commander import KeptDecision


@dataclass(frozen=True, slots=True)
class PersistExecuted:
    """Write the executed command ids to the state file now: before executing (write-ahead),
    and again with each outcome decided (``outcomes``: (commander, id, CommandResult value,
    reason) next to the ids, for re-reporting after a restart; ``decisions``: the member's
    ``DecisionLog`` with kind, time and life, for ``swarmctl outcomes`` in a later life).
    ``command``: the (commander, id) whose receipt or decision asked for this write, so the
    daemon can name it if the write fails (``SwarmCore.state_saved``). ``told_unsaved``:
    the decisions whose commander was told their record was not saved (a later life that
    holds their final answer tells it they are: ``DecisionLog.told_unsaved``).
    ``disarm_unconfirmed``: the failed take-offs whose DISARM was never confirmed (a later
    life re-reports them flagged ``OUTCOME_DISARM_UNCONFIRMED``: ``Member.rereport``)."""

    executed: tuple[tuple[str, int], ...]
    outcomes: tuple[KeptOutcome, ...] = ()
    decisions: tuple[KeptDecision, ...] = ()
    command: tuple[str, int] | None = None
    told_unsaved: tuple[tuple[str, int], ...] = ()
    disarm_unconfirmed: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True, slots=True)
class PeerTrafficVerified:
    """A datagram from ``node`` passed the data plane's MAC under the pair's key: ``node``
    is alive. The daemon hands it to discovery (``DiscoveryEngine.peer_traffic``), so the
    commander's leases on members ride on their 1 Hz readiness (docs/discovery.md)."""

    node: str


@dataclass(frozen=True, slots=True)
class MemberReadinessChanged:
    member: str
    ready: bool
    reason: str | None


@dataclass(frozen=True, slots=True)
class SentBy:
    """Who asked the commander for a command: the control socket client's credentials as
    the kernel gave them at connect (``SO_PEERCRED``; ``user`` None when the uid has no
    name). A record for the operator's log, not an authority (docs/security.md)."""

    uid: int
    user: str | None
    pid: int

    def as_json(self) -> dict[str, int | str | None]:
        return {"uid": self.uid, "user": self.user, "pid": self.pid}


@dataclass(frozen=True, slots=True)
class CommandIssued:
    command_id: int
    kind: CommandKind
    altitude_m: float | None
    targets: tuple[str, ...]
    refused: Mapping[str, str]
    sent_by: SentBy | None = None  # None: issued without a control socket client (tests)


@dataclass(frozen=True, slots=True)
class CommandExecuting:
    commander: str
    command_id: int
    kind: CommandKind
    altitude_m: float | None


@dataclass(frozen=True, slots=True)
class CommandExpired:
    """A member refused a command that reached it after its validity (REJECTED
    ``expired``); ``detail`` says by how much, or that it could not be dated."""

    commander: str
    command_id: int
    kind: CommandKind
    detail: str


@dataclass(frozen=True, slots=True)
class CommandBeforeLife:
    """A member refused a command it cannot prove was issued after its daemon started
    (REJECTED ``memory_lost``): its record of the commands it ran may be lost, and it may
    have run this one before (docs/dataplane.md, "A life runs only its own commands")."""

    commander: str
    command_id: int
    kind: CommandKind
    detail: str


@dataclass(frozen=True, slots=True)
class CommandWithdrawn:
    """The commander's validity for a command ended: its writer no longer holds it, so
    repair never carries it to a member that did not have it by then."""

    command_id: int


@dataclass(frozen=True, slots=True)
class CommandNotDelivered:
    """The commander will not hand command ``command_id`` to ``member``: ``reason``
    (``commander.RESTARTED``: it came back in a new boot epoch before acknowledging it);
    the tracker says ``unreachable`` for it from now."""

    member: str
    command_id: int
    reason: str


@dataclass(frozen=True, slots=True)
class CommandLifeEnded:
    """``member`` accepted command ``command_id`` and the commander now sees it in a later
    boot epoch with no final answer: no final will come (its new life never runs the
    command); the tracker's row says ``restarted_before_finishing`` (docs/dataplane.md,
    "Outcomes across a restart")."""

    member: str
    command_id: int


@dataclass(frozen=True, slots=True)
class OutcomeReported:
    """This node's own outcome for a command (sent on ``swarm/outcome``, or recorded in
    the commander's own tracker for its own drone)."""

    command_id: int
    kind: str
    result: CommandResult
    reason: str
    # False: sent flagged ``OUTCOME_NOT_SAVED``, its record could not be written (a
    # decision's later outcome, or the same one again when the failure is learnt after it)
    saved: bool = True
    # the failed take-off's amendment (``OUTCOME_DISARM_UNCONFIRMED``): its DISARM was never
    # confirmed, the vehicle may still be armed; the log line says so, not only the row
    disarm_unconfirmed: bool = False


@dataclass(frozen=True, slots=True)
class OutcomesReReported:
    """This node restarted and re-reported to ``commander`` the outcomes its earlier life
    decided for ``command_ids`` (docs/dataplane.md, "Outcomes across a restart")."""

    commander: str
    command_ids: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class OutcomeRecorded:
    """A member's outcome reached the commander's tracker (``known``: a command it sent)."""

    member: str
    command_id: int
    result: CommandResult
    reason: str
    known: bool
    saved: bool = True  # False: the member flagged it OUTCOME_NOT_SAVED
    # flagged OUTCOME_DISARM_UNCONFIRMED: the vehicle may still be armed (the journal keeps
    # it past the tracker, which a restart empties)
    disarm_unconfirmed: bool = False


@dataclass(frozen=True, slots=True)
class UserDataDropped:
    """The data plane dropped a user datagram (its ``PacketDropped``; discovery's has the
    same name for SPDP): for the debug log, counted in the plane's status."""

    reason: str
    source: tuple[str, int] | None
    detail: str


SwarmEvent = (
    PersistExecuted
    | VehicleRequest
    | MemberReadinessChanged
    | CommandIssued
    | CommandExecuting
    | CommandExpired
    | CommandBeforeLife
    | CommandWithdrawn
    | CommandNotDelivered
    | CommandLifeEnded
    | OutcomeReported
    | OutcomesReReported
    | OutcomeRecorded
    | UserDataDropped
    | PeerTrafficVerified
)
