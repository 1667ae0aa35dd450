"""Authenticated SPDP in the discovery engine, on virtual time (issue 10, docs/security.md).

Every refusal is checked the same way: the counter for its reason moved, and nothing else
did (peer table, leases, locators, foreign table, timers, events other than a drop)."""

from __future__ import annotations

from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.testing import (
    auth_for,
    build_swarm,
    engine_for,
    make_bundle,
    node_ipv4,
    peer_datagram,
)

from swarmd.auth.budget import GLOBAL_NEW_ADDRESS_BURST
from swarmd.auth.spdp import PLACEHOLDER, SpdpAuth, authenticator_overhead, open_tail, tail_window
from swarmd.auth.tags import MAX_RECEIVER_TAGS, ReceiverTags
from swarmd.discovery import (
    DiscoveryEngine,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLocatorsChanged,
    PeerLost,
    PeerRestarted,
)
from swarmd.discovery.engine import DISPOSE_MULTICAST_COPIES, MAX_DISPOSE_UNICAST
from swarmd.discovery.events import Event
from swarmd.discovery.foreign import FOREIGN_DECODE_BURST, FOREIGN_REPORT_BURST
from swarmd.discovery.peers import MAX_FOREIGN
from swarmd.rtps.spdp import encode_spdp_dispose

BUNDLE = make_bundle(3)
P = [p.guid_prefix for p in BUNDLE.participants]
A0 = (node_ipv4(0), 7410)  # the commander uav0's metatraffic address
A1 = (node_ipv4(1), 7412)  # member uav1's metatraffic address
ATTACKER = ("10.0.0.66", 7412)


def receiver() -> DiscoveryEngine:
    return engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))


def drain(engine: DiscoveryEngine) -> list[Event]:
    out = []
    while (e := engine.next_event()) is not None:
        out.append(e)
    return out


def state(engine: DiscoveryEngine, now: float) -> tuple[Any, ...]:
    """Everything a datagram could move."""
    return (engine.peers(), engine.foreign(now), engine.get_timer(), engine.phase)


def dropped(engine: DiscoveryEngine) -> dict[str, int]:
    return {k: v for k, v in engine.counters()["dropped"].items() if v}


def refused(
    engine: DiscoveryEngine, data: bytes, source: tuple[str, int], now: float
) -> dict[str, int]:
    """Feed ``data``; assert it moved nothing; return the drop counters that moved."""
    drain(engine)
    before, counts = state(engine, now), dropped(engine)
    engine.receive_datagram(data, source, now)
    assert state(engine, now) == before
    assert all(isinstance(e, PacketDropped) for e in drain(engine))
    assert engine.datagrams_to_send() == []
    after = dropped(engine)
    return {k: v - counts.get(k, 0) for k, v in after.items() if v != counts.get(k, 0)}


def discovered(engine: DiscoveryEngine, index: int) -> bool:
    view = engine.peer(P[index])
    return view is not None and view.discovered


def test_a_signed_data_p_discovers_the_peer_with_its_epoch() -> None:
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=5)), A1, 0.1)
    (event,) = [x for x in drain(e) if isinstance(x, PeerDiscovered)]
    assert event.name == "uav1" and event.epoch == 5
    view = e.peer(P[1])
    assert view is not None and view.epoch == 5
    assert [p["epoch"] for p in e.status(0.1)["peers"]] == [5, None]
    assert [str(x) for x in event.default_unicast_locators] == [f"udp/{node_ipv4(1)}:7413"]


def test_unsigned_data_p_under_a_bundle_prefix_is_refused() -> None:
    e = receiver()
    assert refused(e, peer_datagram(BUNDLE, 1), A1, 0.1) == {"auth_missing": 1}


def test_replayed_data_p_is_refused_and_refreshes_nothing() -> None:
    e = receiver()
    d = peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1))
    e.receive_datagram(d, A1, 0.1)
    assert discovered(e, 1)
    assert refused(e, d, A1, 5.0) == {"auth_replayed": 1}  # the lease does not move


def test_member_prefix_signed_with_another_members_key_is_refused() -> None:
    e = receiver()
    # uav2 (a captured member) signs a DATA(p) carrying uav1's prefix, and one as commander:
    # its tags are made with its own pair keys, so neither reaches a budget or Ed25519
    as_uav1 = peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 2))
    assert refused(e, as_uav1, A1, 0.1) == {"auth_bad_tag": 1}
    other = engine_for(BUNDLE, 1, auth=auth_for(BUNDLE, 1))
    as_commander = peer_datagram(BUNDLE, 0, auth=auth_for(BUNDLE, 2))
    assert refused(other, as_commander, A1, 0.1) == {"auth_bad_tag": 1}
    assert e.counters()["auth"]["verified"] == 0  # no signature was even checked


