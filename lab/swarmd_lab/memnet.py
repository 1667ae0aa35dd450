"""An in-memory lossy datagram network on virtual time (trio's FakeNet, for sans-IO cores).

Nodes are anything with the engine's four I/O methods (``DatagramNode``). ``MemNet`` owns
a virtual clock and one event heap: deliveries and node timers. After every input to a node
it collects the node's datagrams, routes them (multicast fan-out to every subscriber,
unicast by host and port), and re-arms the node's one timer at ``get_timer()``. Loss,
duplication and delay are drawn from the seeded ``random.Random`` passed in, so a run is a
pure function of its seed. Each receiver of a multicast loses it independently, as on
802.11 where multicast frames are neither acknowledged nor retried.

No sockets, no asyncio, no wall clock: the discovery tests, the benchmark and the
simulator run hundreds of engines through it deterministically.
"""

from __future__ import annotations

import heapq
import random
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Protocol

Address = tuple[str, int]


class DatagramNode(Protocol):
    def receive_datagram(self, data: bytes, source: Address, now: float) -> None: ...

    def handle_timer(self, now: float) -> None: ...

    def datagrams_to_send(self) -> list[tuple[bytes, Address]]: ...

    def get_timer(self) -> float | None: ...


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
    delivered: int = 0
    lost: int = 0
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
        self.after_input: Callable[[int, float], None] | None = None
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

    def isolate(self, node_id: int, isolated: bool = True) -> None:
        """Cut a node off (it still sends; nothing it sends or is sent reaches anyone)."""
        self._nodes[node_id].isolated = isolated

    # ---------------------------------------------------------------- clock

    def call_at(self, when: float, fn: Callable[[float], None]) -> None:
        """Run ``fn(now)`` at virtual time ``when`` (external inputs: link updates, joins)."""
        self._push(when, fn)

    def poke(self, node_id: int) -> None:
        """Collect a node's output and re-arm its timer after an input given from outside."""
        attached = self._nodes[node_id]
        for payload, target in attached.node.datagrams_to_send():
            self._transmit(node_id, payload, target)
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
        self.transmissions.append(Transmission(self.now, src, target, len(payload), multicast))
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
        source = (sender.host, sender.source_port)
        for dst in receivers:
            if dst != src and (sender.isolated or self._nodes[dst].isolated):
                self.stats.isolated += 1
                continue
            loss = 0.0 if dst == src else self._loss(src, dst)
            copies = 1
            if dst != src and self.channel.duplicate and self.rng.random() < self.channel.duplicate:
                copies = 2
                self.stats.duplicated += 1
            for _ in range(copies):
                if loss and self.rng.random() < loss:
                    self.stats.lost += 1
                    continue
                delay = self.channel.delay_s
                if self.channel.jitter_s:
                    delay += self.rng.uniform(0.0, self.channel.jitter_s)
                self.stats.delivered += 1
                self._push(self.now + delay, _Delivery(dst, payload, source))

    def _loss(self, src: int, dst: int) -> float:
        return self.link_loss(src, dst) if self.link_loss is not None else self.channel.loss
