"""The swarm core's events in ``SwarmApp`` (``swarmd/swarmapp.py``; style.md rule 11: the
driver drains them into ``_on_event``): its datagrams to the user-data socket, its saves and
vehicle requests to the write-ahead (``swarmapp_saves.py``), a peer's verified traffic to
discovery, the rest to the log (docs/operations.md). Split out of ``swarmapp.py`` by concern
at 773 lines (style.md rule 19).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import assert_never

from swarmd.px4.vehicle import VehicleRequest
from swarmd.swarm.commander import RESTARTED_RUNNING
from swarmd.swarm.events import (
    CommandBeforeLife,
    CommandExecuting,
    CommandExpired,
    CommandIssued,
    CommandLifeEnded,
    CommandNotDelivered,
    CommandWithdrawn,
    MemberReadinessChanged,
    OutcomeRecorded,
    OutcomeReported,
    OutcomesReReported,
    PeerTrafficVerified,
    PersistExecuted,
    SwarmEvent,
    UserDataDropped,
)
from swarmd.swarmapp_saves import StateSaves
from swarmd.swarmapp_status import Datagram


class CoreEvents(StateSaves):
    """The driver's ``transmit`` and ``on_event`` for the swarm core."""

    # verified user data from a peer, by name: the daemon feeds it to discovery
    on_peer_traffic: Callable[[str], None] | None

    def _transmit(self, datagram: Datagram) -> None:
        if self.socket is None:
            self.counters["tx_closed"] = self.counters.get("tx_closed", 0) + 1
            return
        self.socket.send(*datagram)

    def _on_event(self, event: SwarmEvent) -> None:
        match event:
            case PersistExecuted():
                self._persist(event)
            case VehicleRequest():
                self._vehicle_request(event)
            case MemberReadinessChanged(member=member, ready=ready, reason=reason):
                self.log.info("member_readiness", member=member, ready=ready, reason=reason)
            case CommandIssued():
                self.log.info(
                    "command_sent",
                    command_id=event.command_id,
                    kind=event.kind.name,
                    altitude_m=event.altitude_m,
                    targets=list(event.targets),
                    refused=dict(event.refused),
                    sent_by=None if event.sent_by is None else event.sent_by.as_json(),
                )
            case CommandExecuting():
                self.log.info(
                    "command_received",
                    commander=event.commander,
                    command_id=event.command_id,
                    kind=event.kind.name,
                    altitude_m=event.altitude_m,
                )
            case CommandExpired() | CommandBeforeLife():
                # a member's refusal of a command it may not run (docs/operations.md,
                # "Validity" and "memory_lost": either way a new command runs it now)
                self.log.warning(
                    "command_expired"
                    if isinstance(event, CommandExpired)
                    else "command_refused_memory_lost",
                    commander=event.commander,
                    command_id=event.command_id,
                    kind=event.kind.name,
                    detail=event.detail,
                )
            case CommandWithdrawn():
                self.log.info("command_withdrawn", command_id=event.command_id)
            case CommandNotDelivered():
                self.log.warning(
                    "command_not_delivered",
                    member=event.member,
                    command_id=event.command_id,
                    reason=event.reason,
                )
            case CommandLifeEnded():
                self.log.warning(
                    "command_member_restarted",
                    member=event.member,
                    command_id=event.command_id,
                    reason=RESTARTED_RUNNING,
                )
            case OutcomeReported():
                # a failed take-off's amendment is a warning: the vehicle may still be armed
                # (docs/operations.md, "What swarmctl tells you about a command")
                (self.log.warning if event.disarm_unconfirmed else self.log.info)(
                    "command_outcome",
                    command_id=event.command_id,
                    kind=event.kind,
                    result=event.result.name,
                    reason=event.reason,
                    saved=event.saved,
                    disarm_unconfirmed=event.disarm_unconfirmed,
                )
            case OutcomesReReported():
                self.log.info(
                    "command_outcomes_rereported",
                    commander=event.commander,
                    command_ids=list(event.command_ids),
                )
            case OutcomeRecorded():
                (self.log.warning if event.disarm_unconfirmed else self.log.info)(
                    "command_outcome_received",
                    member=event.member,
                    command_id=event.command_id,
                    result=event.result.name,
                    reason=event.reason,
                    known=event.known,
                    saved=event.saved,
                    disarm_unconfirmed=event.disarm_unconfirmed,
                )
            case PeerTrafficVerified(node=node):
                if self.on_peer_traffic is not None:
                    self.on_peer_traffic(node)
            case UserDataDropped(reason=reason, source=source, detail=detail):
                self.log.debug("userdata_dropped", reason=reason, source=str(source), detail=detail)
            case _:
                assert_never(event)
