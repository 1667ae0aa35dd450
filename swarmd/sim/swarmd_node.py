"""swarmd's real ``DiscoveryEngine`` on the simulated channel.

The adapter is the simulator's version of the daemon's thin asyncio adapter: datagrams in
go to ``receive_datagram``, the single deadline from ``get_timer`` becomes one virtual-clock
timer, and whatever the engine queues goes into the node's MAC queue with its real size.
Addresses are the bundle's: ``10.0.x.y`` maps to a node index, the SPDP group to multicast.
"""

from __future__ import annotations

import contextlib
import random
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Final

import swarmd.discovery.engine as engine_module
from swarmd.bundle.model import Bundle
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import PeerDiscovered, PeerLost
from swarmd.link.quality import q_from_snr
from swarmd.link.sample import LinkSample
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.message import Header
from swarmd.rtps.spdp import SpdpSample, decode_spdp
from swarmd.sim.channel import MULTICAST, Datagram, Kind
from swarmd.sim.clock import Timer
from swarmd.sim.node import NodeContext, SimNode

# decoded datagrams kept for reuse; one multicast reaches all N-1 receivers back to back
DECODE_MEMO_ENTRIES: Final = 64


@dataclass(slots=True)
class SwarmdShared:
    """What all swarmd nodes of one run share: the bundle and the address plan."""

    bundle: Bundle
    config: EngineConfig
    ip_to_index: dict[str, int] = field(default_factory=dict)
    ip_of: list[str] = field(default_factory=list)

    @classmethod
    def of(cls, bundle: Bundle, config: EngineConfig) -> SwarmdShared:
        ips = [p.ipv4 or "" for p in bundle.participants]
        return cls(bundle, config, {ip: i for i, ip in enumerate(ips)}, ips)


class SwarmdNode(SimNode):
    """One drone running ``DiscoveryEngine`` (constructed when the drone starts)."""

    def __init__(self, ctx: NodeContext, shared: SwarmdShared, link: LinkSample) -> None:
        super().__init__(ctx)
        self._shared = shared
        self._link = link
        self.engine: DiscoveryEngine | None = None
        self._timer: Timer | None = None
        self._timer_at: float | None = None
        self._name_to_index = {p.name: p.index for p in shared.bundle.participants}

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
        )
        self._pump(now)

    def receive(self, dgram: Datagram, now: float) -> None:
        engine = self.engine
        if engine is None:
            return  # not powered up yet: the radio is off
        payload = dgram.payload
        assert isinstance(payload, bytes)  # noqa: S101 - swarmd nodes send bytes only
        source = (self._shared.ip_of[dgram.src], dgram.port)
        engine.receive_datagram(payload, source, now)
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
        """Collect the engine's datagrams and events, re-arm its one timer."""
        engine = self.engine
        assert engine is not None  # noqa: S101
        ctx = self.ctx
        group = engine.spdp_multicast[0]
        for payload, (host, _port) in engine.datagrams_to_send(now):
            if host == group:
                dst = MULTICAST
            else:
                found = self._shared.ip_to_index.get(host)
                if found is None:
                    continue  # an address outside the swarm: nobody on the channel owns it
                dst = found
            ctx.send(
                Datagram(
                    self.index, dst, len(payload), Kind.DISCOVERY, payload, engine.metatraffic_port
                )
            )
        while (event := engine.next_event()) is not None:
            if isinstance(event, PeerDiscovered):
                ctx.ledger.discovered(self.index, self._name_to_index[event.name], now)
            elif isinstance(event, PeerLost):
                ctx.ledger.lost(self.index, self._name_to_index[event.name], now)
        deadline = engine.get_timer()
        if deadline == self._timer_at:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = deadline
        self._timer = None if deadline is None else ctx.clock.call_at(deadline, self._on_timer)


def link_sample_for(snr_db: float) -> LinkSample:
    """What the drone's link monitor would report for a typical neighbour SNR (paper eq. 2)."""
    return LinkSample(q=q_from_snr(snr_db), snr_db=snr_db, source="sim")


_DecodeResult = tuple[Header, list[SpdpSample]] | DecodeError


@contextlib.contextmanager
def shared_decode() -> Iterator[None]:
    """Decode each datagram once per run instead of once per receiver.

    On a real channel the N-1 receivers of a multicast decode it in parallel on N CPUs; the
    simulator runs them one after another on one, so it memoises the pure ``decode_spdp``
    (keyed by the bytes object, whose hash Python caches) for the engines it drives. The
    engine never mutates what the decoder returns, so results are unchanged.
    """
    original = engine_module.decode_spdp  # type: ignore[attr-defined]
    memo: dict[bytes, _DecodeResult] = {}

    def memo_decode(datagram: bytes) -> tuple[Header, list[SpdpSample]]:
        hit = memo.get(datagram)
        if hit is None:
            try:
                hit = decode_spdp(datagram)
            except DecodeError as exc:
                hit = exc
            if len(memo) >= DECODE_MEMO_ENTRIES:
                memo.pop(next(iter(memo)))
            memo[datagram] = hit
        if isinstance(hit, DecodeError):
            raise hit
        return hit

    engine_module.decode_spdp = memo_decode  # type: ignore[attr-defined]
    try:
        yield
    finally:
        engine_module.decode_spdp = original  # type: ignore[attr-defined]