def test_unknown_prefix_is_foreign_and_never_matched() -> None:
    e = receiver()
    stranger = make_bundle(3, swarm="other")
    e.receive_datagram(peer_datagram(stranger, 1, auth=auth_for(stranger, 1)), ATTACKER, 0.1)
    assert not any(isinstance(x, PeerDiscovered) for x in drain(e))
    assert [f.reason for f in e.foreign(0.1)] == ["not_in_bundle"]
    assert all(not v.discovered for v in e.peers())


def test_dispose_moves_nothing_unless_signed_by_the_peer() -> None:
    e = receiver()
    a1 = auth_for(BUNDLE, 1, epoch=5)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    drain(e)
    plain = encode_spdp_dispose(P[1], sequence_number=9, timestamp=None)
    assert refused(e, plain, ATTACKER, 0.2) == {"auth_missing": 1}
    template = encode_spdp_dispose(
        P[1], sequence_number=9, timestamp=None, authenticator=PLACEHOLDER
    )
    forged = auth_for(BUNDLE, 2, epoch=99).seal(template)
    assert refused(e, forged, ATTACKER, 0.3) == {"auth_bad_tag": 1}
    assert discovered(e, 1)
    e.receive_datagram(a1.seal(template), A1, 0.4)
    assert [x.reason for x in drain(e) if isinstance(x, PeerLost)] == ["disposed"]


def test_loopback_multicast_and_unspecified_locators_are_refused() -> None:
    e = receiver()
    a1 = auth_for(BUNDLE, 1)
    for host in ("127.0.0.1", "239.255.0.1", "0.0.0.0", "255.255.255.255"):  # noqa: S104
        d = peer_datagram(BUNDLE, 1, auth=a1, host=host)
        assert refused(e, d, A1, 0.1) == {"bad_locator": 1}, host
    # co-hosted daemons talk over loopback: a loopback locator from a loopback source is fine
    # (where the bundle pins no address: a pin binds the locators to it, loopback or not)
    d = peer_datagram(BUNDLE, 1, auth=a1, host="127.0.0.1")
    assert refused(e, d, ("127.0.0.1", 7412), 0.2) == {"bad_locator": 1}
    unpinned = make_bundle(3, with_ipv4=False)
    e = engine_for(unpinned, 0, auth=auth_for(unpinned, 0))
    d = peer_datagram(unpinned, 1, auth=auth_for(unpinned, 1), host="127.0.0.1")
    e.receive_datagram(d, ("127.0.0.1", 7412), 0.2)
    view = e.peer(unpinned.participants[1].guid_prefix)
    assert view is not None and view.discovered


# Untagged datagrams: in a swarm larger than the tag window (MAX_RECEIVER_TAGS + 1 nodes),
# a multicast datagram may carry no tag for this receiver; those are checked under the
# address-keyed budgets of issue 10, which tagged datagrams never spend.
BIG = make_bundle(MAX_RECEIVER_TAGS + 8)
BIG_A1 = (node_ipv4(1), BIG.metatraffic_port(BIG.participants[1]))


class _WindowWithoutUav0(ReceiverTags):
    """Every multicast datagram tags the first MAX_RECEIVER_TAGS peers after the sender:
    in BIG that window never holds uav0 (the untagged path at uav0, on every datagram)."""

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        return (0, 1) if destination is not None else (0, MAX_RECEIVER_TAGS)


class _ShortWindow(ReceiverTags):
    def slots(self, destination: bytes | None) -> tuple[int, int]:
        return 0, 3


def untagged_auth(index: int, *, epoch: int = 1) -> SpdpAuth:
    auth = auth_for(BIG, index, epoch=epoch)
    auth.tags = _WindowWithoutUav0(auth.keyring)
    return auth


def big_receiver() -> DiscoveryEngine:
    return engine_for(BIG, 0, auth=auth_for(BIG, 0))


