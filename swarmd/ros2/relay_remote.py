"""The ROS 2 relay's side that faces the other drones (swarmd.ros2.relay), driven by swarmd's
authenticated discovery: a drone found (its participants announced, disposed first after a
restart of its swarmd), lost (disposed), and its relay's signed liveness word (a node
stopped, back, or restarted under the same GUIDs). Nothing here comes from the air
unauthenticated.
"""

from __future__ import annotations

import math
from typing import Final

from swarmd.bundle.ros2 import Ros2Participant
from swarmd.ros2.relay_announce import Announcer
from swarmd.ros2.relay_events import RemoteNodeLiveness, RemoteParticipantsRelayed
from swarmd.ros2.relay_state import RemoteDrone
from swarmd.rtps.types import GuidPrefix

# A drone's liveness word (PID 0x8A06) is acted on at most once per this interval. Its
# swarmd signs what it likes about its own nodes, and a captured member changed its word on
# every DATA(p) (4 a datagram, 20 datagrams a second): each change disposed or announced its
# nodes again at every local node of every drone, 80 re-matches a second (review 18). A
# change within the interval is held, the latest word acted on at its end: late, never lost
# (a restart count is compared with the last word acted on, so the lives in between are not
# missed). An honest relay's changes reach the air with the engine's pulled-in multicast, at
# most one per retransmit_min_gap_s (0.5 s) (swarmd.discovery.engine ``set_ros2_alive``), so
# they are not held, but one that reaches a drone sooner (a directed DATA(p), a start-up
# announcement), and that by less than 0.25 s.
#
# Over time, the lives a word brings (a node back, or restarted under the same GUIDs: each
# a re-match at every local node) are damped as discovery damps the drone's own restarts
# and returns (swarmd.lives, RFC 2439; review 18b): one penalty per drone, +1 per word
# acted on that brings a life, halved every minute; above the limit such a word is held
# until the penalty has decayed back to it, at most FLAP_HOLD_MAX_S (24.9 s), the latest
# word winning. Spaced alone, a captured member's churn cost 240 re-matches a minute; now
# the first 4 and one per 24.9 s after. A word that only stops nodes is no life (as a
# dispose is none in discovery): it waits for the interval only, so a stopped node's
# writers stop at once; a stop can only follow a life acted on. Nor is a word heard while
# swarmd has lost the drone: it re-matches nothing, it only sets which of its nodes the
# drone's return announces, and that return is discovery's (a life discovery damps, after
# the drone's own dispose). The engine reports a returning drone's word before it finds
# the drone, so charged, it cost an honest fly-out a free life (h-tidy18).
LIVENESS_MIN_INTERVAL_S: Final = 0.25


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
        proxies of the earlier life (swarmd.ros2.relay, "A restart under the same GUIDs").
        Its relay restarted too: its word starts afresh, as a new relay's does (all nodes
        alive, restart counts 0), so the one kept is dropped (``_new_life``)."""
        remote = self._remote_by_drone.get(drone)
        if not remote or address is None:
            return
        known = self._present.get(drone)
        if known is not None and known.address == address and not restarted:
            return
        self._present[drone] = RemoteDrone(drone, address, now)
        again = restarted and known is not None
        announced = self._alive_remote(drone) if again else []
        if restarted:
            self._new_life(drone)
        self._events.append(RemoteParticipantsRelayed(drone, len(remote), up=True, restarted=again))
        self._send_graph_spdp(None)
        for p in self._alive_remote(drone):
            if p in announced:
                self._send_dispose(p)
            self._send_alive(p, address, now)
            if self.graph is not None:
                self.graph.publish(GuidPrefix(p.guid_prefix), now)
        if self._next_renewal is None:
            self._next_renewal = now + self.period_s

    def _new_life(self, drone: str) -> None:
        """``drone``'s swarmd restarted (``PeerRestarted``, discovery's spacing and damping
        passed): forget its relay's word, so the new life's first word (the engine reports
        it, and after the restart: swarmd.discovery.receive) is its baseline. Its counts
        start again at 0 with its relay, and a change from the old life's counts is no
        restart of its nodes: the restart's own re-match (``peer_discovered``) has made
        their proxies go already. Kept as the old life's, that word re-matched every node
        whose count was not 0 a second time and added to the drone's penalty (h-restartword18).
        What a captured member cannot gain: the penalty and the spacing are kept (a word
        after the restart that brings a life is damped as any), and the word held for the
        old life is dropped only because this re-match, damped by discovery, covers it."""
        self._remote_alive.pop(drone, None)
        self._remote_restarts.pop(drone, None)
        self._liveness_held.pop(drone, None)

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
        drone's participants are ignored, missing ones are "not alive". Acted on at most
        once per ``LIVENESS_MIN_INTERVAL_S`` per drone, and a word that brings a life not
        while the drone's penalty holds it (``LifeDamping``): held, the latest word acted
        on when due (``release_liveness``). While swarmd has lost the drone a word is
        spaced only: it moves no node, and is what its return announces."""
        remote = self._remote_by_drone.get(drone)
        if not remote:
            self.counters["liveness_unknown_drone"] += 1
            return
        if now < self._liveness_ready_at(drone, remote, alive):
            self._liveness_held[drone] = alive  # the latest one wins
            spaced = now < self._liveness_acted.get(drone, -LIVENESS_MIN_INTERVAL_S) + (
                LIVENESS_MIN_INTERVAL_S
            )
            self.counters["remote_liveness_held" if spaced else "remote_liveness_damped"] += 1
            return
        self._liveness_held.pop(drone, None)
        self._act_on_liveness(drone, remote, alive, now)

    def liveness_due(self) -> float | None:
        """When the earliest held liveness word is acted on."""
        return min(
            (
                self._liveness_ready_at(d, self._remote_by_drone[d], word)
                for d, word in self._liveness_held.items()
            ),
            default=None,
        )

    def release_liveness(self, now: float) -> None:
        """Act on the held words that are due."""
        due = [
            d
            for d, word in self._liveness_held.items()
            if now >= self._liveness_ready_at(d, self._remote_by_drone[d], word)
        ]
        for drone in due:
            alive = self._liveness_held.pop(drone)
            self._act_on_liveness(drone, self._remote_by_drone[drone], alive, now)

    def _liveness_ready_at(self, drone: str, remote: list[Ros2Participant], alive: bytes) -> float:
        """When ``drone``'s word ``alive`` may be acted on: the interval after the last word
        acted on, and, if it brings a life while swarmd has the drone, the end of the
        drone's hold (held while lost, it would keep a node that came back from the
        drone's return, up to ``FLAP_HOLD_MAX_S``)."""
        acted = self._liveness_acted.get(drone)
        ready = -math.inf if acted is None else acted + LIVENESS_MIN_INTERVAL_S
        if drone in self._present and any(
            up for _i, up, _restarted in self._liveness_changes(drone, remote, alive)
        ):
            ready = max(ready, self._liveness_lives.reuse_at(self._drone_index[drone]))
        return ready

    def _liveness_changes(
        self, drone: str, remote: list[Ros2Participant], alive: bytes
    ) -> list[tuple[int, bool, bool]]:
        """(participant index, up, restarted) for each of ``drone``'s participants that the
        word ``alive`` moves from the last word acted on: stopped, back (up), or a new life
        of a node that was and is alive (up and restarted: its proxies must go)."""
        new, restarts = _decode_word(alive, len(remote))
        old = self._remote_alive.get(drone, (True,) * len(remote))
        old_restarts = self._remote_restarts.get(drone)
        changes = []
        for i, (was, up) in enumerate(zip(old, new, strict=True)):
            restarted = (
                was
                and up
                and restarts is not None
                and old_restarts is not None
                and restarts[i] != old_restarts[i]
            )
            if was != up or restarted:
                changes.append((i, up, restarted))
        return changes

    def _act_on_liveness(
        self, drone: str, remote: list[Ros2Participant], alive: bytes, now: float
    ) -> None:
        """``peer_liveness``'s work. A word that moved a node starts the interval; one that
        brought a life while swarmd has the drone adds to the drone's penalty. While it is
        lost the word only sets what is announced when swarmd finds it (a re-match that is
        discovery's return: the engine reports a returning drone's word before it is found,
        swarmd.discovery.receive ``_heard``), so it re-matches nothing and costs no penalty
        (h-tidy18: it cost an honest fly-out one of its free word lives)."""
        changes = self._liveness_changes(drone, remote, alive)
        self._remote_alive[drone], self._remote_restarts[drone] = _decode_word(alive, len(remote))
        if not changes:
            return
        self._liveness_acted[drone] = now
        present = self._present.get(drone)
        if present is not None and any(up for _i, up, _restarted in changes):
            self._liveness_lives.honoured(self._drone_index[drone], now)
        for i, up, restarted in changes:
            p = remote[i]
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


def _decode_word(alive: bytes, count: int) -> tuple[tuple[bool, ...], tuple[int, ...] | None]:
    """A liveness word (PID 0x8A06) over ``count`` participants: the alive bits (LSB of
    byte 0 first; missing ones are not alive), then the restart counts (None when the
    word has none: a relay that sends only the bitmap)."""
    bits = tuple(i // 8 < len(alive) and bool(alive[i // 8] >> (i % 8) & 1) for i in range(count))
    counted = len(alive) >= (count + 7) // 8 + count
    restarts = tuple(alive[(count + 7) // 8 :][:count]) if counted else None
    return bits, restarts
