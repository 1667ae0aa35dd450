"""ROS 2 node liveness relayed through swarmd (docs/ros2.md, "Node liveness"), on hand-set
time: the relay's local bookkeeping (heard, left, lease expired unheard), the other drones'
relays disposing and re-announcing, the engine carrying the bitmap in its signed DATA(p)
(PID 0x8A06), and the attacks: a forged or replayed liveness change moves nothing. A
restart under the same GUIDs (docs/ros2.md, "A restart under the same GUIDs"): a peer's
swarmd restarted, or one of its nodes under a running swarmd (its count in the signed
word), is disposed and announced again at the local nodes; only an authenticated restart.
The real-process tests are tests/test_ros2_relay_netns.py and tests/test_ros2_reboot_netns.py."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest
from swarmd_lab.testing import auth_for, engine_for, make_bundle, node_ipv4, peer_datagram

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import Ros2Participant, bundle_ros2_participants
from swarmd.cli.status_cmd import render_status
from swarmd.discovery import (
    DiscoveryEngine,
    PacketDropped,
    PeerDiscovered,
    PeerRestarted,
    PeerRos2Liveness,
)
from swarmd.discovery.events import Event
from swarmd.lives import FLAP_HOLD_MAX_S, FLAP_PENALTY_LIMIT
from swarmd.ros2.relay import (
    LIVENESS_MIN_INTERVAL_S,
    LOOPBACK,
    Ros2Relay,
)
from swarmd.ros2.relay_events import (
    LocalLivenessChanged,
    RelayEvent,
    RemoteNodeLiveness,
    RemoteParticipantsRelayed,
)
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import (
    PID_SWARMD_ROS2_ALIVE,
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
)
from swarmd.rtps.types import Duration, GuidPrefix, VendorId

REPO = Path(__file__).resolve().parent.parent
MISSION = (REPO / "firmware_bundle" / "missions" / "swarm3-ros2.yaml").read_text()
LEASE_S = 8.0
NODE_LEASE_S = 20.0
ADDRESS = {"lead": "10.42.0.10", "drone-1": "10.42.0.11", "drone-2": "10.42.0.12"}


def _participants() -> tuple[Ros2Participant, ...]:
    return bundle_ros2_participants(build_dev_bundle(parse_mission(MISSION)).bundle)


def _by(drone: str) -> Ros2Participant:
    return next(p for p in _participants() if p.drone == drone)


def _relay(drone: str) -> Ros2Relay:
    return Ros2Relay(_participants(), drone, domain_id=0, lease_s=LEASE_S, epoch=7)


def _events(relay: Ros2Relay) -> list[RelayEvent]:
    out = []
    while (event := relay.next_event()) is not None:
        out.append(event)
    return out


def _lead_with_two_peers() -> tuple[Ros2Relay, GuidPrefix, GuidPrefix]:
    """The lead's relay with drone-1 and drone-2 discovered and their announcements drained;
    their GUID prefixes."""
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 0.0)
    relay.datagrams_to_send()
    _events(relay)
    return relay, GuidPrefix(_by("drone-1").guid_prefix), GuidPrefix(_by("drone-2").guid_prefix)


def _node_spdp(p: Ros2Participant, sn: int) -> bytes:
    return encode_spdp(
        SpdpParticipant(
            GuidPrefix(p.guid_prefix),
            vendor_id=VendorId(b"\x01\x0f"),
            metatraffic_unicast_locators=(Locator.udpv6(LOOPBACK, p.metatraffic_port),),
            lease_duration=Duration.from_seconds(NODE_LEASE_S),
            entity_name="/",
        ),
        sequence_number=sn,
        timestamp=None,
    )


def _sent(relay: Ros2Relay) -> list[tuple[str, GuidPrefix]]:
    """("alive" | "dispose", participant) for each datagram the relay queued."""
    out = []
    for data, _dest in relay.datagrams_to_send():
        _header, samples = decode_spdp(data)
        for s in samples:
            if isinstance(s, SpdpAlive):
                out.append(("alive", s.participant.guid_prefix))
            else:
                assert isinstance(s, SpdpDisposed)
                out.append(("dispose", s.guid_prefix))
    return out


# ---- the relay's own drone: which of its nodes are alive -----------------------------------


def test_a_node_never_heard_is_alive_for_one_lease_then_stopped() -> None:
    relay = _relay("drone-1")
    relay.started(0.0)
    assert relay.alive_bitmap() == b"\x01"  # swarmd's first DATA(p) announces it alive
    assert relay.get_timer() == LEASE_S
    relay.handle_timer(LEASE_S - 0.001)
    assert _events(relay) == []
    relay.handle_timer(LEASE_S)
    assert _events(relay) == [LocalLivenessChanged(b"\x00\x00", "talker", up=False)]
    assert relay.get_timer() is None
    row = relay.status(LEASE_S)["local"][0]
    assert row["state"] == "not heard" and row["alive"] is False


def test_a_heard_node_stays_alive_within_its_own_lease_and_expires_after() -> None:
    relay = _relay("drone-1")
    relay.started(0.0)
    relay.receive_datagram(_node_spdp(_by("drone-1"), 1), ("::1", 40000), 1.0)
    assert _events(relay)[0].__class__.__name__ == "LocalParticipantHeard"  # no change: alive
    relay.handle_timer(LEASE_S)  # the grace of the never-heard is over; it was heard
    assert _events(relay) == []
    assert relay.get_timer() == 1.0 + NODE_LEASE_S
    relay.receive_datagram(_node_spdp(_by("drone-1"), 2), ("::1", 40000), 5.0)  # renews
    relay.handle_timer(1.0 + NODE_LEASE_S)
    assert _events(relay) == []
    relay.handle_timer(5.0 + NODE_LEASE_S)  # silent for its lease: killed (SIGKILL)
    assert _events(relay) == [LocalLivenessChanged(b"\x00\x00", "talker", up=False)]
    assert relay.status(30.0)["local"][0]["state"] == "lease expired"
    relay.receive_datagram(_node_spdp(_by("drone-1"), 1), ("::1", 40001), 31.0)  # restarted
    events = _events(relay)
    assert events[0] == LocalLivenessChanged(b"\x01\x01", "talker", up=True)  # its 2nd life


# ---- the other drones: dispose a stopped node, announce it again when back -----------------


def test_a_stopped_remote_node_is_disposed_at_once_and_announced_again_when_back() -> None:
    relay, one, two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x00", 1.0)
    assert _sent(relay) == [("dispose", one)]
    assert _events(relay) == [RemoteNodeLiveness("drone-1", "talker", up=False)]
    # the renewals and a starting local node no longer get it
    relay.handle_timer(relay.get_timer() or 0.0)
    assert _sent(relay) == [("alive", two)]
    relay.receive_datagram(_node_spdp(_by("lead"), 1), ("::1", 40000), 3.0)
    assert _sent(relay) == [("alive", two)]
    _events(relay)
    rows = {r["drone"]: r["state"] for r in relay.status(3.0)["remote"]}
    assert rows == {"drone-1": "node stopped", "drone-2": "relayed"}
    relay.peer_liveness("drone-1", b"\x00", 4.0)  # the same word again: nothing
    assert _sent(relay) == [] and _events(relay) == []
    relay.peer_liveness("drone-1", b"\x01", 5.0)  # back: announced at once
    assert _sent(relay) == [("alive", one)]
    assert _events(relay) == [RemoteNodeLiveness("drone-1", "talker", up=True)]
    text = "\n".join(render_status({"ros2": relay.status(5.0)}))
    assert "node stopped" not in text
    relay.peer_liveness("drone-2", b"\x00", 6.0)
    text = "\n".join(render_status({"ros2": relay.status(6.0)}))
    assert re.search(r"drone-2 +talker +node stopped", text), text


def test_liveness_before_discovery_is_kept_and_unknown_drones_are_counted() -> None:
    relay = _relay("lead")
    relay.peer_liveness("drone-2", b"", 0.0)  # missing bits: not alive
    assert _sent(relay) == []  # swarmd has not found drone-2: nothing to dispose
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 1.0)
    assert _sent(relay) == []  # discovered, but its node is stopped: not announced
    relay.peer_liveness("nobody", b"\xff", 1.0)
    relay.peer_liveness("lead", b"\xff", 1.0)  # our own drone is not a remote one
    assert relay.counters["liveness_unknown_drone"] == 2
    assert _sent(relay) == []


# ---- swarmd carries it, signed --------------------------------------------------------------

BUNDLE = make_bundle(3)
A1 = (node_ipv4(1), 7412)


def _drain(engine: DiscoveryEngine) -> list[Event]:
    out = []
    while (e := engine.next_event()) is not None:
        out.append(e)
    return out


def _liveness(events: list[Event]) -> list[bytes]:
    return [e.alive for e in events if isinstance(e, PeerRos2Liveness)]


def test_the_engine_sends_the_bitmap_only_with_a_relay_and_pulls_its_multicast_in() -> None:
    e = engine_for(BUNDLE, 0)
    e.receive_datagram(peer_datagram(BUNDLE, 1, heard=(0, 1, 2)), A1, 0.1)
    e.receive_datagram(peer_datagram(BUNDLE, 2, heard=(0, 1, 2)), (node_ipv4(2), 7414), 0.1)
    now = 0.1
    sent: list[bytes] = []
    while (t := e.get_timer()) is not None and t < 60.0:
        now = t
        e.handle_timer(now)
        sent += [d for d, _ in e.datagrams_to_send()]
    assert sent and all(PID_SWARMD_ROS2_ALIVE.to_bytes(2, "little") not in d for d in sent)
    renewal = e.get_timer()
    assert renewal is not None
    e.set_ros2_alive(b"\x02", now)
    pulled = e.get_timer()
    assert pulled is not None and pulled < renewal  # not a renewal period away
    e.handle_timer(pulled)
    (data, _dest), *_ = e.datagrams_to_send()
    _header, samples = decode_spdp(data)
    assert isinstance(samples[0], SpdpAlive)
    assert samples[0].participant.ros2_alive == b"\x02"
    # a local process flapping its node: at most one multicast per retransmit gap
    e.set_ros2_alive(b"\x00", pulled)
    again = e.get_timer()
    assert again is not None and again >= pulled + 0.5


def test_a_peers_signed_liveness_is_reported_once_per_change() -> None:
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    a1 = auth_for(BUNDLE, 1)
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x01"), A1, 0.1)
    assert _liveness(_drain(e)) == [b"\x01"]
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x01"), A1, 0.2)
    assert _liveness(_drain(e)) == []
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x00"), A1, 0.3)
    assert _liveness(_drain(e)) == [b"\x00"]
    e.receive_datagram(peer_datagram(BUNDLE, 1, auth=a1), A1, 0.4)  # absent: no word
    assert _liveness(_drain(e)) == []


def test_a_forged_or_replayed_liveness_change_is_refused() -> None:
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    a1 = auth_for(BUNDLE, 1)
    alive = peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x01")
    stopped = peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x00")
    e.receive_datagram(alive, A1, 0.1)
    e.receive_datagram(stopped, A1, 0.2)
    assert _liveness(_drain(e)) == [b"\x01", b"\x00"]
    # replayed: the older, genuine "alive" word (an attacker reviving a stopped node)
    e.receive_datagram(alive, A1, 0.3)
    events = _drain(e)
    assert _liveness(events) == [] and all(isinstance(x, PacketDropped) for x in events)
    assert e.counters()["dropped"]["auth_replayed"] == 1
    # forged: a fresh genuine datagram with its bitmap byte flipped on the air
    fresh = peer_datagram(BUNDLE, 1, auth=a1, ros2_alive=b"\x00")
    pid = PID_SWARMD_ROS2_ALIVE.to_bytes(2, "little") + (8).to_bytes(2, "little")
    at = fresh.index(pid) + 8  # PID, length, octet count, then the bitmap
    forged = fresh[:at] + b"\x01" + fresh[at + 1 :]
    e.receive_datagram(forged, A1, 0.4)
    # signed by another member (a captured drone speaking for uav1)
    other = peer_datagram(BUNDLE, 1, auth=auth_for(BUNDLE, 2, epoch=50), ros2_alive=b"\x01")
    e.receive_datagram(other, A1, 0.5)
    events = _drain(e)
    assert _liveness(events) == [] and all(isinstance(x, PacketDropped) for x in events)
    dropped = e.counters()["dropped"]
    # the flipped bit fails uav1's tag; so does the other member's (its own pair keys), its
    # counter made newer than uav1's so that freshness (checked first) lets it that far
    assert dropped["auth_bad_tag"] == 2 and dropped["auth_replayed"] == 1
    # the genuine datagram itself is still good afterwards: nothing was consumed by them
    e.receive_datagram(fresh, A1, 0.6)
    assert _liveness(_drain(e)) == []  # "stopped", as before: no change to report


# ---- a restart under the same GUIDs ---------------------------------------------------------


def test_a_peers_swarmd_restart_disposes_its_nodes_and_announces_them_again() -> None:
    relay, one, two = _lead_with_two_peers()
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 1.0)  # the same drone, same address
    assert _sent(relay) == [] and _events(relay) == []
    # its swarmd restarted (PeerRestarted): the earlier life's proxies go, the new one is
    # matched afresh; dispose first, the same participant announced right after
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 2.0, restarted=True)
    assert _sent(relay) == [("dispose", one), ("alive", one)]
    assert _events(relay) == [RemoteParticipantsRelayed("drone-1", 1, up=True, restarted=True)]
    # a drone swarmd had lost: nothing of it is at the nodes, it is only announced
    relay.peer_lost("drone-2", 3.0)
    relay.datagrams_to_send()
    _events(relay)
    relay.peer_discovered("drone-2", ADDRESS["drone-2"], 4.0, restarted=True)
    assert _sent(relay) == [("alive", two)]
    assert _events(relay) == [RemoteParticipantsRelayed("drone-2", 1, up=True)]
    # a node its relay said was stopped was disposed already: not again. Its new relay
    # says every node alive until it has not heard one for a lease, so it is announced; the
    # new life's word decides (the engine reports it right after the restart)
    relay.peer_liveness("drone-1", b"\x00", 5.0)
    assert _sent(relay) == [("dispose", one)]
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 6.0, restarted=True)
    assert _sent(relay) == [("alive", one)]
    relay.peer_liveness("drone-1", b"\x00", 6.0)
    assert _sent(relay) == [("dispose", one)]  # a stop: no life, nothing damped
    assert relay.counters["remote_liveness_damped"] == 0


def test_a_local_nodes_new_life_is_counted_in_the_signed_liveness_word() -> None:
    relay = _relay("drone-1")
    relay.started(0.0)
    talker = _by("drone-1")
    for sn in (1, 2, 3):
        relay.receive_datagram(_node_spdp(talker, sn), ("::1", 40000), float(sn))
    _events(relay)
    assert relay.liveness() == b"\x01\x00"  # the bitmap, then one restart count per node
    # SIGKILLed and started again within its lease: its bit never went down
    relay.receive_datagram(_node_spdp(talker, 1), ("::1", 40001), 4.0)
    assert _events(relay)[0] == LocalLivenessChanged(b"\x01\x01", "talker", up=True)
    assert relay.liveness() == b"\x01\x01" and relay.alive_bitmap() == b"\x01"
    assert relay.status(4.0)["local"][0]["restarts"] == 1
    relay.receive_datagram(_node_spdp(talker, 2), ("::1", 40001), 5.0)  # a renewal: no event
    assert _events(relay) == []
    # counted modulo 256: one octet per node on the air
    for i in range(255):
        relay.receive_datagram(_node_spdp(talker, 9), ("::1", 40002), 6.0 + i)
        relay.receive_datagram(_node_spdp(talker, 1), ("::1", 40002), 6.5 + i)
    assert relay.liveness() == b"\x01\x00"


def test_a_remote_nodes_new_life_is_disposed_and_announced_again() -> None:
    relay = _relay("lead")
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 0.0)
    relay.datagrams_to_send()
    _events(relay)
    one = GuidPrefix(_by("drone-1").guid_prefix)
    relay.peer_liveness("drone-1", b"\x01\x00", 1.0)  # its first word: the base
    assert _sent(relay) == [] and _events(relay) == []
    relay.peer_liveness("drone-1", b"\x01\x01", 2.0)  # a new life, still alive
    assert _sent(relay) == [("dispose", one), ("alive", one)]
    assert _events(relay) == [RemoteNodeLiveness("drone-1", "talker", up=True, restarted=True)]
    assert relay.counters["remote_restarts"] == 1
    relay.peer_liveness("drone-1", b"\x01\x01", 3.0)  # the same word: nothing
    assert _sent(relay) == []
    # a relay that sends only the bitmap (an older swarmd): no count, no restart seen
    relay.peer_liveness("drone-1", b"\x01", 4.0)
    relay.peer_liveness("drone-1", b"\x01\x02", 5.0)
    assert _sent(relay) == [] and _events(relay) == []
    # stopped (and counted): disposed once; back: announced once, nothing left to dispose
    relay.peer_liveness("drone-1", b"\x00\x03", 6.0)
    assert _sent(relay) == [("dispose", one)]
    relay.peer_liveness("drone-1", b"\x01\x04", 7.0)
    assert _sent(relay) == [("alive", one)]
    assert _events(relay) == [
        RemoteNodeLiveness("drone-1", "talker", up=False),
        RemoteNodeLiveness("drone-1", "talker", up=True),
    ]
    # a word while swarmd does not have the drone moves nothing at the nodes
    relay.peer_lost("drone-1", 8.0)
    relay.datagrams_to_send()
    relay.peer_liveness("drone-1", b"\x01\x05", 9.0)
    assert _sent(relay) == []


def _drive_to(relay: Ros2Relay, now: float) -> None:
    """The driver: every timer due by ``now``, at its deadline."""
    while (due := relay.get_timer()) is not None and due <= now:
        relay.handle_timer(due)


def test_a_captured_members_word_changing_on_every_sample_moves_its_nodes_at_a_bounded_rate() -> (
    None
):
    """Review 18, attacker 2: drone-1's key signs a new restart count for its talker in every
    DATA(p), 4 a datagram at its verification budget (20 a second) for 2.5 s: 200 words, each
    a new life. Its restarts are spaced (0.25 s) and damped in discovery, but each word
    disposed and announced its node again at every local node: 200 re-matches. Now a drone's
    word is acted on at most once per ``LIVENESS_MIN_INTERVAL_S``, the latest held word at
    the interval's end: late, never lost. [fails on main: 200 disposes]"""
    relay, one, _two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)  # its first word: the base
    words, flood_s = 200, 2.5
    for k in range(words // 4):
        now = k * flood_s / (words // 4)
        _drive_to(relay, now)
        for j in range(4):
            relay.peer_liveness("drone-1", bytes((1, (4 * k + j + 1) & 0xFF)), now)
    _drive_to(relay, flood_s + LIVENESS_MIN_INTERVAL_S)
    sent = _sent(relay)
    disposes = sent.count(("dispose", one))
    assert 1 <= disposes <= flood_s / LIVENESS_MIN_INTERVAL_S + 1
    assert relay.counters["remote_restarts"] == disposes
    held = relay.counters["remote_liveness_held"] + relay.counters["remote_liveness_damped"]
    assert held >= words - disposes
    # never lost: its last word is the one acted on last (then nothing is held; review
    # 18b's damping holds it up to FLAP_HOLD_MAX_S)
    _drive_to(relay, flood_s + FLAP_HOLD_MAX_S)
    assert relay.liveness_due() is None
    _sent(relay)  # its renewals meanwhile
    relay.peer_liveness("drone-1", bytes((1, words & 0xFF)), 30.0)  # the same word again
    assert _sent(relay) == []
    # an honest relay's changes, at most one per 0.5 s on the air: each acted on at once
    relay, one, _two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)
    for k in range(1, 4):
        relay.peer_liveness("drone-1", bytes((1, k)), 0.5 * k)
        assert _sent(relay) == [("dispose", one), ("alive", one)]


def _churn(relay: Ros2Relay, seconds: float, *, flip: bool) -> None:
    """A captured drone-1 for ``seconds``: 4 new words a datagram at its verification
    budget (20 a second), a new restart count each (``flip``: its bit down and up in turn
    instead); the relay's timers run between datagrams, as the driver runs them."""
    per_s, per_datagram = 20, 4
    for k in range(int(seconds * per_s)):
        now = k / per_s
        _drive_to(relay, now)
        for j in range(per_datagram):
            n = per_datagram * k + j + 1
            word = bytes((n & 1, 0)) if flip else bytes((1, n & 0xFF))
            relay.peer_liveness("drone-1", word, now)
    _drive_to(relay, seconds + FLAP_HOLD_MAX_S)


@pytest.mark.parametrize("flip", [False, True], ids=["restart-count", "bit-flip"])
def test_a_captured_members_word_churning_for_a_minute_draws_a_handful_of_rematches(
    flip: bool,
) -> None:
    """Review 18b, attacker 2: drone-1's key signs a new liveness word in every sample for a
    minute, 80 a second. Spaced alone (0.25 s), every drone's relay re-matched its node at
    every local node 4 times a second, 240 in the minute. Now the lives a word brings (a
    node back, or restarted) are damped as discovery damps a peer's lives (swarmd/lives.py,
    RFC 2439, one penalty per drone): the first 4 at once, then one per ``FLAP_HOLD_MAX_S``
    at most. [fails on main: 240 announcements in the minute]"""
    relay, one, _two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)  # its first word: the base
    _churn(relay, 60.0, flip=flip)
    moves = [e for e in _events(relay) if isinstance(e, RemoteNodeLiveness)]
    lives = sum(e.up for e in moves)  # each a re-match at every local node
    lives_at_most = FREE_LIVES + math.ceil(60.0 / FLAP_HOLD_MAX_S)  # 4 free + 3 = 7
    assert FREE_LIVES <= lives <= lives_at_most
    assert len(moves) - lives <= lives + 1  # a stop only after a life
    assert _sent(relay).count(("dispose", one)) <= 2 * lives + 1
    assert relay.counters["remote_liveness_damped"] > 0


