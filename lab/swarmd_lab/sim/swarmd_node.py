"""swarmd's real ``DiscoveryEngine`` on the simulated channel.

The adapter is the simulator's version of the daemon's ``Driver`` (the same driving
protocol, ``swarmd.sansio.SansIOCore``, in the same order): datagrams in go to
``receive_datagram``, the single deadline from ``get_timer`` becomes one virtual-clock
timer, and whatever the engine queues goes into the node's MAC queue with its real size.
Addresses are the bundle's: ``10.0.x.y`` maps to a node index, the SPDP group to multicast.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field

from swarmd.bundle.model import Bundle
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import PeerDiscovered, PeerLost
from swarmd.discovery.inputs import LinkSample
from swarmd.link.quality import q_from_snr
from swarmd_lab.sim.channel import MULTICAST, Datagram, Kind
from swarmd_lab.sim.clock import Timer
from swarmd_lab.sim.modelled_auth import ModelledSpdpAuth
from swarmd_lab.sim.node import NodeContext, SimNode


@dataclass(slots=True)
class SwarmdShared:
    """What all swarmd nodes of one run share: the bundle and the address plan."""

    bundle: Bundle
    config: EngineConfig
    ip_to_index: dict[str, int] = field(default_factory=dict)
    ip_of: list[str] = field(default_factory=list)
    name_to_index: dict[str, int] = field(default_factory=dict)
    # the UDP source address a receiver sees for a datagram from node i (one tuple per
    # node, not one per reception: a multicast fans out to N - 1 receivers)
    source_of: list[tuple[str, int]] = field(default_factory=list)
    # every engine seals and checks with ModelledSpdpAuth (protocol "swarmd-auth")
    modelled_auth: bool = False
    # the run's nodes by index (each registers itself): the multicast fan-out's loop
    nodes: list[SwarmdNode] = field(default_factory=list)

    @classmethod
    def of(cls, bundle: Bundle, config: EngineConfig) -> SwarmdShared:
        ips = [p.ipv4 or "" for p in bundle.participants]
        names = {p.name: p.index for p in bundle.participants}
        sources = [(ips[p.index], bundle.metatraffic_port(p)) for p in bundle.participants]
        return cls(bundle, config, {ip: i for i, ip in enumerate(ips)}, ips, names, sources)


class SwarmdNode(SimNode):
    """One drone running ``DiscoveryEngine`` (constructed when the drone starts)."""

    def __init__(self, ctx: NodeContext, shared: SwarmdShared, link: LinkSample) -> None:
        super().__init__(ctx)
        self._shared = shared
        self._link = link
        self.engine: DiscoveryEngine | None = None
        self._timer: Timer | None = None
        self._timer_at: float | None = None
        self._name_to_index = shared.name_to_index
        self._source_of = shared.source_of
        assert len(shared.nodes) == self.index  # noqa: S101 - built in index order
        shared.nodes.append(self)

    def start(self, now: float) -> None:
        shared = self._shared
        p = shared.bundle.participants[self.index]
        self.engine = DiscoveryEngine(
            shared.bundle,
            p.name,
            config=shared.config,
            rng=random.Random(f"{self.ctx.seed}/engine/{self.index}"),  # noqa: S311
            now=now,
            local_ipv4=shared.ip_of[self.index],
            link=self._link,
            auth=(
                ModelledSpdpAuth(p.guid_prefix, 1, len(shared.bundle.participants))
                if shared.modelled_auth
                else None
            ),
        )
        self._pump(now)

    def receive(self, dgram: Datagram, now: float) -> None:
        engine = self.engine
        if engine is None:
            return  # not powered up yet: the radio is off
        payload = dgram.payload
        assert isinstance(payload, bytes)  # noqa: S101 - swarmd nodes send bytes only
        # the engine decodes a multicast once for all receivers (its decode memo is keyed
        # by the payload, and every receiver gets this same bytes object)
        engine.receive_datagram(payload, self._source_of[dgram.src], now)
        self._pump(now)

    def receive_each(
        self, nodes: Sequence[SimNode], receivers: list[int], dgram: Datagram, now: float
    ) -> None:
        # ``receive`` for each receiver in one loop (~3M receptions per 1000-drone run):
        # the payload and its source are the same for all of them
        payload = dgram.payload
        assert isinstance(payload, bytes)  # noqa: S101 - swarmd nodes send bytes only
        source = self._source_of[dgram.src]
        swarm = self._shared.nodes
        for j in receivers:
            node = swarm[j]
            engine = node.engine
            if engine is None:
                continue  # not powered up yet: the radio is off
            engine.receive_datagram(payload, source, now)
            node._pump(now)

    def data_received(self, src: int, now: float) -> None:
        # the daemon feeds the data plane's verified user data to the engine the same way
        # (``DiscoveryEngine.peer_traffic``): the commander hears every member at 1 Hz
        engine = self.engine
        if engine is None:
            return
        engine.peer_traffic(self._shared.bundle.participants[src].guid_prefix, now)
        self._pump(now)

    def _on_timer(self) -> None:
        engine = self.engine
        assert engine is not None  # noqa: S101
        now = self.ctx.clock.now
        self._timer = None
        self._timer_at = None
        engine.handle_timer(now)
        self._pump(now)

    def _pump(self, now: float) -> None:
        """Drive the engine after an input as ``swarmd.driver.Driver`` and ``MemNet`` do
        (the driving protocol, ``swarmd.sansio``): send, dispatch events, send again, re-arm
        its one timer when the deadline changed. Only the channel model is the simulator's."""
        engine = self.engine
        assert engine is not None  # noqa: S101
        # runs after every reception (~10^6 per run at N = 1000): the usual answer is
        # "nothing queued, no event, same deadline", so each step is cheap when empty
        out = engine.datagrams_to_send()
        if out:
            self._transmit(engine, out)
        event = engine.next_event()
        if event is not None:
            while event is not None:
                if isinstance(event, PeerDiscovered):
                    self.ctx.ledger.discovered(self.index, self._name_to_index[event.name], now)
                elif isinstance(event, PeerLost):
                    self.ctx.ledger.lost(self.index, self._name_to_index[event.name], now)
                event = engine.next_event()
            out = engine.datagrams_to_send()  # send again, as Driver and MemNet do
            if out:
                self._transmit(engine, out)
        deadline = engine.get_timer()
        if deadline == self._timer_at:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = deadline
        self._timer = None if deadline is None else self.ctx.clock.call_at(deadline, self._on_timer)

    def _transmit(self, engine: DiscoveryEngine, out: list[tuple[bytes, tuple[str, int]]]) -> None:
        group = engine.spdp_multicast[0]
        for payload, (host, _port) in out:
            if host == group:
                dst = MULTICAST
            else:
                found = self._shared.ip_to_index.get(host)
                if found is None:
                    continue  # an address outside the swarm: nobody on the channel owns it
                dst = found
            self.ctx.send(
                Datagram(
                    self.index, dst, len(payload), Kind.DISCOVERY, payload, engine.metatraffic_port
                )
            )


def link_sample_for(snr_db: float) -> LinkSample:
    """What the drone's link monitor would report for a typical neighbour SNR (paper eq. 2)."""
    return LinkSample(q=q_from_snr(snr_db), snr_db=snr_db, source="sim")