def test_untagged_datagrams_in_a_large_swarm_are_checked_under_the_address_budgets() -> None:
    e = big_receiver()
    e.receive_datagram(peer_datagram(BIG, 1, auth=untagged_auth(1)), BIG_A1, 0.1)
    view = e.peer(BIG.participants[1].guid_prefix)
    assert view is not None and view.discovered
    assert e.counters()["auth"]["untagged"] == 1
    # without a tag for uav0, the signature is what refuses a captured member's forgery
    forged = peer_datagram(BIG, 1, auth=untagged_auth(2, epoch=50))
    assert refused(e, forged, BIG_A1, 0.2) == {"auth_bad_signature": 1}
    # a window that could have held uav0 but does not (fewer tags than a full window) is a
    # forgery: no genuine datagram looks like that
    short = auth_for(BIG, 2, epoch=60)
    short.tags = _ShortWindow(short.keyring)
    assert refused(e, peer_datagram(BIG, 1, auth=short), BIG_A1, 0.3) == {"auth_bad_tag": 1}


def test_a_flood_spoofing_a_member_from_other_addresses_costs_a_bounded_budget() -> None:
    e = big_receiver()
    a1 = untagged_auth(1, epoch=5)
    e.receive_datagram(peer_datagram(BIG, 1, auth=a1), BIG_A1, 0.1)
    forger = untagged_auth(2, epoch=1000)
    counts: dict[str, int] = {}
    for i in range(400):
        forged = peer_datagram(BIG, 1, auth=forger, host="10.0.0.66")
        for k, v in refused(e, forged, (f"10.1.{i // 200}.{i % 200}", 7412), 0.2).items():
            counts[k] = counts.get(k, 0) + v
    # at most the global budget's burst reached Ed25519; the rest were refused for free
    assert counts["auth_bad_signature"] <= GLOBAL_NEW_ADDRESS_BURST
    assert counts["auth_budget_global"] >= 400 - GLOBAL_NEW_ADDRESS_BURST
    assert e.counters()["dropped"]["auth_budget_global"] == counts["auth_budget_global"]
    # the member at its known address is still heard, in the same instant
    before = e.peer(BIG.participants[1].guid_prefix)
    e.receive_datagram(peer_datagram(BIG, 1, auth=a1), BIG_A1, 0.2)
    after = e.peer(BIG.participants[1].guid_prefix)
    assert before is not None and after is not None and after.last_heard == 0.2


def test_a_replayed_reply_for_another_node_is_refused_before_any_budget() -> None:
    """A genuine directed DATA(p) uav1 -> uav2, captured and replayed to uav0 from the
    attacker's address, carries no tag for uav0: refused before any budget or signature
    (issue 10 verified it and dropped it as not_for_me, having spent a token)."""
    e = receiver()
    a1 = auth_for(BUNDLE, 1, epoch=5)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    verified = e.counters()["auth"]["verified"]
    captured = peer_datagram(BUNDLE, 1, auth=a1, destination=P[2])
    assert refused(e, captured, ATTACKER, 0.2) == {"auth_bad_tag": 1}
    assert e.counters()["auth"]["verified"] == verified


def test_per_address_budget_runs_out_for_one_spoofed_address() -> None:
    e = big_receiver()
    forger = untagged_auth(2, epoch=1000)
    counts: dict[str, int] = {}
    for _ in range(50):
        for k, v in refused(e, peer_datagram(BIG, 1, auth=forger), ATTACKER, 0.2).items():
            counts[k] = counts.get(k, 0) + v
    assert counts.get("auth_budget_sender", 0) >= 40


def test_restart_is_reported_and_the_earlier_life_is_stale() -> None:
    e = receiver()
    life1, life2 = auth_for(BUNDLE, 1, epoch=5), auth_for(BUNDLE, 1, epoch=6)
    captured = peer_datagram(BUNDLE, 1, auth=life1, sequence_number=2)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=life1), A1, 0.1)
    drain(e)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=life2), A1, 1.0)
    (restart,) = [x for x in drain(e) if isinstance(x, PeerRestarted)]
    assert (restart.name, restart.epoch, restart.previous_epoch) == ("uav1", 6, 5)
    view = e.peer(P[1])
    assert view is not None and view.discovered
    # a datagram of its earlier life, never delivered before, is stale now
    assert refused(e, captured, A1, 1.1) == {"auth_replayed": 1}