FREE_LIVES = int(FLAP_PENALTY_LIMIT) + 1


def _node_life(relay: Ros2Relay, n: int, now: float, *, stop: bool) -> bool:
    """drone-1's talker's ``n``-th new life, as its honest relay says it: a stop (bit
    down) then its start (``stop``), or a restart under the same GUIDs (the count); True
    when the lead's relay acted on the life (announced the node again) at its word."""
    if stop:
        relay.peer_liveness("drone-1", bytes((0, n - 1)), now)
        now += 0.5  # swarmd's next pulled-in multicast carries the start
        _drive_to(relay, now)
        assert RemoteNodeLiveness("drone-1", "talker", up=False) in _events(relay)  # at once
    relay.peer_liveness("drone-1", bytes((1, n)), now)
    return _rematched(relay)


def _rematched(relay: Ros2Relay) -> bool:
    return any(isinstance(e, RemoteNodeLiveness) and e.up for e in _events(relay))


@pytest.mark.parametrize("stop", [False, True], ids=["restart", "stop-and-start"])
def test_an_honest_nodes_lives_are_acted_on_at_once_and_a_crash_loop_late_never_lost(
    stop: bool,
) -> None:
    """The honest shapes of tests/test_discovery_lives.py, for a node: a few restarts (or
    stops and starts) an hour apart are all acted on at once; a crash loop at systemd's
    fastest (RestartSec=2s and a start-up) has its first 4 lives at once, the next late by
    at most ``FLAP_HOLD_MAX_S``, and its last word is the one that stays."""
    relay, _one, _two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)
    for n in range(1, 13):  # one every 300 s
        now = 300.0 * n
        _drive_to(relay, now)
        assert _node_life(relay, n, now, stop=stop)
    # a crash loop, 2.288 s apart: free lives at once, then held
    base, start = 12, 300.0 * 13
    for k in range(FREE_LIVES):
        _drive_to(relay, start + 2.288 * k)
        assert _node_life(relay, base + 1 + k, start + 2.288 * k, stop=stop)
    late = start + 2.288 * FREE_LIVES
    _drive_to(relay, late)
    assert not _node_life(relay, base + FREE_LIVES + 1, late, stop=stop)
    assert relay.counters["remote_liveness_damped"] == 1
    _drive_to(relay, late + FLAP_HOLD_MAX_S)  # late, never lost
    assert _rematched(relay)
    rows = {r["drone"]: r["state"] for r in relay.status(late + 30.0)["remote"]}
    assert rows["drone-1"] == "relayed"


