"""The ROS 2 relay's side that faces the other drones (swarmd.ros2.relay), driven by swarmd's
authenticated discovery: a drone found (its participants announced, disposed first after a
restart of its swarmd), lost (disposed), and its relay's signed liveness word (a node
stopped, back, or restarted under the same GUIDs). Nothing here comes from the air
unauthenticated.
"""

from __future__ import annotations

from swarmd.ros2.relay_announce import Announcer
from swarmd.ros2.relay_events import RemoteNodeLiveness, RemoteParticipantsRelayed
from swarmd.ros2.relay_state import RemoteDrone
from swarmd.rtps.types import GuidPrefix


class RemoteDrones(Announcer):
    """The relay's rows of the other drones' participants, moved by discovery's events."""

    def peer_discovered(
        self, drone: str, address: str | None, now: float, *, restarted: bool = False
    ) -> None:
        """swarmd's discovery has ``drone`` at ``address``: relay its ROS 2 participants to
        every local one now, and from then on within their lease. ``restarted``: its swarmd
        restarted (the engine's ``PeerRestarted``: a higher epoch in an authenticated
        DATA(p), never anything else): its participants, announced before, are disposed at
        the local nodes and announced again at once, so their readers drop the writer
        proxies of the earlier life (swarmd.ros2.relay, "A restart under the same GUIDs")."""
        remote = self._remote_by_drone.get(drone)
        if not remote or address is None:
            return
        known = self._present.get(drone)
        if known is not None and known.address == address and not restarted:
            return
        self._present[drone] = RemoteDrone(drone, address, now)
        again = restarted and known is not None
        self._events.append(RemoteParticipantsRelayed(drone, len(remote), up=True, restarted=again))
        self._send_graph_spdp(None)
        for p in self._alive_remote(drone):
            if again:
                self._send_dispose(p)
            self._send_alive(p, address, now)
            if self.graph is not None:
                self.graph.publish(GuidPrefix(p.guid_prefix), now)
        if self._next_renewal is None:
            self._next_renewal = now + self.period_s

    def peer_lost(self, drone: str, now: float) -> None:
        """swarmd lost ``drone``: dispose its ROS 2 participants at every local node, so
        their writers stop sending to it at once rather than after the lease."""
        if self._present.pop(drone, None) is None:
            return
        remote = self._remote_by_drone.get(drone, [])
        self._events.append(RemoteParticipantsRelayed(drone, len(remote), up=False))
        for p in remote:
            self._send_dispose(p)
        if not self._present:
            self._next_renewal = None

    def peer_liveness(self, drone: str, alive: bytes, now: float) -> None:
        """``drone``'s relay says which of its ROS 2 participants are alive (PID 0x8A06 of
        its swarmd's DATA(p), which the discovery engine accepted: authenticated). A node
        that stopped is disposed (DATA(p[UD])) at every local node, one that is back is
        announced again at once; both only while swarmd has the drone. Bits past the
        drone's participants are ignored, missing ones are "not alive"."""
        remote = self._remote_by_drone.get(drone)
        if not remote:
            self.counters["liveness_unknown_drone"] += 1
            return
        new = tuple(
            i // 8 < len(alive) and bool(alive[i // 8] >> (i % 8) & 1) for i in range(len(remote))
        )
        # the restart counts after the bitmap (a relay that sends none: no restart is seen)
        counted = len(alive) >= (len(remote) + 7) // 8 + len(remote)
        restarts = tuple(alive[(len(remote) + 7) // 8 :][: len(remote)]) if counted else None
        old = self._remote_alive.get(drone, (True,) * len(remote))
        old_restarts = self._remote_restarts.get(drone)
        self._remote_alive[drone] = new
        self._remote_restarts[drone] = restarts
        present = self._present.get(drone)
        for i, (p, was, up) in enumerate(zip(remote, old, new, strict=True)):
            # a new life of a node that was and is alive: its proxies must go (DATA(p[UD]))
            restarted = (
                was
                and up
                and restarts is not None
                and old_restarts is not None
                and restarts[i] != old_restarts[i]
            )
            if was == up and not restarted:
                continue
            self._events.append(RemoteNodeLiveness(drone, p.node.name, up, restarted))
            if restarted:
                self.counters["remote_restarts"] += 1
            if present is None:
                continue  # announced (or not) when swarmd finds the drone
            if up:
                if restarted:
                    self._send_dispose(p)
                self._send_graph_spdp(None)
                self._send_alive(p, present.address, now)
                if self.graph is not None:
                    self.graph.publish(GuidPrefix(p.guid_prefix), now)
            else:
                self._send_dispose(p)
