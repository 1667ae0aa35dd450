"""The swarm as a sans-IO core: readiness reports, and the commander's and the member's
sides of a command, driven as one.

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
  withdraws it (``issuer.py``);
- calls: ``start``, ``peer_up``/``peer_down`` (discovery), ``vehicle_changed`` and
  ``task_finished`` (the vehicle core), ``state_saved`` (the daemon wrote, or failed to
  write, a ``PersistExecuted``), and the commander's requests (``request_takeoff``,
  ``request_command``, ``request_outcomes``; ``RequestInvalid`` on a bad one).

Outputs: ``datagrams_to_send()``, ``get_timer()``, ``next_event()``. Two events are orders
for the driver, in this order for each command: ``PersistExecuted`` (write the state file
before anything moves: a crash then loses a command, never repeats it; docs/dataplane.md,
"Exactly once") and ``px4.vehicle.VehicleRequest`` (what the vehicle should do, tagged with
the member's own task number, never the command id: ``member.py``). Each outcome a member
decides is followed by another ``PersistExecuted`` carrying it next to its id. The others
are for the log.

Each side's state lives with it: ``issuer.py`` (``Issuer``: request validation, issuing,
the tracker's records, withdrawal at the end of a validity), ``member.py`` (``Member``:
exactly once, the validity and life proofs, the vehicle's tasks, the answers, the
re-report after a restart, docs/dataplane.md "Outcomes across a restart"). This module
keeps the driving protocol, discovery's calls, the readiness reports and the dispatch of
the data plane's events to the two sides. Their public names are re-exported here.

Time is the ``now`` argument; the vehicle's verdict and the link quality are read through
the injected ``verdict(now)`` (None: the node has no vehicle link) and ``link_q()``. No
I/O, no clock, no asyncio.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, assert_never

from swarmd.dataplane import (
    TOPIC_READY,
    CommandCopyVoided,
    CommandReceived,
    DataPlane,
    OutcomeReceived,
    PacketDropped,
    ReadinessReceived,
)
from swarmd.dataplane.convert import ReadinessVerdict, readiness_sample
from swarmd.dataplane.types import Command
from swarmd.dataplane.validity import stamp_ms
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished
from swarmd.swarm.commander import (
    MAX_TRACKED_COMMANDS,
    READINESS_REPORT_BURST,
    READINESS_REPORTS_PER_S,
    CommandTracker,
    KeptDecision,
    ReadinessReports,
    ReadinessTable,
)
from swarmd.swarm.events import (
    MemberReadinessChanged,
    PeerTrafficVerified,
    SentBy,
    SwarmEvent,
    UserDataDropped,
)
from swarmd.swarm.issuer import (
    COMMAND_KINDS,
    DEFAULT_VALID_FOR_S,
    MAX_PENDING_WITHDRAWALS,
    MAX_VALID_FOR_S,
    UNKNOWN_OUTCOME_REPORT_BURST,
    UNKNOWN_OUTCOME_REPORTS_PER_S,
    Issuer,
    RequestInvalid,
)
from swarmd.swarm.member import (
    ID_IN_USE,
    MAX_REREPORTED,
    MAX_RUNNING_IDS,
    NO_VEHICLE,
    PX4_DISABLED,
    REREPORT_WINDOW_S,
    UNKNOWN_KIND,
    Member,
    NoVehicle,
)
from swarmd.swarm.roles import Roles, reads

# SwarmCore and its settings, and the two sides' names, where importers have found them
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
    "READINESS_REPORTS_PER_S",
    "READINESS_REPORT_BURST",
]


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
        earlier_decisions: Iterable[KeptDecision] = (),
        told_unsaved: Iterable[tuple[str, int]] = (),
        disarm_unconfirmed: Iterable[tuple[str, int]] = (),
    ) -> None:
        """``earlier_decisions``: what the member's earlier lives decided, from the state
        file, on this life's clock (``swarmctl outcomes``); ``told_unsaved``: which of them
        their commanders were told were not saved; ``disarm_unconfirmed``: the failed
        take-offs whose DISARM an earlier life never saw confirmed (``Member``)."""
        self.roles = roles
        self.plane = plane
        self.has_vehicle = verdict is not None
        self.settings = settings or SwarmSettings()
        self._link_q = link_q
        self.table = ReadinessTable(roles.members, stale_after_s=self.settings.stale_after_s)
        # which of its changes are logged, at a bounded rate per member (review 16)
        self._readiness_reports = ReadinessReports()
        if roles.is_commander and self.has_vehicle:
            self.table.add_local(roles.me)  # the commander's own drone flies with the swarm
        # the commander's commands: issued (issuer.py), its own drone's outcomes (member.py)
        self.tracker = CommandTracker()
        self.counters: dict[str, int] = {
            "readiness_published": 0,
            "outcomes_rereported": 0,
            "unknown_outcomes_suppressed": 0,
            "readiness_changes_suppressed": 0,
        }
        self._events: deque[SwarmEvent] = deque()
        # the member's side: what this node decides for the commands it receives
        self.member = Member(
            roles,
            plane,
            verdict=verdict,
            tracker=self.tracker,
            events=self._events,
            counters=self.counters,
            earlier=earlier_decisions,
            told_unsaved=told_unsaved,
            disarm_unconfirmed=disarm_unconfirmed,
        )
        self.decisions = self.member.decisions  # what this member decided (swarmctl outcomes)
        self.executor_counters = self.member.counters
        # the commander's side: requests, issued commands, their withdrawal
        self.issuer = Issuer(
            roles,
            plane,
            table=self.table,
            tracker=self.tracker,
            member=self.member,
            takeoff_alt_m=self.settings.takeoff_alt_m,
            events=self._events,
            counters=self.counters,
        )
        # readiness reporting: when the next report is due, its number, the last verdict
        self._tick_at: float | None = None
        self._seq = 0
        self._last_key: tuple[bool, str | None] | None = None
        self._readers_up: set[str] = set()  # peers up that read our readiness (peer_up)

    # ---- driving protocol ---------------------------------------------------------------

    def start(self, now: float) -> None:
        """Publish the first readiness report now, then every period."""
        self._tick_at = now
        self.member.start(now)

    def state_saved(self, command: tuple[str, int] | None, error: str | None, now: float) -> None:
        """The daemon's answer to a ``PersistExecuted``: written (``error`` None) or not
        (``Member.state_saved``: the commander is told)."""
        self.member.state_saved(command, error, now)

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        if self.plane is None:
            return
        self.plane.receive_datagram(data, source, now)
        self._drain_plane(now)

    def handle_timer(self, now: float) -> None:
        self.issuer.withdraw_expired(now)
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
            self.issuer.next_expiry(),
        ]
        return min((d for d in deadlines if d is not None), default=None)

    def next_event(self) -> SwarmEvent | None:
        return self._events.popleft() if self._events else None

    # ---- discovery ----------------------------------------------------------------------

    def peer_up(self, name: str, locator: tuple[str, int] | None, epoch: int, now: float) -> None:
        """Discovery heard ``name`` (authenticated SPDP) in boot ``epoch``; its user-data
        locator, or None when no address is known (the data plane then keeps it down)."""
        self.table.on_peer(name, True)
        if self.roles.is_commander:
            # a later life of a member ends the rows its earlier life accepted and never
            # finished (the epoch is from its authenticated SPDP; rows only, no new table)
            self.issuer.member_seen(name, epoch, now)
        if self.plane is not None and locator is not None:
            self.plane.peer_up(name, locator, now, epoch=epoch)
            self._drain_plane(now)
            self.member.rereport(name, now)
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

    def task_finished(self, done: TaskFinished | DisarmUnconfirmed, now: float) -> None:
        """The vehicle ended the task of command ``done.token``, or amended the end of a
        failed take-off: its DISARM was not confirmed (``Member.disarm_unconfirmed``)."""
        if isinstance(done, DisarmUnconfirmed):
            self.member.disarm_unconfirmed(done, now)
        else:
            self.member.task_finished(done, now)

    # ---- the commander's requests -------------------------------------------------------

    def request_takeoff(
        self, request: Mapping[str, Any], now: float, *, sent_by: SentBy | None = None
    ) -> dict[str, Any]:
        """Take-off of the targeted nodes that are ready now; ``require_all``: all or none.
        ``sent_by``: who asked (kept with the command, and in ``CommandIssued``)."""
        return self.issuer.request_takeoff(request, now, sent_by)

    def request_command(
        self, request: Mapping[str, Any], now: float, *, sent_by: SentBy | None = None
    ) -> dict[str, Any]:
        """Any command to the targets as they are: members judge for themselves."""
        return self.issuer.request_command(request, now, sent_by)

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
                "ran": self.decisions.recent(now, self.member.disarm_marks),
                "ran_evicted": self.decisions.evicted,
                "life": self.decisions.life,  # each "ran" entry names the life that decided it
            }
        command_id = request.get("command_id")
        if not isinstance(command_id, int) or isinstance(command_id, bool):
            raise RequestInvalid('"command_id" must be an integer')
        snap = self.tracker.snapshot(command_id, now)
        if snap is None:
            raise RequestInvalid(f"unknown command id {command_id}")
        return snap

    # ---- status (pure: evaluated when asked) --------------------------------------------

    def executor_status(self, now: float | None = None) -> dict[str, Any]:
        """``executor`` of ``status``: with ``now``, each running command's age too."""
        return self.member.status(now)

    # ---- internals: data plane ----------------------------------------------------------

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
                        self._readiness_changed(node, after, now)
                case CommandReceived(commander=commander, command=command):
                    self._events.append(PeerTrafficVerified(commander))
                    self.member.received(commander, command, now)
                case OutcomeReceived(node=node, outcome=outcome, epoch=epoch):
                    self._events.append(PeerTrafficVerified(node))
                    self.issuer.outcome_received(node, outcome, epoch, now)
                case CommandCopyVoided(member=member, command_id=command_id):
                    self.issuer.copy_voided(member, command_id, now)
                case PacketDropped(reason=reason, source=source, detail=detail):
                    self._events.append(UserDataDropped(reason, source, detail))
                case _:
                    assert_never(event)

    def _readiness_changed(
        self, node: str, verdict: tuple[bool, str | None], now: float, *, retry: bool = False
    ) -> None:
        """Report a member's new verdict (the log's ``member_readiness``) within its budget;
        held back, it is counted and caught up by the tick (``ReadinessReports``)."""
        reports = self._readiness_reports
        if reports.changed(node, verdict, now, retry=retry):
            self._events.append(MemberReadinessChanged(node, verdict[0], verdict[1]))
        self.counters["readiness_changes_suppressed"] = reports.suppressed

    def _tick(self, now: float) -> None:
        self._tick_at = now + self.settings.readiness_period_s
        for node in self._readiness_reports.held():
            self._readiness_changed(node, self.table.verdict(node, now), now, retry=True)
        if not (self.roles.reports_readiness or self.table.names):
            return
        self._seq += 1
        sample = readiness_sample(
            self.roles.me, self._seq, self.member.verdict(now), self._link_q(), stamp_ms(now)
        )
        if self.roles.reports_readiness and self.plane is not None:
            self.plane.publish_readiness(sample, now)
            self.member.reports.sent(sample.stamp_ms, now)
            self.counters["readiness_published"] += 1
        if self.roles.me in self.table.names:
            self.table.on_report(self.roles.me, sample, None, now)

    # ---- the halves' state, by the names tests reach for ---------------------------------

    @property
    def _expiries(self) -> list[tuple[float, int, int]]:
        """Commands awaiting their withdrawal (``Issuer.expiries``)."""
        return self.issuer.expiries

    def _execute(self, commander: str, command: Command, now: float) -> None:
        """A member's decision on ``command``, as if received (``Member.execute``)."""
        self.member.execute(commander, command, now)