def test_a_drone_flying_out_and_back_past_its_free_lives_is_announced_at_once() -> None:
    """A fly-out and back is swarmd's PeerLost and PeerDiscovered, no word: never held,
    whatever the drone's penalty (tests/test_discovery_lives.py's fly-out, for the relay)."""
    relay, one, _two = _lead_with_two_peers()
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)
    _churn(relay, 5.0, flip=False)  # its penalty past the limit
    _sent(relay)
    assert relay.counters["remote_liveness_damped"] > 0
    relay.peer_lost("drone-1", 40.0)
    assert _sent(relay) == [("dispose", one)]
    relay.peer_discovered("drone-1", ADDRESS["drone-1"], 41.0)
    assert _sent(relay) == [("alive", one)]


ROS2_BUNDLE = build_dev_bundle(parse_mission(MISSION)).bundle
UAV1 = (ADDRESS["drone-1"], 7412)


def _to_relay(relay: Ros2Relay, events: list[Event], now: float) -> None:
    """The daemon's routing of discovery's events to its relay (swarmd.daemon)."""
    for event in events:
        if isinstance(event, PeerDiscovered):
            relay.peer_discovered(event.name, ADDRESS[event.name], now)
        elif isinstance(event, PeerRestarted):
            relay.peer_discovered(event.name, ADDRESS[event.name], now, restarted=True)
        elif isinstance(event, PeerRos2Liveness):
            relay.peer_liveness(event.name, event.alive, now)


