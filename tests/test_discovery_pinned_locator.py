"""A drone's address pinned by the bundle binds every unicast locator it signs.

Attacker 2 of docs/security.md (a captured member: its own node key, so its DATA(p) is
genuine and fresh) names a victim's address in its signed unicast locators. Every send
swarmd makes to a peer goes to the locator of that peer's latest accepted DATA(p)
(``Peer.target()``): discovery's directed frames, and, through the host the daemon reads
from the engine's view (``SwarmDaemon._peer_ipv4``: ``PeerView.locator``), the data plane's
repairs and ACKNACK answers (``SwarmApp.peer_up``) and the ROS 2 relay's announcements
(``Ros2Relay.peer_discovered``). Where the mission pins the member's ``ipv4``, a DATA(p)
whose unicast locators (metatraffic or default) name another address is refused whole as
``bad_locator``: counted, nothing moves. Without a pin the signed locator is taken, as
before (the residual of docs/security.md). Sans-IO, virtual time."""

from __future__ import annotations

from typing import Any

from swarmd_lab.testing import auth_for, drain, engine_for, make_bundle, node_ipv4, peer_datagram

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.discovery import DiscoveryEngine, PacketDropped, PeerDiscovered
from swarmd.ros2.relay import Ros2Relay
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpAlive, decode_spdp
from tests.test_ros2_relay import MISSION

BUNDLE = make_bundle(3)  # pins uav{i} at node_ipv4(i)
P = [p.guid_prefix for p in BUNDLE.participants]
A1 = (node_ipv4(1), 7412)  # member uav1's pinned address, metatraffic port
VICTIM = "10.9.9.9"  # a host of the captured member's choice, not in the swarm


def state(engine: DiscoveryEngine, now: float) -> tuple[Any, ...]:
    """Everything a datagram could move: peer rows (state, locator, lease, last heard,
    locator lists), the foreign table, the timers (lease renewals), the phase."""
    return (engine.peers(), engine.foreign(now), engine.get_timer(), engine.phase)


def refused(
    engine: DiscoveryEngine, data: bytes, source: tuple[str, int], now: float
) -> dict[str, int]:
    """Feed ``data``; assert it moved nothing and sent nothing; the drop counters that moved."""
    drain(engine)
    before = state(engine, now)
    counts = dict(engine.counters()["dropped"])
    engine.receive_datagram(data, source, now)
    assert state(engine, now) == before
    assert all(isinstance(e, PacketDropped) for e in drain(engine))
    assert engine.datagrams_to_send() == []
    after = engine.counters()["dropped"]
    return {k: v - counts.get(k, 0) for k, v in after.items() if v != counts.get(k, 0)}


def victim_variants(auth_index: int = 1, *, epoch: int = 1) -> list[bytes]:
    """uav1's genuine DATA(p)s naming the victim: in both lists, in the default (user data)
    list only, in the metatraffic list only."""
    a1 = auth_for(BUNDLE, auth_index, epoch=epoch)
    return [
        peer_datagram(BUNDLE, 1, auth=a1, host=VICTIM),
        peer_datagram(BUNDLE, 1, auth=a1, default_host=VICTIM),
        peer_datagram(BUNDLE, 1, auth=a1, host=VICTIM, default_host=node_ipv4(1)),
    ]


def test_a_captured_members_victim_locator_is_refused_before_it_is_known() -> None:
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    for i, d in enumerate(victim_variants()):
        assert refused(e, d, A1, 0.1 + i) == {"bad_locator": 1}, i
    view = e.peer(P[1])
    assert view is not None and not view.discovered
    assert view.locator == A1  # still the bundle's address: the only target it ever had


def test_a_captured_members_victim_locator_renews_and_moves_nothing_once_known() -> None:
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    a1 = auth_for(BUNDLE, 1, epoch=5)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    assert any(isinstance(x, PeerDiscovered) for x in drain(e))
    # the same member, later, in the same life (a fresh counter) and in a new life
    for epoch in (5, 6):
        a = a1 if epoch == 5 else auth_for(BUNDLE, 1, epoch=epoch)
        for d in (
            peer_datagram(BUNDLE, 1, auth=a, host=VICTIM),
            peer_datagram(BUNDLE, 1, auth=a, default_host=VICTIM),
            peer_datagram(BUNDLE, 1, auth=a, host=VICTIM, destination=P[0]),
        ):
            assert refused(e, d, (VICTIM, 7412), 2.0) == {"bad_locator": 1}
    view = e.peer(P[1])
    assert view is not None and view.discovered
    assert view.locator == A1 and view.last_heard == 0.1 and view.epoch == 5
    assert [str(x) for x in view.default_unicast_locators] == [f"udp/{node_ipv4(1)}:7413"]


