"""Test and simulation helpers: a synthetic bundle without the bundle builder.

``make_bundle(n)`` builds the ``Bundle`` a mission with one commander (index 0) and n - 1
members would yield: GUID prefixes from ``derive_guid_prefix``, endpoint entity ids from
``endpoint_entity_id``, topics ``swarm/ready`` (members write, the commander reads) and
``swarm/command`` (the commander writes, members read). Used by the discovery, daemon and
simulator tests; never by the daemon itself.
"""

from __future__ import annotations

import hashlib
import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.auth.spdp import PLACEHOLDER, SpdpAuth
from swarmd.bundle.keys import dev_node_keys
from swarmd.bundle.model import (
    Bundle,
    DiscoveryParams,
    Durability,
    Endpoint,
    EndpointKind,
    Participant,
    Qos,
    Reliability,
    Role,
    Topic,
    derive_guid_prefix,
    endpoint_entity_id,
)
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.digest import encode_heard
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import Event, PeerDiscovered, PeerLost
from swarmd.discovery.inputs import LinkSample
from swarmd.rtps.locator import Locator
from swarmd.rtps.ports import SPDP_MULTICAST_GROUP, spdp_multicast_port
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp, encode_spdp_dispose
from swarmd.rtps.types import Duration, GuidPrefix
from swarmd_lab.memnet import Channel, MemNet

READY = "swarm/ready"
COMMAND = "swarm/command"


def node_name(index: int) -> str:
    return f"uav{index}"


def node_ipv4(index: int) -> str:
    """10.0.x.y with y = 1..250, one address per participant index."""
    return f"10.0.{index // 250}.{index % 250 + 1}"


def make_bundle(
    n: int,
    *,
    swarm: str = "alpha",
    domain_id: int = 0,
    discovery: DiscoveryParams | None = None,
    with_ipv4: bool = True,
    content_sha256: bytes | None = None,
) -> Bundle:
    """A bundle of ``n`` participants ``uav0`` (commander) .. ``uav{n-1}`` (members)."""
    if n < 1:
        raise ValueError("a bundle needs at least one participant")
    topics = (
        Topic(READY, "swarmd::Readiness", Qos(), 0),
        Topic(COMMAND, "swarmd::Command", Qos(Reliability.RELIABLE, Durability.VOLATILE, 8), 1),
    )

    def endpoint(topic: Topic, kind: EndpointKind) -> Endpoint:
        return Endpoint(topic.name, kind, endpoint_entity_id(topic.index, kind))

    # the dev keys a dev bundle would carry: engines built on this bundle can sign and verify
    keys = [dev_node_keys(swarm, node_name(i)) for i in range(n)]
    participants = []
    for i in range(n):
        role = Role.COMMANDER if i == 0 else Role.MEMBER
        if role == Role.COMMANDER:
            eps = (
                endpoint(topics[0], EndpointKind.READER),
                endpoint(topics[1], EndpointKind.WRITER),
            )
        else:
            eps = (
                endpoint(topics[0], EndpointKind.WRITER),
                endpoint(topics[1], EndpointKind.READER),
            )
        participants.append(
            Participant(
                name=node_name(i),
                index=i,
                role=role,
                mavlink_sysid=i + 1,
                ipv4=node_ipv4(i) if with_ipv4 else None,
                guid_prefix=derive_guid_prefix(swarm, domain_id, i),
                announce_public_key=keys[i].public[0],
                endpoints=eps,
                x25519_public_key=keys[i].public[1],
            )
        )
    digest = content_sha256 or hashlib.sha256(f"bundle/{swarm}/{domain_id}/{n}".encode()).digest()
    return Bundle(
        swarm=swarm,
        domain_id=domain_id,
        discovery=discovery or DiscoveryParams(),
        topics=topics,
        participants=tuple(participants),
        content_sha256=digest,
        signing_public_key=hashlib.sha256(f"signing/{swarm}".encode()).digest(),
        dev=True,
    )