def test_only_an_authenticated_restart_makes_the_relay_dispose() -> None:
    """The attacker's way to cut a drone's ROS 2 data for a moment, over and over: a forged
    or replayed restart (a higher epoch, or a changed restart count) is refused by the
    engine before the relay hears of it; genuine restarts cost two loopback datagrams per
    participant and local node each, one per epoch rise."""
    e = engine_for(ROS2_BUNDLE, 0, auth=auth_for(ROS2_BUNDLE, 0))
    relay = _relay("lead")
    one = GuidPrefix(_by("drone-1").guid_prefix)
    life = auth_for(ROS2_BUNDLE, 1, epoch=5)
    captured = peer_datagram(ROS2_BUNDLE, 1, auth=life, ros2_alive=b"\x01\x00")
    e.receive_datagram(captured, UAV1, 0.1)
    _to_relay(relay, _drain(e), 0.1)
    assert _sent(relay) == [("alive", one)]
    # forged: uav1 at a higher epoch, sealed by another member (a captured drone)
    forged = peer_datagram(
        ROS2_BUNDLE, 1, auth=auth_for(ROS2_BUNDLE, 2, epoch=50), ros2_alive=b"\x01\x07"
    )
    # forged: a genuine fresh datagram with its restart count changed on the air
    fresh = peer_datagram(ROS2_BUNDLE, 1, auth=life, ros2_alive=b"\x01\x00")
    pid = PID_SWARMD_ROS2_ALIVE.to_bytes(2, "little") + (8).to_bytes(2, "little")
    at = fresh.index(pid) + 9  # PID, length, octet count, the bitmap, then the count
    flipped = fresh[:at] + b"\x09" + fresh[at + 1 :]
    for i, attack in enumerate((forged, flipped, captured)):  # captured: a replay
        e.receive_datagram(attack, UAV1, 0.2 + i / 10)
        events = _drain(e)
        assert all(isinstance(x, PacketDropped) for x in events), events
        _to_relay(relay, events, 0.2)
    assert _sent(relay) == []
    dropped = e.counters()["dropped"]
    assert dropped["auth_bad_tag"] == 2 and dropped["auth_replayed"] == 1
    # genuine restarts, each a higher epoch: one dispose and one announcement each
    for epoch in (6, 7, 8):
        restarted = peer_datagram(
            ROS2_BUNDLE, 1, auth=auth_for(ROS2_BUNDLE, 1, epoch=epoch), ros2_alive=b"\x01\x00"
        )
        e.receive_datagram(restarted, UAV1, float(epoch))
        events = _drain(e)
        assert [x.epoch for x in events if isinstance(x, PeerRestarted)] == [epoch]
        _to_relay(relay, events, float(epoch))
        assert _sent(relay) == [("dispose", one), ("alive", one)]
        e.receive_datagram(restarted, UAV1, epoch + 0.5)  # its replay: refused, nothing
        _to_relay(relay, _drain(e), epoch + 0.5)
        assert _sent(relay) == []
