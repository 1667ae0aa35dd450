"""The daemon's routing of discovery's events (style.md rule 11: the driver drains them
into ``_on_event``): each is logged, kept for ``swarmctl watch`` (``PeerHistory``), and
handed to the data plane (``SwarmApp``) and the ROS 2 relay (``Ros2App``) with the address
discovery has for the peer; the ``STATUS=`` line of sd_notify moves with them. And the
callbacks those two give back to the engine (a peer's authenticated traffic, our nodes'
ROS 2 liveness). Split out of ``daemon.py`` by concern at 757 lines (style.md rule 19).
"""

from __future__ import annotations

from typing import Final

from swarmd.changereports import ChangeReports
from swarmd.daemon_status import DaemonStatus
from swarmd.discovery.events import (
    Event,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLocatorsChanged,
    PeerLost,
    PeerRestarted,
    PeerRos2Liveness,
    PhaseChanged,
)
from swarmd.peerlog import PeerChangeKind
from swarmd.rtps.types import GuidPrefix

# A peer's moves and ROS 2 liveness words are logged (``peer_locators_changed``,
# ``peer_ros2_liveness``). A captured member's signed datagrams change them at will: up to 4
# lines a datagram (MAX_SPDP_SAMPLES) within its 20 a second (session 16, h-insider16). At
# most this many a second per peer and kind, the rest counted (``peer_changes_suppressed``);
# an honest drone moves a few times a flight and its relay's word changes as its nodes
# start (the burst). What is done with each change (the data plane, the relay) is not held.
PEER_CHANGE_REPORTS_PER_S: Final = 1.0
PEER_CHANGE_REPORT_BURST: Final = 10.0


def peer_change_reports() -> ChangeReports[tuple[str, str], object]:
    """The daemon's budget of peer-change log lines, keyed by (peer, kind)."""
    return ChangeReports(PEER_CHANGE_REPORTS_PER_S, PEER_CHANGE_REPORT_BURST)