def test_locators_follow_only_authenticated_changes() -> None:
    """Where the bundle pins no address for the member (DHCP): a pinned one cannot move
    (tests/test_discovery_pinned_locator.py)."""
    bundle = make_bundle(3, with_ipv4=False)
    e = engine_for(bundle, 0, auth=auth_for(bundle, 0))
    a1 = auth_for(bundle, 1)
    e.receive_datagram(peer_datagram(bundle, 1, auth=a1), A1, 0.1)
    drain(e)
    # the attacker's redirect (issue 10, attack 4): refused, the locator stays
    forged = peer_datagram(bundle, 1, auth=auth_for(bundle, 2, epoch=50), host="10.0.0.66")
    assert refused(e, forged, ATTACKER, 0.2) == {"auth_bad_tag": 1}
    # the member itself moves: reported, and used from now on
    e.receive_datagram(peer_datagram(bundle, 1, auth=a1, host="10.0.7.7"), ("10.0.7.7", 7412), 0.3)
    (moved,) = [x for x in drain(e) if isinstance(x, PeerLocatorsChanged)]
    assert [str(x) for x in moved.default_unicast_locators] == ["udp/10.0.7.7:7413"]
    view = e.peer(bundle.participants[1].guid_prefix)
    assert view is not None and view.locator == ("10.0.7.7", 7412)


def test_every_datagram_the_engine_sends_is_sealed_with_a_fresh_counter() -> None:
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1)), A1, 0.1)
    sent: list[bytes] = []
    now = 0.1
    while len(sent) < 3 and (t := e.get_timer()) is not None and t < 100:
        now = t
        e.handle_timer(now)
        sent += [d for d, _ in e.datagrams_to_send()]
    e.shutdown(now)
    sent += [d for d, _ in e.datagrams_to_send()]
    assert len(sent) >= 3
    ring = auth_for(BUNDLE, 1).keyring
    seen = []
    for d in sent:
        opened = open_tail(d)
        assert opened is not None
        freshness, signature, signed = opened
        assert ring.verify(P[0], signed, signature)
        seen.append(freshness)
    assert seen == sorted(set(seen)) and {f.epoch for f in seen} == {1}


def test_a_leave_signs_a_bounded_number_of_times_whatever_n() -> None:
    """One Ed25519 signature per dispose sent: a leave signs at most
    MAX_DISPOSE_UNICAST + DISPOSE_MULTICAST_COPIES times, not once per peer."""
    n = 40
    bundle = make_bundle(n)
    auth = auth_for(bundle, 0)
    e = engine_for(bundle, 0, auth=auth)
    for i in range(1, n):
        d = peer_datagram(bundle, i, auth=auth_for(bundle, i))
        e.receive_datagram(d, (node_ipv4(i), 7410 + 2 * i), 0.1)
    assert e.peer_counts() == (n - 1, n - 1)
    e.datagrams_to_send()
    first = auth.counter.next().seq  # every seal takes the next value: one signature each
    e.shutdown(0.2)
    out = e.datagrams_to_send()
    signatures = auth.counter.next().seq - first - 1
    assert signatures == len(out) <= MAX_DISPOSE_UNICAST + DISPOSE_MULTICAST_COPIES
    # each copy carries its own freshness: a receiver accepts whichever copy reaches it
    # first, and counts no replay for the others (they are not replays)
    ring = auth_for(bundle, 1).keyring
    freshness = []
    for d, _ in out:
        opened = open_tail(d)
        assert opened is not None
        assert ring.verify(P[0], opened[2], opened[1])
        freshness.append(opened[0])
    assert len(set(freshness)) == len(out)
    # a peer that missed the first copy is dropped by the next
    peer = engine_for(bundle, 1, auth=auth_for(bundle, 1))
    peer.receive_datagram(peer_datagram(bundle, 0, auth=auth_for(bundle, 0)), A0, 0.1)
    drain(peer)
    for d, _ in out[1:]:
        peer.receive_datagram(d, A0, 0.3)
    assert [x.reason for x in drain(peer) if isinstance(x, PeerLost)] == ["disposed"]
    assert dropped(peer) == {}


def test_an_authenticated_swarm_converges_with_the_same_frames() -> None:
    """+0 packets: authentication changes bytes, never the schedule (issue 10, Numbers)."""
    runs = {}
    for authenticated in (False, True):
        swarm = build_swarm(5, seed=7, authenticated=authenticated)
        swarm.run_until(60.0)
        assert swarm.all_discovered()
        tx = swarm.net.transmissions
        runs[authenticated] = (len(tx), sum(t.size for t in tx))
        if authenticated:
            windows = [tail_window(t.payload) for t in tx]
            tags = [w[1] for w in windows if w is not None]
            assert len(tags) == len(tx) and set(tags) <= {1, 4}
    assert runs[True][0] == runs[False][0]
    # each datagram: the authenticator (80 octets) and one 4-octet tag per receiver it
    # names (all 4 peers in a multicast one, the destination in a directed one)
    assert runs[True][1] == runs[False][1] + sum(authenticator_overhead(t) for t in tags)


