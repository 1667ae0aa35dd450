"""The last-chance probe and the rejoin pull-in (issue 20; docs/discovery.md, "Probing before
a lease ends"), one engine driven by hand on virtual time."""

from __future__ import annotations

from typing import cast

import pytest
from swarmd_lab.testing import drain, engine_for, make_bundle, peer_datagram, run_to

from swarmd.discovery import DiscoveryEngine, EngineConfig, PeerDiscovered, PeerLost
from swarmd.discovery.config import Mode
from swarmd.discovery.digest import decode_heard
from swarmd.discovery.leases import PROBE_AT, PROBE_ATTEMPTS
from swarmd.rtps.spdp import SpdpAlive, decode_spdp

LEASE_S = 20.0
HEARD_AT = 5.0
GAP_S = EngineConfig().retransmit_min_gap_s


def alive(datagram: bytes) -> SpdpAlive:
    _, samples = decode_spdp(datagram)
    assert len(samples) == 1 and isinstance(samples[0], SpdpAlive)
    return samples[0]


def _member_hearing_the_commander(
    mode: str = "adaptive", announce_budget_fps: float = 50.0
) -> tuple[DiscoveryEngine, int]:
    """uav1 of a 2-drone bundle, which heard uav0 (listing it) at ``HEARD_AT``; uav0's
    index."""
    bundle = make_bundle(2)
    config = EngineConfig(mode=cast(Mode, mode), announce_budget_fps=announce_budget_fps)
    engine = engine_for(bundle, 1, q=1.0, config=config)
    run_to(engine, HEARD_AT)
    engine.receive_datagram(
        peer_datagram(bundle, 0, heard=(1,), lease_s=LEASE_S), ("10.0.0.1", 7410), HEARD_AT
    )
    assert any(isinstance(e, PeerDiscovered) for e in drain(engine))
    return engine, 0


def _probes(engine: DiscoveryEngine) -> int:
    return int(engine.counters()["tx_kind"]["probe"])


def test_a_silent_peer_is_probed_in_its_lease_last_quarter_then_lost_at_its_end() -> None:
    engine, commander = _member_hearing_the_commander()
    run_to(engine, HEARD_AT + 1.0)  # our answer to its DATA(p) (directed, listing it)
    probe_times: list[float] = []
    for t, data, _ in run_to(engine, HEARD_AT + LEASE_S - 0.001):
        sample = alive(data)
        if sample.destination is not None:
            probe_times.append(t)
            # its own bit cleared, so that it answers at once
            assert commander not in decode_heard(sample.participant.heard or b"", 2)
    assert _probes(engine) == PROBE_ATTEMPTS == len(probe_times)
    assert min(probe_times) == pytest.approx(HEARD_AT + PROBE_AT * LEASE_S)
    assert max(probe_times) < HEARD_AT + LEASE_S
    assert not any(isinstance(e, PeerLost) for e in drain(engine))  # the lease still runs
    run_to(engine, HEARD_AT + LEASE_S)
    assert [type(e) for e in drain(engine)] == [PeerLost]
    assert _probes(engine) == PROBE_ATTEMPTS  # nothing after the loss


def test_paper_mode_keeps_the_paper_liveliness_no_probe() -> None:
    engine, _ = _member_hearing_the_commander("paper")
    run_to(engine, HEARD_AT + LEASE_S - 0.001)
    assert _probes(engine) == 0
    assert not any(isinstance(e, PeerLost) for e in drain(engine))
    run_to(engine, HEARD_AT + LEASE_S)
    assert [type(e) for e in drain(engine)] == [PeerLost]


def test_an_answered_probe_keeps_the_peer_and_stops_the_probing() -> None:
    engine, commander = _member_hearing_the_commander()
    bundle = make_bundle(2)
    first_probe = HEARD_AT + PROBE_AT * LEASE_S
    run_to(engine, first_probe)
    assert _probes(engine) == 1
    # its answer, directed to us and listing us, arrives 0.1 s later
    answer = peer_datagram(
        bundle, 0, heard=(1,), sequence_number=2, lease_s=LEASE_S, destination=engine.guid_prefix
    )
    engine.receive_datagram(answer, ("10.0.0.1", 7410), first_probe + 0.1)
    run_to(engine, first_probe + 0.1 + PROBE_AT * LEASE_S - 0.001)
    assert _probes(engine) == 1
    assert not any(isinstance(e, PeerLost) for e in drain(engine))
    view = engine.peer(f"uav{commander}")
    assert view is not None and view.state.name == "DISCOVERED"