def test_nothing_the_engine_sends_ever_goes_to_the_victim() -> None:
    """Two minutes of virtual time with the captured member's signed DATA(p)s (multicast
    and directed at the receiver) every second: every datagram the receiver sends goes to
    the pinned address or the multicast group, and the host the daemon hands the data
    plane and the relay (the view's locator) is the pinned one throughout."""
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    a1 = auth_for(BUNDLE, 1, epoch=5)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    sent: list[tuple[str, int]] = [to for _, to in e.datagrams_to_send()]
    now, next_attack, attacks = 0.1, 1.0, 0
    while now < 120.0:
        timer = e.get_timer()
        if timer is None or timer > next_attack:
            now = next_attack
            d = peer_datagram(
                BUNDLE, 1, auth=a1, host=VICTIM, destination=P[0] if attacks % 2 else None
            )
            e.receive_datagram(d, (VICTIM, 7412), now)
            attacks += 1
            next_attack += 1.0
        else:
            now = timer
            e.handle_timer(now)
        sent += [to for _, to in e.datagrams_to_send()]
        drain(e)
        view = e.peer(P[1])
        assert view is not None and view.locator is not None and view.locator[0] == A1[0]
    assert attacks >= 100 and e.counters()["dropped"]["bad_locator"] == attacks
    assert sent  # the engine kept talking (to the group, and to uav1 at its pinned address)
    assert not [to for to in sent if to[0] == VICTIM]


def test_the_pinned_address_at_another_port_is_accepted() -> None:
    """The pin binds the address, not the port (DDSI-RTPS 9.6.1.1: the well-known ports are
    derived from a participant id the participant picks; any port on the pinned address
    reaches only the member's own host)."""
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    a1 = auth_for(BUNDLE, 1)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1, metatraffic_port=17412), A1, 0.1)
    view = e.peer(P[1])
    assert view is not None and view.discovered and view.locator == (node_ipv4(1), 17412)


def test_without_a_pin_the_signed_locator_is_taken_as_before() -> None:
    """The residual (docs/security.md): a bundle without ``ipv4`` for the member (DHCP)
    leaves its address to what it signs."""
    bundle = make_bundle(3, with_ipv4=False)
    e = engine_for(bundle, 0, auth=auth_for(bundle, 0))
    e.receive_datagram(peer_datagram(bundle, 1, auth=auth_for(bundle, 1), host=VICTIM), A1, 0.1)
    view = e.peer(bundle.participants[1].guid_prefix)
    assert view is not None and view.discovered and view.locator == (VICTIM, 7412)


def test_the_ros2_relay_never_announces_a_drone_at_the_victim() -> None:
    """The relay's core fed as the daemon feeds it: on each PeerDiscovered, the host of the
    engine's view. The mission of the ROS 2 tests pins every drone; drone-1, captured,
    signs the victim's address: the relay announces it nowhere until it signs its pinned
    one, and then at that address."""
    bundle = build_dev_bundle(parse_mission(MISSION)).bundle
    lead, drone1 = bundle.participant("lead"), bundle.participant("drone-1")
    e = engine_for(bundle, lead.index, auth=auth_for(bundle, lead.index))
    relay = Ros2Relay(
        bundle_ros2_participants(bundle),
        "lead",
        domain_id=0,
        lease_s=8.0,
        relay_port=7399,
        epoch=1_790_000_000,
    )
    a = auth_for(bundle, drone1.index)
    source = (VICTIM, bundle.metatraffic_port(drone1))
    announced: list[bytes] = []

    def step(data: bytes, now: float) -> None:
        e.receive_datagram(data, source, now)
        for event in drain(e):
            if isinstance(event, PeerDiscovered):
                view = e.peer(event.guid_prefix)
                host = None if view is None or view.locator is None else view.locator[0]
                relay.peer_discovered(event.name, host, now)
        announced.extend(d for d, _ in relay.datagrams_to_send())

    step(peer_datagram(bundle, drone1.index, auth=a, host=VICTIM), 0.1)
    step(peer_datagram(bundle, drone1.index, auth=a, default_host=VICTIM), 0.2)
    assert announced == []
    step(peer_datagram(bundle, drone1.index, auth=a), 0.3)
    assert announced
    for d in announced:
        _, samples = decode_spdp(d)
        for s in samples:
            assert isinstance(s, SpdpAlive)
            for loc in s.participant.default_unicast_locators:
                assert loc.address == Locator.udpv4(drone1.ipv4 or "", loc.port).address
