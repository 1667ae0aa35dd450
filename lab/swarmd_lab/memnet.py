"""The one in-memory lossy datagram network on virtual time (trio's FakeNet, style.md 12).

Nodes are any sans-IO core of swarmd (``swarmd.sansio.SansIOCore`` with bytes in and
``(bytes, (host, port))`` out): the discovery engine, the data plane, the swarm core.
``MemNet`` owns a virtual clock and one event heap: deliveries, node timers and external
calls. After every input to a node it drives the node as ``swarmd.driver.Driver`` does on
the loop: send every datagram, hand every ``next_event()`` to ``on_event``, send again,
then re-arm the node's one timer at ``get_timer()``. Routing: multicast fan-out to every
subscriber, unicast by host and port. Loss, duplication and delay are drawn from the seeded
``random.Random`` passed in, so a run is a pure function of its seed: each receiver of a
datagram loses it independently (as on 802.11, where multicast frames are neither
acknowledged nor retried), and a copy that arrives may arrive twice; independent delays
reorder (counted).

No sockets, no asyncio, no wall clock: the discovery, data-plane and swarm-core tests and
the discovery benchmark run their cores through it deterministically. The simulator drives
the same protocol on its own 802.11 channel model (``swarmd_lab.sim.swarmd_node``).
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from swarmd.sansio import SansIOCore

Address = tuple[str, int]
# any core of swarmd that takes bytes from a UDP address and gives (bytes, address)
DatagramNode = SansIOCore[bytes, tuple[bytes, Address], Any]


@dataclass(frozen=True, slots=True)
class Channel:
    """Per-delivery loss and duplication probabilities; delay = delay_s + U(0, jitter_s)."""

    loss: float = 0.0
    duplicate: float = 0.0
    delay_s: float = 0.0005
    jitter_s: float = 0.0

    def __post_init__(self) -> None:
        if not (0 <= self.loss <= 1 and 0 <= self.duplicate <= 1):
            raise ValueError("channel loss and duplicate are probabilities in [0, 1]")
        if self.delay_s < 0 or self.jitter_s < 0:
            raise ValueError("channel delays must be >= 0")


@dataclass(frozen=True, slots=True)
class Transmission:
    """One datagram a node handed to the network."""

    time: float
    node: int
    target: Address
    size: int
    multicast: bool
    payload: bytes = b""
    source: Address = ("", 0)


@dataclass(slots=True)
class _Attached:
    node: DatagramNode
    host: str
    ports: frozenset[int]
    groups: frozenset[Address]
    source_port: int
    isolated: bool = False
    timer_generation: int = 0


@dataclass(frozen=True, slots=True)
class _Delivery:
    node_id: int
    payload: bytes
    source: Address


@dataclass(frozen=True, slots=True)
class _TimerFire:
    node_id: int
    generation: int


_Item = _Delivery | _TimerFire | Callable[[float], None]


@dataclass(slots=True)
class NetStats:
    sent: int = 0
    delivered: int = 0
    lost: int = 0
    reordered: int = 0  # deliveries due before an earlier one on the same (src, dst) link
    duplicated: int = 0
    unroutable: int = 0
    isolated: int = 0
    per_node_tx: dict[int, int] = field(default_factory=dict)


def is_multicast(host: str) -> bool:
    first = host.split(".", 1)[0]
    return first.isdigit() and 224 <= int(first) <= 239


class MemNet:
    """Virtual-time network joining ``DatagramNode``s; see the module docstring."""

    def __init__(
        self,
        rng: random.Random,
        channel: Channel | None = None,
        *,
        multicast_loopback: bool = True,
        now: float = 0.0,
        link_loss: Callable[[int, int], float] | None = None,
    ) -> None:
        """``link_loss(src, dst)``, when given, replaces ``channel.loss`` per node pair."""
        self.rng = rng
        self.channel = channel or Channel()
        self.multicast_loopback = multicast_loopback
        self.now = now
        self.link_loss = link_loss
        self.transmissions: list[Transmission] = []
        self.stats = NetStats()
        # each event a node emits, as (node id, event, now); the owner's Driver.on_event.
        # None: the network leaves events in the core (a test reads next_event() itself)
        self.on_event: Callable[[int, Any, float], None] | None = None
        # after each input has been driven (observers: convergence checks)
        self.after_input: Callable[[int, float], None] | None = None
        self._last_arrival: dict[tuple[int, int], float] = {}
        self._nodes: list[_Attached] = []
        self._by_host: dict[str, int] = {}
        self._heap: list[tuple[float, int, _Item]] = []
        self._seq = 0

    # ------------------------------------------------------------- topology

    def add(
        self,
        node: DatagramNode,
        host: str,
        ports: Iterable[int],
        *,
        groups: Iterable[Address] = (),
        source_port: int | None = None,
    ) -> int:
        """Attach ``node`` at ``host``, listening on ``ports`` and multicast ``groups``."""
        if host in self._by_host:
            raise ValueError(f"host {host} is already attached")
        port_set = frozenset(ports)
        if not port_set:
            raise ValueError("a node must listen on at least one port")
        node_id = len(self._nodes)
        self._nodes.append(
            _Attached(
                node,
                host,
                port_set,
                frozenset(groups),
                source_port if source_port is not None else min(port_set),
            )
        )
        self._by_host[host] = node_id
        self.stats.per_node_tx[node_id] = 0
        self.poke(node_id)
        return node_id

    def node(self, node_id: int) -> DatagramNode:
        return self._nodes[node_id].node

    def __len__(self) -> int:
        return len(self._nodes)

    def replace(self, node_id: int, node: DatagramNode) -> None:
        """A node's process restarts: ``node`` takes its place (address, ports, groups); the
        old node's timer is dropped."""
        self._nodes[node_id].node = node
        self.poke(node_id)

    def payloads(self) -> list[tuple[bytes, Address, Address]]:
        """Every datagram handed to the network, as (payload, source, target): what a
        sniffer on the medium would record."""
        return [(t.payload, t.source, t.target) for t in self.transmissions]

    def isolate(self, node_id: int, isolated: bool = True) -> None:
        """Cut a node off (it still sends; nothing it sends or is sent reaches anyone)."""
        self._nodes[node_id].isolated = isolated

    # ---------------------------------------------------------------- clock

    def call_at(self, when: float, fn: Callable[[float], None]) -> None:
        """Run ``fn(now)`` at virtual time ``when`` (external inputs: link updates, joins)."""
        self._push(when, fn)

    def poke(self, node_id: int) -> None:
        """Drive a node after an input (a delivery, its timer, a call from outside): send,
        dispatch its events, send again (a handler may have given it more to do), until no
        event is left; then re-arm its one timer."""
        attached = self._nodes[node_id]
        node = attached.node
        on_event = self.on_event
        while True:
            for payload, target in node.datagrams_to_send():
                self._transmit(node_id, payload, target)
            if on_event is None:
                break  # events stay queued in the core for its owner to read
            event = node.next_event()
            if event is None:
                break
            while event is not None:
                on_event(node_id, event, self.now)
                event = node.next_event()
        attached.timer_generation += 1
        deadline = attached.node.get_timer()
        if deadline is not None:
            self._push(max(deadline, self.now), _TimerFire(node_id, attached.timer_generation))
        if self.after_input is not None:
            self.after_input(node_id, self.now)

    def run_until(self, end: float) -> None:
        """Process every delivery and timer up to and including virtual time ``end``."""
        while self._heap and self._heap[0][0] <= end:
            when, _, item = heapq.heappop(self._heap)
            self.now = max(self.now, when)
            if isinstance(item, _Delivery):
                self._nodes[item.node_id].node.receive_datagram(item.payload, item.source, self.now)
                self.poke(item.node_id)
            elif isinstance(item, _TimerFire):
                if item.generation == self._nodes[item.node_id].timer_generation:
                    self._nodes[item.node_id].node.handle_timer(self.now)
                    self.poke(item.node_id)
            else:
                item(self.now)
        self.now = max(self.now, end)

    def next_time(self) -> float | None:
        return self._heap[0][0] if self._heap else None

    # -------------------------------------------------------------- routing

    def _push(self, when: float, item: _Item) -> None:
        self._seq += 1
        heapq.heappush(self._heap, (when, self._seq, item))

    def _transmit(self, src: int, payload: bytes, target: Address) -> None:
        sender = self._nodes[src]
        multicast = is_multicast(target[0])
        source = (sender.host, sender.source_port)
        self.transmissions.append(
            Transmission(self.now, src, target, len(payload), multicast, payload, source)
        )
        self.stats.sent += 1
        self.stats.per_node_tx[src] += 1
        if multicast:
            receivers = [
                i
                for i, n in enumerate(self._nodes)
                if target in n.groups and (i != src or self.multicast_loopback)
            ]
        else:
            dst = self._by_host.get(target[0])
            if dst is None or target[1] not in self._nodes[dst].ports:
                self.stats.unroutable += 1
                return
            receivers = [dst]
        for dst in receivers:
            if dst != src and (sender.isolated or self._nodes[dst].isolated):
                self.stats.isolated += 1
                continue
            loss = 0.0 if dst == src else self._loss(src, dst)
            if loss and self.rng.random() < loss:
                self.stats.lost += 1
                continue
            copies = 1
            if dst != src and self.channel.duplicate and self.rng.random() < self.channel.duplicate:
                copies = 2
                self.stats.duplicated += 1
            for _ in range(copies):
                delay = self.channel.delay_s
                if self.channel.jitter_s:
                    delay += self.rng.uniform(0.0, self.channel.jitter_s)
                self.stats.delivered += 1
                at = self.now + delay
                last = self._last_arrival.get((src, dst), 0.0)
                if at < last:
                    self.stats.reordered += 1
                else:
                    self._last_arrival[(src, dst)] = at
                self._push(at, _Delivery(dst, payload, source))

    def _loss(self, src: int, dst: int) -> float:
        return self.link_loss(src, dst) if self.link_loss is not None else self.channel.loss