@dataclass(slots=True)
class Swarm:
    """N engines joined by a ``MemNet``, with every event they emitted (for tests and bench)."""

    bundle: Bundle
    net: MemNet
    engines: list[DiscoveryEngine]
    events: list[list[tuple[float, Event]]]  # per node: (virtual time, event)
    pairs: int = 0  # ordered (a, b) pairs where a currently has b discovered
    full_at: float | None = None  # first virtual time every pair was discovered at once
    met: set[tuple[int, int]] = field(default_factory=set)  # (a, b): a has ever heard b
    all_met_at: float | None = None  # first virtual time every pair had met
    lost: int = 0  # PeerLost events (lease expiry and disposal)
    index_of: dict[str, int] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return self.bundle.size

    def all_discovered(self) -> bool:
        return self.pairs == self.size * (self.size - 1)

    def _on_event(self, node_id: int, event: Event, now: float) -> None:
        self.events[node_id].append((now, event))
        if isinstance(event, PeerDiscovered):
            self.pairs += 1
            self.met.add((node_id, self.index_of[event.name]))
        elif isinstance(event, PeerLost):
            self.pairs -= 1
            self.lost += 1

    def _after_input(self, node_id: int, now: float) -> None:
        if self.full_at is None and self.all_discovered():
            self.full_at = now
        if self.all_met_at is None and len(self.met) == self.size * (self.size - 1):
            self.all_met_at = now

    def run_until(self, end: float) -> None:
        self.net.run_until(end)

    def tx_kinds(self) -> Counter[str]:
        """Discovery frames sent so far by kind (``counters()["tx_kind"]``: announce,
        reply, probe, renewal, ...), summed over the engines."""
        total: Counter[str] = Counter()
        for engine in self.engines:
            total.update(engine.counters()["tx_kind"])
        return total

    def restart(self, node: int, now: float, *, seed: int, q: float, epoch: int = 2) -> None:
        """Node ``node``'s process restarts at ``now``: a new authenticated engine (boot epoch
        ``epoch``, link quality ``q``, rng seeded ``seed``) takes its place on the net,
        which no longer cuts it off."""
        participant = self.bundle.participants[node]
        engine = DiscoveryEngine(
            self.bundle,
            participant.name,
            config=EngineConfig(),
            rng=random.Random(seed),  # noqa: S311 - seeded on purpose
            now=now,
            local_ipv4=node_ipv4(participant.index),
            link=LinkSample(q=q, source="static"),
            auth=auth_for(self.bundle, node, epoch=epoch, now=now),
        )
        self.engines[node] = engine
        self.net.isolate(node, False)
        self.net.replace(node, engine)
        self.net.poke(node)


def build_swarm(
    n: int,
    *,
    seed: int,
    config: EngineConfig | None = None,
    channel: Channel | None = None,
    q: float = 1.0,
    bundle: Bundle | None = None,
    start_times: list[float] | None = None,
    authenticated: bool = False,
) -> Swarm:
    """``n`` engines (``uav0``..) on one in-memory network, each given a link sample of ``q``
    when it starts (at ``start_times[i]``, default 0). One seed drives the network and, via
    derived seeds, every engine's ``random.Random``. ``authenticated``: every engine signs
    and verifies with its dev keys (``auth_for``), as daemons do."""
    bundle = bundle or make_bundle(n)
    cfg = config or EngineConfig()
    # seeded on purpose: a run is a pure function of its seed (not for cryptography)
    master = random.Random(seed)  # noqa: S311
    net = MemNet(random.Random(master.getrandbits(64)), channel)  # noqa: S311
    swarm = Swarm(bundle, net, [], [[] for _ in range(n)])
    swarm.index_of = {p.name: p.index for p in bundle.participants}
    net.on_event = swarm._on_event
    net.after_input = swarm._after_input
    seeds = [master.getrandbits(64) for _ in range(n)]
    starts = start_times or [0.0] * n

    def start(i: int) -> Callable[[float], None]:
        def go(now: float) -> None:
            p = bundle.participants[i]
            engine = DiscoveryEngine(
                bundle,
                p.name,
                config=cfg,
                rng=random.Random(seeds[i]),  # noqa: S311
                now=now,
                local_ipv4=node_ipv4(p.index),
                link=LinkSample(q=q, source="static"),
                auth=auth_for(bundle, i, now=now) if authenticated else None,
            )
            swarm.engines.append(engine)
            net.add(
                engine,
                node_ipv4(p.index),
                (engine.metatraffic_port, engine.spdp_multicast[1]),
                groups=(engine.spdp_multicast,),
                source_port=engine.metatraffic_port,
            )

        return go

    order = sorted(range(n), key=lambda i: (starts[i], i))
    if order != list(range(n)):
        raise ValueError("start_times must be non-decreasing so node ids match indices")
    for i in order:
        net.call_at(starts[i], start(i))
    return swarm


def auth_for(bundle: Bundle, index: int, *, epoch: int = 1, now: float = 0.0) -> SpdpAuth:
    """The SPDP authentication of bundle participant ``index`` with its dev keys (the bundle
    must carry dev keys, as ``make_bundle`` and dev bundles do)."""
    name = bundle.participants[index].name
    ring = KeyRing.from_bundle(bundle, name, NodeSecrets.dev(bundle.swarm, name))
    return SpdpAuth(ring, epoch, now)