def test_a_rejoining_peer_pulls_our_next_multicast_in_once_per_gap() -> None:
    """A lost peer heard again while another is missing: our next multicast comes within the
    reply holdoff (counted as an announcement); a second rejoin within the re-ack gap (a peer
    flapping, or a forger replaying in an unauthenticated swarm) pulls nothing more in."""
    bundle = make_bundle(3)
    engine = engine_for(bundle, 1, q=1.0)
    # the pull-in alone: the seek's own multicasts (test_discovery_seek.py) kept out
    engine._seek.enabled = False  # noqa: SLF001
    run_to(engine, HEARD_AT)
    for peer in (0, 2):
        engine.receive_datagram(
            peer_datagram(bundle, peer, heard=(1,), lease_s=LEASE_S),
            (f"10.0.0.{peer + 1}", 7410 + 2 * peer),
            HEARD_AT,
        )
    run_to(engine, HEARD_AT + LEASE_S + 1.0)  # both lost (their probes unanswered)
    assert sum(isinstance(e, PeerLost) for e in drain(engine)) == 2
    back = HEARD_AT + LEASE_S + 2.0
    renewal_due = engine.get_timer()
    assert renewal_due is not None
    announced = engine.counters()["tx_kind"]["announce"]
    engine.receive_datagram(
        peer_datagram(bundle, 0, heard=(1,), sequence_number=5, lease_s=LEASE_S),
        ("10.0.0.1", 7410),
        back,
    )
    pulled = engine.get_timer()
    assert pulled is not None and back < pulled < min(renewal_due, back + 1.0)
    sent = run_to(engine, pulled)
    assert [alive(d).destination for _, d, _ in sent] == [None]  # one multicast
    assert engine.counters()["tx_kind"]["announce"] == announced + 1
    # lost again and back at once: within the gap of that multicast nothing is pulled in
    # (its own answer may go, directed)
    engine._lose(engine._peers[0], "lease")  # noqa: SLF001 - the shortest way to a re-loss
    engine.receive_datagram(
        peer_datagram(bundle, 0, heard=(1,), sequence_number=6, lease_s=LEASE_S),
        ("10.0.0.1", 7410),
        pulled + 0.01,
    )
    sent = run_to(engine, pulled + GAP_S - 0.02)
    assert [d for _, d, _ in sent if alive(d).destination is None] == []
    assert engine.counters()["tx_kind"]["announce"] == announced + 1


def test_a_probe_is_answered_at_once_and_a_flood_of_them_at_most_once_per_gap() -> None:
    """The probed side: a directed DATA(p) from a known peer that does not list us is
    answered within ``reply_delay_max_s`` (not after adaptive mode's U(W, 2W) holdoff);
    a forger repeating it (unauthenticated swarm) gets one answer per re-ack gap. An
    announce budget of 0.25 frames/s makes adaptive mode's W 8 s (N / budget), as a swarm
    of 400 at the default budget: its answer window (2W) outlasts the flood, so every
    answer in it is this rule's."""
    engine, commander = _member_hearing_the_commander(announce_budget_fps=0.25)
    bundle = make_bundle(2)
    run_to(engine, HEARD_AT + 1.0)  # our first answer, listing it
    t0 = HEARD_AT + 2.0
    reply_max = EngineConfig().reply_delay_max_s
    answers: list[float] = []
    sn = 10
    t = t0
    while t < t0 + 2.0:  # a probe every 10 ms for 2 s: 200 of them
        sn += 1
        probe = peer_datagram(
            bundle, commander, heard=(), sequence_number=sn, destination=engine.guid_prefix
        )
        engine.receive_datagram(probe, ("10.0.0.1", 7410), t)
        answers += [at for at, d, _ in run_to(engine, t + 0.01) if alive(d).destination]
        t += 0.01
    assert answers and answers[0] - t0 <= reply_max + 0.01
    assert len(answers) <= 2.0 / GAP_S + 1


def _renewal_due(engine: DiscoveryEngine) -> float | None:
    return engine._renewal.due  # noqa: SLF001 - the renewal's phase is what is asserted