@settings(max_examples=200, deadline=None)
@given(st.integers(min_value=0, max_value=100_000), st.integers(min_value=0, max_value=7))
def test_flipping_any_bit_of_a_signed_data_p_gets_it_refused(where: int, bit: int) -> None:
    d = peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 1, epoch=3), heard=(0,))
    flipped = bytearray(d)
    flipped[where % len(d)] ^= 1 << bit
    e = receiver()
    e.receive_datagram(bytes(flipped), A1, 0.1)
    assert not discovered(e, 1)
    assert not any(isinstance(x, PeerDiscovered) for x in drain(e))
    e.receive_datagram(d, A1, 0.2)  # the genuine one still gets through: nothing was spent
    assert discovered(e, 1)


def test_a_flood_of_invented_participants_is_decoded_at_a_bounded_rate() -> None:
    """Attack 9: every datagram a "new" participant. Decodes and reports are budgeted; the
    foreign table stays capped; a report says how many it stands for."""
    e = receiver()
    stranger = make_bundle(250, swarm="forger")
    for i in range(1000):
        e.receive_datagram(peer_datagram(stranger, 1 + i % 249), (f"10.7.0.{i % 250}", 1), 0.5)
    dropped_now = e.counters()["dropped"]
    decoded = dropped_now["not_in_bundle"]
    assert decoded == FOREIGN_DECODE_BURST and dropped_now["foreign_budget"] == 1000 - decoded
    reports = [x for x in drain(e) if isinstance(x, ForeignParticipantSeen)]
    assert len(reports) == FOREIGN_REPORT_BURST  # not one per new prefix
    assert len(e.foreign(0.5)) == min(MAX_FOREIGN, FOREIGN_DECODE_BURST)  # capped either way
    # a second later: one more report, carrying the count it stands for
    e.receive_datagram(peer_datagram(make_bundle(2, swarm="late"), 1), ATTACKER, 1.5)
    (late,) = [x for x in drain(e) if isinstance(x, ForeignParticipantSeen)]
    assert late.suppressed == e.counters()["foreign_suppressed"] > 0


@settings(max_examples=150, deadline=None)
@given(st.integers(min_value=0, max_value=100_000), st.integers(min_value=0, max_value=7))
def test_flipping_any_bit_of_a_signed_dispose_gets_it_refused(where: int, bit: int) -> None:
    a1 = auth_for(BUNDLE, 1, epoch=3)
    e = receiver()
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    template = encode_spdp_dispose(
        P[1], sequence_number=2, timestamp=None, authenticator=PLACEHOLDER
    )
    d = a1.seal(template)
    flipped = bytearray(d)
    flipped[where % len(d)] ^= 1 << bit
    drain(e)
    e.receive_datagram(bytes(flipped), A1, 0.2)
    assert discovered(e, 1)
    assert not any(isinstance(x, PeerLost) for x in drain(e))
    e.receive_datagram(d, A1, 0.3)  # the genuine dispose still works afterwards
    assert not discovered(e, 1)


def test_a_members_dispose_or_alive_under_an_invented_header_prefix_moves_nothing() -> None:
    """Session 10 network review. Authentication is chosen by the RTPS header's prefix: an
    invented one takes the foreign path (no tag, no signature, only the decode budget). So a
    DATA(p[UD]) or DATA(p) naming a member inside such a header must never reach that
    member's state: the decoder refuses a sample whose participant differs from the header
    (``decode_error``), and the member stays discovered, its locators unchanged."""
    e = receiver()
    a1 = auth_for(BUNDLE, 1, epoch=5)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.1)
    drain(e)
    invented = bytes(range(100, 112))
    dispose = bytearray(encode_spdp_dispose(P[1], sequence_number=9, timestamp=None))
    dispose[8:20] = invented
    assert refused(e, bytes(dispose), ATTACKER, 0.2) == {"decode_error": 1}
    alive = bytearray(peer_datagram(BUNDLE, 1))  # unsigned: the foreign path never verifies
    alive[8:20] = invented
    assert refused(e, bytes(alive), ATTACKER, 0.3) == {"decode_error": 1}
    assert discovered(e, 1)