class DaemonEvents(DaemonStatus):
    """Discovery's events to the log, the peer history, the data plane and the relay."""

    def _on_event(self, event: Event) -> None:
        self._log_event(event)
        # the sd_notify line moves only with discovery's events: nothing per datagram is
        # rebuilt (a flood of datagrams must not become a flood of status snapshots)
        if self._ready and isinstance(event, PeerDiscovered | PeerLost | PhaseChanged):
            text = self._status_text()
            if text != self._status_line:
                self._status_line = text
                self.notifier.status(text)

    def _log_event(self, event: Event) -> None:
        match event:
            case PeerDiscovered(name=name, matches=matches, via=via, epoch=epoch):
                self.log.info(
                    "peer_discovered", peer=name, via=via, matched=len(matches), epoch=epoch
                )
                self._record_change(event.guid_prefix, name, PeerChangeKind.DISCOVERED, via)
                if self.app is not None and epoch is not None:  # None only without auth
                    self.app.peer_up(name, self._peer_ipv4(event.guid_prefix), epoch)
                self._ros2_peer(name, event.guid_prefix)
            case PeerLocatorsChanged(name=name, default_unicast_locators=user):
                # authenticated: the peer itself moved its address
                moved = (event.metatraffic_unicast_locators, user)
                if self._report_change(name, "locators", moved):
                    self.log.info("peer_locators_changed", peer=name, user=[str(x) for x in user])
                if self.app is not None:
                    self.app.peer_moved(name, self._peer_ipv4(event.guid_prefix))
                self._ros2_peer(name, event.guid_prefix)
            case PeerRestarted(name=name, epoch=epoch, previous_epoch=previous):
                self.log.info("peer_restarted", peer=name, epoch=epoch, previous_epoch=previous)
                self._record_change(event.guid_prefix, name, PeerChangeKind.RESTARTED, None)
                # its data-plane state belongs to its earlier life: the plane resets it
                if self.app is not None:
                    self.app.peer_up(name, self._peer_ipv4(event.guid_prefix), epoch)
                # its ROS 2 nodes' writers number from 1 again under the same GUIDs: the
                # relay disposes them at our nodes and announces them again (docs/ros2.md)
                self._ros2_peer(name, event.guid_prefix, restarted=True)
            case PeerRos2Liveness(name=name, alive=alive):
                # authenticated (the engine takes PID 0x8A06 only from a DATA(p) it accepted)
                if self._report_change(name, "ros2_liveness", alive):
                    self.log.info("peer_ros2_liveness", peer=name, alive=alive.hex())
                if self.ros2 is not None:
                    self.ros2.peer_liveness(name, alive)
            case PeerLost(name=name, reason=reason):
                self.log.info("peer_lost", peer=name, reason=reason)
                self._record_change(event.guid_prefix, name, PeerChangeKind.LOST, reason)
                if self.app is not None:
                    self.app.peer_down(name)
                if self.ros2 is not None and name is not None:
                    self.ros2.peer_down(name)
            case ForeignParticipantSeen(guid_prefix=prefix, vendor=vendor, name=name):
                # rate-limited in the engine: ``suppressed`` more were not reported one by one
                self.log.info(
                    "foreign_participant",
                    guid_prefix=str(prefix),
                    vendor=vendor,
                    name=name,
                    reason=str(event.reason),
                    suppressed=event.suppressed,
                )
            case PhaseChanged(old=old, new=new, reason=reason):
                self.log.info("phase_changed", old=str(old), new=str(new), reason=reason)
            case PacketDropped(reason=reason, source=source):
                self.log.debug("packet_dropped", reason=reason, source=f"{source[0]}:{source[1]}")
            case _:  # Event is concrete, so match cannot be exhaustive; log what is new
                self.log.info("engine_event", event_type=type(event).__name__)

    def _report_change(self, name: str, kind: str, value: object) -> bool:
        """Whether the log gets this change of ``name``'s ``kind`` (its budget: above)."""
        reports = self._peer_changes
        said = reports.changed((name, kind), value, self._drive().now())
        self.counters["peer_changes_suppressed"] = reports.suppressed
        return said

    def _ros2_liveness(self, alive: bytes) -> None:
        """Our relay's nodes changed liveness: into our signed DATA(p) (docs/ros2.md)."""
        engine = self.engine
        if engine is not None:
            self._drive().call(lambda now: engine.set_ros2_alive(alive, now))

    def _ros2_peer(self, name: str, prefix: GuidPrefix, *, restarted: bool = False) -> None:
        """An authenticated peer is up, moved or ``restarted`` (a higher signed epoch): the
        relay serves its drone's ROS 2 nodes at the address discovery has for it."""
        if self.ros2 is not None:
            self.ros2.peer_up(name, self._peer_ipv4(prefix), restarted=restarted)

    def _record_change(
        self, prefix: GuidPrefix, name: str, kind: PeerChangeKind, reason: str | None
    ) -> None:
        """Keep the change for ``swarmctl watch`` with the peer's advertised link quality and
        how long it had been silent (its view at the event: one O(1) lookup per change)."""
        view = self._core().peer(prefix)
        self.peer_history.record(
            self._drive().now(),
            name,
            kind,
            reason=reason,
            link_quality_permille=None if view is None else view.link_quality_permille,
            last_heard=None if view is None else view.last_heard,
        )

    def _peer_traffic(self, name: str) -> None:
        """A peer's user data passed its MAC: discovery takes it as the peer's liveliness
        (the commander's leases on members ride on their readiness; docs/discovery.md)."""
        engine = self.engine
        if engine is not None:
            self._drive().call(lambda now: engine.peer_traffic(name, now))

    def _peer_ipv4(self, prefix: GuidPrefix) -> str | None:
        """The host discovery reaches the peer at (a typed engine query, O(1) by prefix):
        its first usable unicast metatraffic locator, else the UDP source it was heard from,
        else its bundle address. The data plane's port comes from the bundle."""
        view = self._core().peer(prefix)
        if view is None or view.locator is None:
            return None
        return view.locator[0]

    def _link_q(self) -> float:
        latest = self.monitor.latest
        if latest is not None:
            return latest.q
        return self.config.link.static_q
