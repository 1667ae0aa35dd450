"""What every simulated drone's protocol looks like to the simulator, and the discovery ledger.

A protocol node (swarmd's real engine behind an adapter, or a frame-level baseline model)
gets a ``NodeContext``: the virtual clock, a ``send`` into its MAC queue and the ``Ledger``
it reports discoveries to. The channel calls ``receive`` for every datagram the node's
radio decoded.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from swarmd_lab.sim.channel import Datagram
from swarmd_lab.sim.clock import VirtualClock


class Ledger:
    """Who knows whom, and since when: ``first[i, j]`` is when ``i`` first discovered ``j``.

    A pair counts as discovered while ``i`` holds ``j`` as a discovered peer with its
    endpoints matched (for swarmd: ``PeerDiscovered``; for the DDS models: SPDP and SEDP
    both complete; for zenoh: the session is open and ``j``'s declarations arrived).
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self._pairs = n * (n - 1)  # read on every discovered pair
        # known[i][j]: rows of bytes, not a numpy matrix: a run makes ~N^2 scalar lookups
        # here (every PeerDiscovered), and numpy's scalar indexing costs ~10x a bytearray's
        self.known = [bytearray(n) for _ in range(n)]
        self.first = np.full((n, n), math.nan)
        self._seen = [bytearray(n) for _ in range(n)]  # first[i, j] is set
        self.count = 0
        self.all_discovered_s: float | None = None
        self.lost_events = 0
        self._on_all: list[Callable[[float], None]] = []

    @property
    def pairs(self) -> int:
        return self._pairs

    def on_all_discovered(self, listener: Callable[[float], None]) -> None:
        """Call ``listener(now)`` once, when every pair is first discovered at once (not on
        every pair: ~10^6 of them at N = 1000)."""
        self._on_all.append(listener)

    def discovered(self, i: int, j: int, now: float) -> None:
        row = self.known[i]
        if i == j or row[j]:
            return
        row[j] = 1
        self.count += 1
        seen = self._seen[i]
        if not seen[j]:
            seen[j] = 1
            self.first[i, j] = now
        if self.count == self._pairs and self.all_discovered_s is None:
            self.all_discovered_s = now
            for listener in self._on_all:
                listener(now)

    def lost(self, i: int, j: int, now: float) -> None:
        row = self.known[i]
        if not row[j]:
            return
        row[j] = 0
        self.count -= 1
        self.lost_events += 1


@dataclass(slots=True)
class NodeContext:
    """The simulator as one node sees it."""

    index: int
    n: int
    clock: VirtualClock
    send: Callable[[Datagram], None]
    ledger: Ledger
    seed: int


class SimNode(ABC):
    """One drone's discovery protocol in the simulator."""

    def __init__(self, ctx: NodeContext) -> None:
        self.ctx = ctx
        self.index = ctx.index

    @abstractmethod
    def start(self, now: float) -> None:
        """The drone powers up at ``now``."""

    @abstractmethod
    def receive(self, dgram: Datagram, now: float) -> None:
        """The radio decoded ``dgram`` (multicast, or unicast addressed to this node)."""

    def receive_each(
        self, nodes: Sequence[SimNode], receivers: list[int], dgram: Datagram, now: float
    ) -> None:
        """``nodes[j].receive(dgram, now)`` for every ``j`` in ``receivers``, in that order:
        one multicast's fan-out (every node of a run runs this node's protocol). A protocol
        may override it with a tighter loop of the same effect."""
        for j in receivers:
            nodes[j].receive(dgram, now)

    def data_received(self, src: int, now: float) -> None:  # noqa: B027 - optional hook
        """The 1 Hz workload delivered node ``src``'s sample here (user data, not discovery).
        A protocol that takes liveliness from user data overrides this; default: nothing."""
