"""The discovery engine driven by hand on virtual time: one engine, hand-made peer frames."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from swarmd_lab.testing import drain, make_bundle, node_ipv4, peer_datagram, run_to

from swarmd.bundle.model import DiscoveryParams
from swarmd.discovery import (
    DiscoveryEngine,
    EngineConfig,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLost,
    Phase,
    PhaseChanged,
)
from swarmd.discovery.digest import decode_heard
from swarmd.discovery.engine import (
    DISPOSE_MULTICAST_COPIES,
    MAX_DISPOSE_UNICAST,
    MAX_PENDING_EVENTS,
)
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.peers import MAX_FOREIGN
from swarmd.rtps.spdp import BES_SPDP_ONLY, SpdpAlive, SpdpDisposed, decode_spdp
from swarmd.rtps.types import VENDORID_SWARMD, GuidPrefix

FIXTURES = Path(__file__).parent / "fixtures"
MCAST = ("239.255.0.1", 7400)


def engine_for(
    n: int = 10,
    *,
    index: int = 0,
    mode: str = "adaptive",
    seed: int = 7,
    q: float | None = 1.0,
    bundle_discovery: DiscoveryParams | None = None,
    **config: float,
) -> DiscoveryEngine:
    bundle = make_bundle(n, discovery=bundle_discovery)
    cfg = EngineConfig(mode=mode, **config)  # type: ignore[arg-type]
    return DiscoveryEngine(
        bundle,
        f"uav{index}",
        config=cfg,
        rng=random.Random(seed),
        now=0.0,
        local_ipv4=node_ipv4(index),
        link=None if q is None else LinkSample(q=q),
    )


def alive(datagram: bytes) -> SpdpAlive:
    _, samples = decode_spdp(datagram)
    assert len(samples) == 1
    sample = samples[0]
    assert isinstance(sample, SpdpAlive)
    return sample


# ------------------------------------------------------------------ passive timer


def test_passive_timer_is_drawn_from_the_seeded_rng_adaptive() -> None:
    engine = engine_for(10, seed=7)
    # adaptive: W = min(paper 8 s, N / (50 fps * Q)) = 0.2 s; first draw of the rng
    assert engine.passive_window_s == pytest.approx(0.2)
    expected = random.Random(7).uniform(0.0, 0.2)
    assert engine.passive_timer_s == expected
    assert engine.phase == Phase.PASSIVE
    assert engine.get_timer() == expected


def test_passive_timer_paper_mode_follows_eq3() -> None:
    engine = engine_for(10, mode="paper", q=0.5, seed=3)
    # eq. 3: W = Tmin + (Tmax - Tmin)(1 - Q) = 8 + 12 * 0.5
    assert engine.passive_window_s == pytest.approx(14.0)
    assert engine.passive_timer_s == random.Random(3).uniform(0.0, 14.0)


def test_bundle_discovery_params_override_defaults_and_config_overrides_bundle() -> None:
    bundle_params = DiscoveryParams(t_min_s=2.0, t_max_s=4.0, lease_s=10.0)
    engine = engine_for(10, mode="paper", q=0.0, bundle_discovery=bundle_params)
    assert engine.passive_window_s == pytest.approx(4.0)
    timing = engine.status(0.0)["timing"]
    assert timing["sources"] == {"t_min_s": "bundle", "t_max_s": "bundle", "lease_s": "bundle"}
    overridden = engine_for(10, mode="paper", q=0.0, bundle_discovery=bundle_params, t_max_s=6.0)
    assert overridden.passive_window_s == pytest.approx(6.0)
    assert overridden.status(0.0)["timing"]["sources"]["t_max_s"] == "config"


def test_boot_waits_for_a_link_sample_then_falls_back_to_default_q() -> None:
    engine = engine_for(10, mode="paper", q=None, boot_link_timeout_s=2.0)
    phases = [engine.phase]
    assert engine.get_timer() == 2.0
    engine.handle_timer(2.0)
    phases.append(engine.phase)
    assert phases == [Phase.BOOT, Phase.PASSIVE]
    # default Q 0.5 in paper mode: W = 14 s
    assert engine.passive_window_s == pytest.approx(14.0)
    (changed,) = [e for e in drain(engine) if isinstance(e, PhaseChanged)]
    assert "default Q" in changed.reason


# ------------------------------------------------------------------- schedule


def test_lonely_engine_stages_announcements_with_backoff_then_gives_up() -> None:
    engine = engine_for(10, seed=11, vouch=False)  # uav0, the commander: a plain schedule
    sent = run_to(engine, 60.0)
    times = [t for t, _, a in sent if a == MCAST]
    assert all(a == MCAST for _, _, a in sent), "nobody answered, so nothing is directed"
    kinds = engine.counters()["tx_kind"]
    assert kinds["announce"] == 6  # max_attempts
    first = times[0]
    assert first == engine.passive_timer_s
    gaps = [b - a for a, b in zip(times[:6], times[1:6], strict=False)]
    # base max(1 s, 2W) = 1 s doubling to the 8 s cap, each stretched by U(1, 1.25)
    for k, gap in enumerate(gaps):
        plain = min(8.0, 2.0**k)
        assert plain <= gap <= plain * 1.25
    settled = [e for e in drain(engine) if isinstance(e, PhaseChanged) and e.new == Phase.STEADY]
    assert len(settled) == 1
    assert "gave up on 9 peer(s)" in settled[0].reason
    # then renewals only: period lease / 2 = 10 s at Q = 1, shortened by U(0, 10 %)
    renewals = times[6:]
    assert renewals
    for a, b in zip(times[5:], renewals, strict=False):
        assert 9.0 <= b - a <= 10.0


def test_same_seed_same_bytes_different_seed_different_schedule() -> None:
    a = run_to(engine_for(10, seed=5), 40.0)
    b = run_to(engine_for(10, seed=5), 40.0)
    c = run_to(engine_for(10, seed=6), 40.0)
    assert a == b
    assert [t for t, _, _ in a] != [t for t, _, _ in c]


def test_our_announcement_carries_what_the_issue_specifies() -> None:
    engine = engine_for(10, index=3, seed=1)
    bundle = make_bundle(10)
    (t, datagram, target), *_ = run_to(engine, 1.0)
    assert target == MCAST
    sample = alive(datagram)
    p = sample.participant
    me = bundle.participants[3]
    assert p.guid_prefix == me.guid_prefix
    assert p.vendor_id == VENDORID_SWARMD
    assert p.builtin_endpoints == BES_SPDP_ONLY
    assert p.entity_name == "alpha/uav3"
    assert p.domain_id == 0
    assert p.lease_duration.total_seconds() == 20.0
    assert [str(loc) for loc in p.metatraffic_unicast_locators] == ["udp/10.0.0.4:7416"]
    assert [str(loc) for loc in p.default_unicast_locators] == ["udp/10.0.0.4:7417"]
    assert [str(loc) for loc in p.metatraffic_multicast_locators] == ["udp/239.255.0.1:7400"]
    assert p.bundle_digest == bundle.content_sha256[:16]
    assert p.heard == bytes(2)  # 10 participants: 2 octets, nobody heard yet
    assert p.link_quality_permille == 1000
    assert sample.sequence_number == 1
    assert sample.destination is None
    assert sample.timestamp is None  # no wallclock: INFO_TS with the invalidate flag


def test_wallclock_stamps_info_ts() -> None:
    bundle = make_bundle(3)
    engine = DiscoveryEngine(
        bundle,
        "uav0",
        config=EngineConfig(),
        rng=random.Random(1),
        now=0.0,
        local_ipv4=node_ipv4(0),
        wallclock=lambda: 1_700_000_000.5,
        link=LinkSample(q=1.0),
    )
    (_, datagram, _), *_ = run_to(engine, 1.0)
    ts = alive(datagram).timestamp
    assert ts is not None
    assert ts.total_seconds() == 1_700_000_000.5


# ------------------------------------------------------------------ passive phase


def test_passive_phase_never_multicasts_and_replies_directed_to_the_metatraffic_locator() -> None:
    engine = engine_for(10, mode="paper", seed=2)  # passive for U(0, 8 s)
    bundle = make_bundle(10)
    deadline = engine.get_timer()
    assert deadline is not None and deadline > 0.5
    engine.receive_datagram(peer_datagram(bundle, 4), (node_ipv4(4), 55555), 0.01)
    events = drain(engine)
    (found,) = [e for e in events if isinstance(e, PeerDiscovered)]
    assert found.name == "uav4" and found.via == "multicast"
    # matches come from the bundle: uav0 (commander) reads swarm/ready, writes swarm/command
    assert {(m.topic, m.local_kind) for m in found.matches} == {
        ("swarm/ready", "reader"),
        ("swarm/command", "writer"),
    }
    sent = run_to(engine, deadline - 1e-9)
    assert len(sent) == 1, "exactly one directed reply while passive"
    t, datagram, target = sent[0]
    assert target == (node_ipv4(4), 7418)  # its metatraffic locator, not the UDP source
    assert t <= 0.01 + 0.1  # paper mode: reply within U(0, 0.1 s)
    reply = alive(datagram)
    assert reply.destination == bundle.participants[4].guid_prefix
    assert decode_heard(reply.participant.heard, 10) == {4}
    assert engine.phase == Phase.PASSIVE


def test_a_peer_that_already_lists_us_and_was_told_gets_no_reply() -> None:
    engine = engine_for(2, seed=4)
    bundle = make_bundle(2)
    # our announcement goes out first (nobody heard yet), then uav1 answers listing us
    run_to(engine, 1.0)
    engine.datagrams_to_send()
    engine.receive_datagram(peer_datagram(bundle, 1, heard=(0,)), (node_ipv4(1), 7412), 1.0)
    sent = run_to(engine, 1.5)
    # uav1 lists us but we never listed it: one ack is owed (directed, it is alone)
    assert [(a, alive(d).destination) for _, d, a in sent] == [
        ((node_ipv4(1), 7412), bundle.participants[1].guid_prefix)
    ]
    # it answers again, still listing us: nothing more
    engine.receive_datagram(
        peer_datagram(bundle, 1, heard=(0,), sequence_number=2), (node_ipv4(1), 7412), 1.6
    )
    after = [a for _, _, a in run_to(engine, 1.9) if a != MCAST]
    assert after == []


def test_a_repeated_directed_frame_means_our_ack_was_lost_and_is_answered_again() -> None:
    engine = engine_for(2, seed=4)
    bundle = make_bundle(2)
    me = bundle.participants[0].guid_prefix
    run_to(engine, 1.0)
    engine.datagrams_to_send()
    frame = peer_datagram(bundle, 1, heard=(0,), sequence_number=3, destination=me)
    engine.receive_datagram(frame, (node_ipv4(1), 7412), 1.0)
    first = [a for _, _, a in run_to(engine, 1.5)]
    assert first == [(node_ipv4(1), 7412)]
    # the same SN again 1 s later: uav1 has not seen us list it
    engine.receive_datagram(frame, (node_ipv4(1), 7412), 2.5)
    again = [a for _, _, a in run_to(engine, 3.0)]
    assert again == [(node_ipv4(1), 7412)]
    # a duplicate within retransmit_min_gap_s (the network doubled it) is not a repeat
    engine.receive_datagram(frame, (node_ipv4(1), 7412), 2.7)
    assert [a for _, _, a in run_to(engine, 3.5)] == []


# ---------------------------------------------------------------- leases, dispose


def test_a_peer_silent_past_its_lease_is_lost_and_comes_back() -> None:
    engine = engine_for(3, seed=4)
    bundle = make_bundle(3)
    engine.receive_datagram(peer_datagram(bundle, 2, lease_s=5.0), (node_ipv4(2), 7414), 0.5)
    run_to(engine, 5.4)
    assert engine.status(5.4)["peers"][1]["state"] == "discovered"
    run_to(engine, 5.5)
    lost = [e for e in drain(engine) if isinstance(e, PeerLost)]
    assert [(e.name, e.reason) for e in lost] == [("uav2", "lease")]
    assert engine.status(5.5)["peers"][1]["state"] == "lost"
    engine.receive_datagram(
        peer_datagram(bundle, 2, heard=(0,), sequence_number=9), (node_ipv4(2), 7414), 30.0
    )
    back = [e for e in drain(engine) if isinstance(e, PeerDiscovered)]
    assert [e.name for e in back] == ["uav2"]


def test_dispose_drops_the_peer_at_once() -> None:
    from swarmd.rtps.spdp import encode_spdp_dispose

    engine = engine_for(3, seed=4)
    bundle = make_bundle(3)
    engine.receive_datagram(peer_datagram(bundle, 1), (node_ipv4(1), 7412), 0.5)
    drain(engine)
    bye = encode_spdp_dispose(bundle.participants[1].guid_prefix, sequence_number=2, timestamp=None)
    engine.receive_datagram(bye, (node_ipv4(1), 7412), 0.6)
    assert [(e.name, e.reason) for e in drain(engine) if isinstance(e, PeerLost)] == [
        ("uav1", "disposed")
    ]


def shutdown_datagrams(
    n: int, heard: range, now: float = 0.6
) -> tuple[DiscoveryEngine, list[tuple[bytes, tuple[str, int]]]]:
    """uav0 of an ``n``-drone bundle hears the peers in ``heard``, then leaves: what it sends."""
    engine = engine_for(n, seed=4)
    bundle = make_bundle(n)
    for i in heard:
        engine.receive_datagram(peer_datagram(bundle, i), (node_ipv4(i), 7410 + 2 * i), 0.1)
    run_to(engine, 0.5)
    engine.datagrams_to_send()
    before = engine.counters()
    engine.shutdown(now)
    out = engine.datagrams_to_send()
    after = engine.counters()
    # the counters say exactly what was queued
    assert after["tx_kind"]["dispose"] - before["tx_kind"]["dispose"] == len(out)
    assert after["tx_datagrams"] - before["tx_datagrams"] == len(out)
    multicast = sum(a == MCAST for _, a in out)
    assert after["tx_multicast"] - before["tx_multicast"] == multicast
    assert after["tx_unicast"] - before["tx_unicast"] == len(out) - multicast
    for datagram, _ in out:
        _, samples = decode_spdp(datagram)
        assert isinstance(samples[0], SpdpDisposed)
        assert samples[0].guid_prefix == bundle.participants[0].guid_prefix
    return engine, out


def test_shutdown_sends_dispose_to_multicast_and_every_known_peer() -> None:
    engine, out = shutdown_datagrams(4, range(1, 4, 2))
    assert sorted(a for _, a in out) == sorted(
        [MCAST] * DISPOSE_MULTICAST_COPIES + [(node_ipv4(1), 7412), (node_ipv4(3), 7416)]
    )
    assert out[0][1] == MCAST  # the copy every peer can hear leaves first
    assert engine.phase == Phase.STOPPED
    assert engine.get_timer() is None
    engine.receive_datagram(peer_datagram(make_bundle(4), 2), (node_ipv4(2), 7414), 0.7)
    assert engine.counters()["dropped"]["stopped"] == 1


@pytest.mark.parametrize("peers", [1, 3, MAX_DISPOSE_UNICAST])
def test_a_small_swarm_still_gets_a_directed_dispose_each(peers: int) -> None:
    _, out = shutdown_datagrams(peers + 1, range(1, peers + 1))
    unicast = sorted(a for _, a in out if a != MCAST)
    assert unicast == sorted((node_ipv4(i), 7410 + 2 * i) for i in range(1, peers + 1))
    assert len(out) == peers + DISPOSE_MULTICAST_COPIES


@pytest.mark.parametrize("peers", [MAX_DISPOSE_UNICAST + 1, 50])
def test_a_leaving_drone_sends_a_bounded_number_of_frames_whatever_n(peers: int) -> None:
    """A leave must not cost O(N) frames: at N = 1000 a swarm powering down together would
    put ~N^2 disposes on the channel (docs/discovery.md, "Leaving")."""
    engine, out = shutdown_datagrams(peers + 1, range(1, peers + 1))
    assert engine.peer_counts() == (peers, peers)  # every one of them was discovered
    assert len(out) <= MAX_DISPOSE_UNICAST + DISPOSE_MULTICAST_COPIES
    assert [a for _, a in out] == [MCAST] * DISPOSE_MULTICAST_COPIES


def test_every_peer_hears_the_leave_from_one_multicast_copy_of_several() -> None:
    """Group frames are not acknowledged: any one of the copies reaching a peer drops us
    there at once; the others change nothing (the dispose is idempotent)."""
    n = MAX_DISPOSE_UNICAST + 3
    bundle = make_bundle(n)
    _, out = shutdown_datagrams(n, range(1, n))
    copies = [d for d, a in out if a == MCAST]
    for arrived in range(len(copies)):
        peer = engine_for(n, index=1, seed=5)
        peer.receive_datagram(peer_datagram(bundle, 0), (node_ipv4(0), 7410), 0.2)
        drain(peer)
        for d in copies[arrived:]:  # the earlier copies were lost
            peer.receive_datagram(d, (node_ipv4(0), 7410), 0.7)
        lost = [(e.name, e.reason) for e in drain(peer) if isinstance(e, PeerLost)]
        assert lost == [("uav0", "disposed")]


# ---------------------------------------------------------- foreign and bad input


def test_stock_cyclone_participant_is_listed_as_foreign_and_never_matched() -> None:
    engine = engine_for(3, seed=4)
    cyclone = (FIXTURES / "cyclone-0.10.2" / "spdp-alive.bin").read_bytes()
    engine.receive_datagram(cyclone, ("10.0.0.99", 7410), 0.1)
    engine.receive_datagram(cyclone, ("10.0.0.99", 7410), 0.2)
    events = drain(engine)
    assert not any(isinstance(e, PeerDiscovered) for e in events)
    (seen,) = [e for e in events if isinstance(e, ForeignParticipantSeen)]
    assert seen.vendor == "Eclipse Cyclone DDS"
    assert seen.reason == "not_in_bundle"
    status = engine.status(0.3)
    assert [f["vendor"] for f in status["foreign"]] == ["Eclipse Cyclone DDS"]
    assert status["counters"]["dropped"]["not_in_bundle"] == 2
    assert status["peers_discovered"] == 0


def test_swarmd_peer_with_another_bundle_digest_is_reported_not_matched() -> None:
    engine = engine_for(3, seed=4)
    bundle = make_bundle(3)
    drain(engine)
    engine.receive_datagram(
        peer_datagram(bundle, 1, bundle_digest=bytes(16)), (node_ipv4(1), 7412), 0.1
    )
    events = drain(engine)
    assert [type(e) for e in events] == [ForeignParticipantSeen]
    assert isinstance(events[0], ForeignParticipantSeen)
    assert events[0].reason == "digest_mismatch"
    assert engine.counters()["dropped"]["digest_mismatch"] == 1
    sent = run_to(engine, 0.5)
    assert sent and all(a == MCAST for _, _, a in sent), "never answered directly"
    assert all(decode_heard(alive(d).participant.heard, 3) == set() for _, d, _ in sent)


def test_another_swarm_on_the_channel_is_foreign() -> None:
    engine = engine_for(3, seed=4)
    other = make_bundle(3, swarm="bravo")
    drain(engine)
    engine.receive_datagram(peer_datagram(other, 1), (node_ipv4(1), 7412), 0.1)
    (seen,) = drain(engine)
    assert isinstance(seen, ForeignParticipantSeen) and seen.reason == "not_in_bundle"


def test_own_loopback_wrong_domain_and_not_for_me_are_dropped_and_counted() -> None:
    engine = engine_for(3, seed=4)
    bundle = make_bundle(3)
    (_, own, _), *_ = run_to(engine, 1.0)
    drain(engine)
    engine.receive_datagram(own, (node_ipv4(0), 7410), 1.0)
    assert drain(engine) == []  # loopback is normal: counted, no event
    engine.receive_datagram(peer_datagram(bundle, 1, domain_id=3), (node_ipv4(1), 7412), 1.1)
    other = GuidPrefix(bytes(range(12)))
    engine.receive_datagram(peer_datagram(bundle, 2, destination=other), (node_ipv4(2), 7414), 1.2)
    engine.receive_datagram(b"RTPS garbage", ("10.9.9.9", 1), 1.3)
    dropped = engine.counters()["dropped"]
    assert (dropped["own"], dropped["wrong_domain"], dropped["not_for_me"]) == (1, 1, 1)
    assert dropped["decode_error"] == 1
    reasons = [e.reason for e in drain(engine) if isinstance(e, PacketDropped)]
    assert reasons == ["wrong_domain", "not_for_me", "decode_error"]
    assert engine.status(1.4)["peers_discovered"] == 0


def test_foreign_table_is_capped_oldest_evicted() -> None:
    engine = engine_for(3, seed=4)
    for i in range(MAX_FOREIGN + 36):
        stranger = make_bundle(2, swarm=f"s{i}")
        engine.receive_datagram(peer_datagram(stranger, 1), ("10.1.1.1", 7412), 0.1 + i * 1e-3)
    status = engine.status(1.0)
    assert len(status["foreign"]) == MAX_FOREIGN
    assert status["counters"]["foreign_evicted"] == 36
    assert status["foreign"][-1]["name"] == f"s{MAX_FOREIGN + 35}/uav1"


def test_event_queue_is_capped_when_nobody_drains_it() -> None:
    engine = engine_for(3, seed=4)
    drain(engine)
    for i in range(MAX_PENDING_EVENTS + 100):
        engine.receive_datagram(b"\x00" * (i % 7), ("10.1.1.1", 1), 0.1)
    assert len(drain(engine)) == MAX_PENDING_EVENTS
    assert engine.counters()["events_dropped"] == 100


# ---------------------------------------------------------------- awareness, status


def test_lower_link_quality_makes_renewals_denser_during_flight() -> None:
    engine = engine_for(3, seed=9, vouch=False)  # uav0, the commander: a plain schedule
    run_to(engine, 40.0)  # alone: gives up announcing, then renews
    assert engine.phase == Phase.STEADY
    engine.datagrams_to_send()
    engine.update_link_quality(LinkSample(q=0.0, snr_db=20.0, source="file"), 40.0)
    renewals = [t for t, _, a in run_to(engine, 80.0) if a == MCAST]
    gaps = [b - a for a, b in zip(renewals, renewals[1:], strict=False)]
    # Q = 0: four renewals per lease, lease / 4 = 5 s shortened by up to 10 %
    assert gaps and all(4.5 <= g <= 5.0 for g in gaps)
    assert engine.status(80.0)["link"] == {"q": 0.0, "snr_db": 20.0, "source": "file"}


@pytest.mark.parametrize(
    ("mode", "period", "lease"),
    [
        # 10 drones at a 0.25 frames/s budget: N / B = 40 s > lease / n(1) = 10 s, so the
        # period is 40 s and the advertised lease n(1) * 40 = 80 s
        ("adaptive", 40.0, 80.0),
        ("paper", 10.0, 20.0),  # paper mode keeps the bundle's lease and lease / n(Q)
    ],
)
def test_renewal_budget_stretches_period_and_advertised_lease(
    mode: str, period: float, lease: float
) -> None:
    # uav0 is the commander: its vouching period is tested in test_discovery_vouch.py
    engine = engine_for(10, mode=mode, seed=9, renewal_budget_fps=0.25, vouch=False)
    sent = run_to(engine, 400.0)  # alone: announces, gives up, then renews
    assert engine.phase == Phase.STEADY
    timing = engine.status(400.0)["timing"]
    assert timing["renewal_period_s"] == pytest.approx(period)
    assert timing["advertised_lease_s"] == pytest.approx(lease)
    multicasts = [(t, d) for t, d, a in sent if a == MCAST]
    assert {alive(d).participant.lease_duration.total_seconds() for _, d in multicasts} == {lease}
    tail = [t for t, _ in multicasts if t > 200.0]
    gaps = [b - a for a, b in zip(tail, tail[1:], strict=False)]
    assert gaps and all(0.9 * period <= g <= period for g in gaps)


def test_status_follows_the_schema() -> None:
    engine = engine_for(3, mode="paper", seed=4)
    bundle = make_bundle(3)
    engine.receive_datagram(peer_datagram(bundle, 1, heard=(0,)), ("10.0.0.2", 7412), 0.05)
    status = engine.status(0.1)
    assert engine.passive_timer_s is not None
    assert status["node"] == "uav0" and status["swarm"] == "alpha"
    assert status["phase"] == "passive" and status["mode"] == "paper"
    assert status["passive_timer_s"] == pytest.approx(engine.passive_timer_s - 0.1, abs=1e-3)
    assert (status["peers_discovered"], status["peers_total"]) == (1, 2)
    peer = status["peers"][0]
    assert peer == {
        "name": "uav1",
        "index": 1,
        "state": "discovered",
        "guid": f"{bundle.participants[1].guid_prefix}:1c1",
        "last_heard_s": pytest.approx(0.05),
        "locator": "udp/10.0.0.2:7412",
        "matched_endpoints": 2,
        "lists_me": True,
        "epoch": None,  # an engine without authentication learns no epochs
    }
    assert status["peers"][1]["state"] == "undiscovered"
    counters = status["counters"]
    for key in ("rx_datagrams", "tx_datagrams", "tx_multicast", "tx_unicast", "dropped"):
        assert key in counters


def test_unknown_node_name_is_one_clear_error() -> None:
    with pytest.raises(ValueError, match="not a participant.*fix: use one of uav0, uav1"):
        DiscoveryEngine(
            make_bundle(2),
            "ghost",
            config=EngineConfig(),
            rng=random.Random(1),
            now=0.0,
            local_ipv4="10.0.0.1",
        )