def engine_for(
    bundle: Bundle,
    index: int = 0,
    *,
    seed: int = 1,
    q: float = 0.7,
    config: EngineConfig | None = None,
    now: float = 0.0,
    auth: SpdpAuth | None = None,
) -> DiscoveryEngine:
    """One engine for bundle participant ``index``, hand-driven on virtual time from
    ``now``, with a first link sample of ``q`` (no BOOT wait) and a seeded rng."""
    p = bundle.participants[index]
    return DiscoveryEngine(
        bundle,
        p.name,
        config=config or EngineConfig(),
        rng=random.Random(seed),  # noqa: S311 - seeded on purpose
        now=now,
        local_ipv4=node_ipv4(p.index),
        link=LinkSample(q=q),
        auth=auth,
    )


def drain(engine: DiscoveryEngine) -> list[Event]:
    """Every event the engine has pending, in order."""
    out = []
    while (e := engine.next_event()) is not None:
        out.append(e)
    return out


def run_to(engine: DiscoveryEngine, end: float) -> list[tuple[float, bytes, tuple[str, int]]]:
    """Fire the engine's timers up to ``end``; every datagram with its send time."""
    sent: list[tuple[float, bytes, tuple[str, int]]] = []
    while (t := engine.get_timer()) is not None and t <= end:
        engine.handle_timer(t)
        sent += [(t, d, a) for d, a in engine.datagrams_to_send()]
    return sent


def peer_datagram(
    bundle: Bundle,
    index: int,
    *,
    heard: tuple[int, ...] = (),
    sequence_number: int = 1,
    destination: GuidPrefix | None = None,
    domain_id: int | None = None,
    bundle_digest: bytes | None = None,
    lease_s: float | None = None,
    auth: SpdpAuth | None = None,
    host: str | None = None,
    default_host: str | None = None,
    metatraffic_port: int | None = None,
    ros2_alive: bytes | None = None,
) -> bytes:
    """A DATA(p) as bundle participant ``index``'s engine would send it, for hand-driven
    tests: ``heard`` lists indices, ``destination`` makes it directed (INFO_DST), ``auth``
    seals it (each call takes the next freshness), ``host`` replaces its locators' address
    (``default_host`` only its default locator's, ``metatraffic_port`` its metatraffic
    locator's port), ``ros2_alive`` its relay's alive ROS 2 participants (PID 0x8A06)."""
    p = bundle.participants[index]
    meta = bundle.metatraffic_port(p) if metatraffic_port is None else metatraffic_port
    host = host or p.ipv4 or node_ipv4(index)
    group = (SPDP_MULTICAST_GROUP, spdp_multicast_port(bundle.domain_id))
    participant = SpdpParticipant(
        p.guid_prefix,
        domain_id=bundle.domain_id if domain_id is None else domain_id,
        metatraffic_unicast_locators=(Locator.udpv4(host, meta),),
        metatraffic_multicast_locators=(Locator.udpv4(*group),),
        default_unicast_locators=(Locator.udpv4(default_host or host, bundle.user_port(p)),),
        lease_duration=Duration.from_seconds(
            bundle.discovery.lease_s if lease_s is None else lease_s
        ),
        entity_name=f"{bundle.swarm}/{p.name}",
        bundle_digest=bundle.content_sha256[:16] if bundle_digest is None else bundle_digest,
        heard=encode_heard(heard, bundle.size),
        link_quality_permille=1000,
        ros2_alive=ros2_alive,
        authenticator=None if auth is None else PLACEHOLDER,
    )
    data = encode_spdp(
        participant, sequence_number=sequence_number, timestamp=None, destination=destination
    )
    return data if auth is None else auth.seal(data)


def leave_or_return_datagram(
    bundle: Bundle, index: int, *, sequence_number: int, auth: SpdpAuth
) -> bytes:
    """A captured member flapping (its genuine key, the attacker's firmware): at an odd
    ``sequence_number`` its signed DATA(p[UD]) (it leaves: the others lose it), at an even
    one its signed DATA(p) listing nobody (it is back: the others find it again)."""
    if sequence_number % 2:
        template = encode_spdp_dispose(
            bundle.participants[index].guid_prefix,
            sequence_number=sequence_number,
            timestamp=None,
            authenticator=PLACEHOLDER,
        )
        return auth.seal(template)
    return peer_datagram(bundle, index, sequence_number=sequence_number, auth=auth)


class ScriptedSender:
    """A node of a ``Swarm``'s MemNet (or any Driver) that only sends: the scripted
    attackers and relays of the tests and benches. A subclass queues datagrams in ``_out``
    from ``handle_timer`` and keeps its next tick in ``_next`` (None once it is done, so
    every script is bounded); it hears nothing unless it overrides ``receive_datagram``."""

    def __init__(self, start: float | None) -> None:
        self._next: float | None = start
        self._out: list[tuple[bytes, tuple[str, int]]] = []

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        return None

    def handle_timer(self, now: float) -> None:
        raise NotImplementedError

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float | None:
        return self._next

    def next_event(self) -> None:
        return None