@pytest.mark.parametrize("mode", ["adaptive", "paper"])
def test_a_lease_end_pulls_one_multicast_in_omitting_the_lost_and_keeps_the_renewal(
    mode: str,
) -> None:
    """Issue 20's fade: a lease that ends while the link is back is followed by one
    multicast within the rejoin delay (its heard digest omits the lost peer, so the peer, if
    it hears it, answers at once), counted as an announcement; the renewal keeps its own
    deadline. A second lease ending within a renewal period pulls nothing more in. Paper
    mode: nothing at the loss."""
    bundle = make_bundle(3)
    config = EngineConfig(mode=cast(Mode, mode))
    engine = engine_for(bundle, 1, q=1.0, config=config)
    # the lease's end alone: the seek's own multicasts (test_discovery_seek.py) kept out
    engine._seek.enabled = False  # noqa: SLF001
    run_to(engine, HEARD_AT)
    for peer, at in ((0, HEARD_AT), (2, HEARD_AT + 1.0)):  # both silent after this
        engine.receive_datagram(
            peer_datagram(bundle, peer, heard=(1,), lease_s=LEASE_S),
            (f"10.0.0.{peer + 1}", 7410 + 2 * peer),
            at,
        )
    end = HEARD_AT + LEASE_S
    run_to(engine, end - 0.001)
    assert not any(isinstance(e, PeerLost) for e in drain(engine))
    renewal = _renewal_due(engine)
    assert renewal is not None and renewal > end + 1.0
    announced = engine.counters()["tx_kind"]["announce"]
    window = len(bundle.participants) / config.announce_budget_fps  # rejoin delay's bound
    sent = [(t, d) for t, d, _ in run_to(engine, end + window) if alive(d).destination is None]
    assert [type(e) for e in drain(engine)] == [PeerLost]
    if mode == "paper":
        assert sent == []
        return
    assert len(sent) == 1
    heard = decode_heard(alive(sent[0][1]).participant.heard or b"", 3)
    assert 0 not in heard and 2 in heard
    assert engine.counters()["tx_kind"]["announce"] == announced + 1
    assert _renewal_due(engine) == renewal  # an extra frame: the renewal's phase kept
    # uav2's lease ends 1 s later, within a renewal period: no second frame
    later = [d for _, d, _ in run_to(engine, end + 1.5) if alive(d).destination is None]
    assert sum(isinstance(e, PeerLost) for e in drain(engine)) == 1
    assert later == []


def test_a_peer_that_stops_listing_us_is_answered_within_the_rejoin_delay() -> None:
    """The other side of the lease-end frame: a peer whose frame listed us sends one that
    does not (it lost us). We read Q = 0, so the reply holdoff is U(W, 2W) with W = N /
    (budget x q_floor) = 0.4 s, past the fade's windows; the answer comes within the rejoin
    delay W1 = N / budget = 0.04 s instead. A peer flipping its bit (a forger, unauthenticated
    swarm) gets such prompt answers at most once per re-ack gap."""
    bundle = make_bundle(2)
    engine = engine_for(bundle, 1, q=0.0)
    run_to(engine, HEARD_AT)
    engine.receive_datagram(
        peer_datagram(bundle, 0, heard=(1,), lease_s=LEASE_S), ("10.0.0.1", 7410), HEARD_AT
    )
    run_to(engine, HEARD_AT + 1.0)  # our answer, listing it: told, and it lists us
    rejoin_window = 2 / EngineConfig().announce_budget_fps
    t0 = HEARD_AT + 2.0
    engine.receive_datagram(
        peer_datagram(bundle, 0, heard=(), sequence_number=2, lease_s=LEASE_S),
        ("10.0.0.1", 7410),
        t0,
    )
    answers = [t for t, _, _ in run_to(engine, t0 + 0.3)]
    assert answers and answers[0] - t0 <= rejoin_window
    # the flood: every 0.1 s a frame without us, 0.06 s later one listing us again (which
    # disarms an answer still held back: only prompt answers get out)
    sn, t, prompt = 2, t0 + 1.0, 0
    while t < t0 + 3.0:
        for heard, dt in (((), 0.0), ((1,), 0.06)):
            sn += 1
            frame = peer_datagram(bundle, 0, heard=heard, sequence_number=sn, lease_s=LEASE_S)
            engine.receive_datagram(frame, ("10.0.0.1", 7410), t + dt)
            end = t + dt + 0.05 if not heard else t + 0.1 - 0.001
            # directed, or (the lost_us rule's answer, h-seek-answer) a multicast
            prompt += len(run_to(engine, end))
        t += 0.1
    assert 1 <= prompt <= 2.0 / GAP_S + 1
