"""A peer's swarmd restart and its relay's liveness word (PID 0x8A06) at the ROS 2 relay
(docs/ros2.md, "A restart under the same GUIDs"), on hand-set time, discovery's engine and
the relay joined as the daemon joins them.

A restarted swarmd's relay starts again: every node alive, every restart count 0. The
engine reported that new word before ``PeerRestarted`` for the same datagram, so the relay
took a count gone back to 0 for a restart of the node and re-matched it (dispose and
announce at every local node, one penalty of the drone's damping), then the restart
re-matched it again: two re-matches and a penalty for one honest restart. Now the restart
comes first and the new life's first word is its baseline. A captured member gains
nothing by it: its penalty and spacing stay, and its restarts are discovery's to damp."""

from __future__ import annotations

import math

import pytest
from swarmd_lab.testing import auth_for, engine_for, peer_datagram

from swarmd.auth.spdp import SpdpAuth
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.discovery import DiscoveryEngine, PeerRestarted, PeerRos2Liveness
from swarmd.discovery.events import Event
from swarmd.lives import FLAP_HOLD_MAX_S, FLAP_PENALTY_LIMIT
from swarmd.ros2.relay import Ros2Relay
from swarmd.ros2.relay_events import RemoteNodeLiveness, RemoteParticipantsRelayed
from swarmd.rtps.spdp import SpdpDisposed, decode_spdp
from swarmd.rtps.types import GuidPrefix
from tests.test_ros2_liveness import LEASE_S, MISSION, UAV1, _to_relay  # as the daemon routes

BUNDLE = build_dev_bundle(parse_mission(MISSION)).bundle
PARTICIPANTS = bundle_ros2_participants(BUNDLE)
TALKER = GuidPrefix(next(p for p in PARTICIPANTS if p.drone == "drone-1").guid_prefix)
FREE_LIVES = int(FLAP_PENALTY_LIMIT) + 1
CRASH_LOOP_S = 2.0 + 0.288  # tests/test_discovery_lives.py: RestartSec=2s + a start-up


class Lead:
    """The lead's discovery engine and relay, joined as swarmd.daemon joins them, hearing
    drone-1 (bundle index 1)."""

    def __init__(self) -> None:
        self.engine: DiscoveryEngine = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
        self.relay = Ros2Relay(PARTICIPANTS, "lead", domain_id=0, lease_s=LEASE_S, epoch=7)
        self.events: list[Event] = []
        self.sn = 0

    def hear(self, auth: SpdpAuth, word: bytes | None, now: float) -> list[str]:
        """drone-1's DATA(p) sealed by ``auth`` carrying ``word``: what the relay sent the
        local nodes about its talker ("dispose", "alive")."""
        self.sn += 1
        datagram = peer_datagram(
            BUNDLE, 1, sequence_number=self.sn, auth=auth, ros2_alive=word, heard=(0, 1)
        )
        self.engine.receive_datagram(datagram, UAV1, now)
        events = []
        while (e := self.engine.next_event()) is not None:
            events.append(e)
        self.events += events
        _to_relay(self.relay, events, now)
        return self.sent()

    def run_to(self, now: float) -> None:
        """The relay's timers due by ``now``, as the driver runs them (its renewals)."""
        while (due := self.relay.get_timer()) is not None and due <= now:
            self.relay.handle_timer(due)
        self.relay.datagrams_to_send()

    def sent(self) -> list[str]:
        out = []
        for data, _dest in self.relay.datagrams_to_send():
            for s in decode_spdp(data)[1]:
                prefix = s.guid_prefix if isinstance(s, SpdpDisposed) else s.participant.guid_prefix
                if prefix == TALKER:
                    out.append("dispose" if isinstance(s, SpdpDisposed) else "alive")
        return out

    def rematches(self) -> int:
        """Re-matches of drone-1's talker the relay reported (each a dispose and an
        announcement, or an announcement, at every local node) since last asked."""
        n = 0
        while (e := self.relay.next_event()) is not None:
            n += isinstance(e, RemoteNodeLiveness) and e.up
            n += isinstance(e, RemoteParticipantsRelayed) and e.restarted
        return n


# (the old life's last word, the new life's datagrams' words: None carries none) and what the
# relay sends the local nodes for the restart
SHAPES: dict[str, tuple[bytes, list[bytes | None], list[str]]] = {
    # the talker kept running through a swarmd restart, after 2 restarts of its own
    "word-in-the-first-datagram": (b"\x01\x02", [b"\x01\x00"], ["dispose", "alive"]),
    # the word comes a datagram later (a swarmd whose first DATA(p) had none)
    "word-in-a-later-datagram": (b"\x01\x02", [None, b"\x01\x00"], ["dispose", "alive"]),
    # the new life's word is the old one: reported all the same, as the baseline
    "the-same-word-again": (b"\x01\x00", [None, b"\x01\x00"], ["dispose", "alive"]),
    # the talker had stopped (disposed at the lead): announced once, nothing to dispose
    "talker-stopped-before": (b"\x00\x01", [b"\x01\x00"], ["alive"]),
}


@pytest.mark.parametrize("shape", list(SHAPES))
def test_an_honest_restart_is_one_rematch_and_its_counts_the_new_baseline(shape: str) -> None:
    """An honest swarmd restart of drone-1: one re-match of its talker at the lead's local
    nodes and no penalty at the relay (discovery's one for the restart is the penalty), so
    the talker's next 4 lives under the new swarmd are all acted on at once and its 5th is
    damped, as for a drone that never restarted. [fails on main: word-in-the-first-datagram
    and word-in-a-later-datagram sent dispose, alive, dispose, alive, talker-stopped-before
    alive, dispose, alive. the-same-word-again passes on main; it fails if the engine does
    not report the new life's first word (the relay then misses the talker's next restart)]"""
    old, new, expected = SHAPES[shape]
    lead = Lead()
    lead.hear(auth_for(BUNDLE, 1, epoch=5), old, 0.1)  # the old life's word: the baseline
    lead.rematches()
    restart = 10.0
    lead.run_to(restart)
    life = auth_for(BUNDLE, 1, epoch=6, now=restart)
    sent = []
    for k, word in enumerate(new):
        sent += lead.hear(life, word, restart + k)
    assert sent == expected
    assert lead.rematches() == 1
    assert [type(e) for e in lead.events if isinstance(e, PeerRestarted)] == [PeerRestarted]
    # the new life's counts are the baseline: its talker's own lives are seen, each once,
    # the first 4 at once (the drone's penalty at the relay was not touched by the restart)
    free_lives_then_damped(lead, life, restart + 10.0)


def free_lives_then_damped(lead: Lead, auth: SpdpAuth, now: float) -> None:
    """drone-1's talker restarts under ``auth``, 0.5 s apart from ``now`` (its count 1, 2,
    ...): its first 4 lives are acted on at once (dispose, alive), its 5th is damped, as
    for a drone whose penalty at the relay is 0."""
    for n in range(1, FREE_LIVES + 1):
        now += 0.5
        assert lead.hear(auth, bytes((1, n)), now) == ["dispose", "alive"], n
    assert lead.hear(auth, bytes((1, FREE_LIVES + 1)), now + 0.5) == []  # damped
    assert lead.relay.counters["remote_liveness_damped"] == 1


def test_a_restart_discovery_holds_brings_its_word_with_it() -> None:
    """An honest crash loop past its free lives, each life's talker restarted once in it
    (its count 1 when the life ends): every restart is one re-match, at the datagram
    discovery honours it; a held life's word waits with it, so the relay's damping adds
    no hold to discovery's (one re-match when the last life is honoured, at most
    ``FLAP_HOLD_MAX_S`` after the last one honoured). [fails on main: the first restart
    re-matched the talker twice; and if the engine reports a held life's word before its
    restart: re-matched at the word and again at the restart]"""
    lead = Lead()
    lead.hear(auth_for(BUNDLE, 1, epoch=1), b"\x01\x00", 0.0)
    lead.rematches()
    honoured = []
    auth = auth_for(BUNDLE, 1, epoch=1)
    lives = FREE_LIVES + 2
    for k in range(1, lives + 1):
        now = k * CRASH_LOOP_S
        auth = auth_for(BUNDLE, 1, epoch=1 + k, now=now)
        before = len([e for e in lead.events if isinstance(e, PeerRestarted)])
        sent = lead.hear(auth, b"\x01\x00", now)
        restarted = len([e for e in lead.events if isinstance(e, PeerRestarted)]) > before
        assert sent == (["dispose", "alive"] if restarted else []), k
        assert lead.rematches() == restarted
        honoured.append(restarted)
        # the talker restarts in this life: a node life at the relay if the life is taken
        lead.run_to(now + 1.0)
        sent = lead.hear(auth, b"\x01\x01", now + 1.0)
        assert sent == (["dispose", "alive"] if restarted else []), k
        lead.rematches()
    assert honoured == [True] * FREE_LIVES + [False] * (lives - FREE_LIVES)
    # the loop stops; the last life renews every second until discovery takes it
    stopped, now = lives * CRASH_LOOP_S, lives * CRASH_LOOP_S + 1.0
    sent = []
    while not sent and now < stopped + 2 * FLAP_HOLD_MAX_S:
        now += 1.0
        lead.run_to(now)
        sent = lead.hear(auth, b"\x01\x01", now)
    assert sent == ["dispose", "alive"]  # one re-match: its word is the new baseline
    assert now - FREE_LIVES * CRASH_LOOP_S <= FLAP_HOLD_MAX_S + 1.0
    assert lead.rematches() == 1
    assert lead.relay.counters["remote_liveness_damped"] == 0


def test_a_captured_member_framing_churn_as_restarts_gains_no_rematches() -> None:
    """Review-18 attacker 2 with restarts: drone-1's key signs a new restart count in every
    DATA(p) (20 a second, its verification budget) and a new boot epoch in every 6th
    (0.3 s apart, past discovery's spacing) for a minute. A restart makes the new life's
    word its baseline, but not the drone's penalty or spacing: the re-matches stay within
    discovery's damped restarts plus the relay's damped words (each the first 4, then one
    per ``FLAP_HOLD_MAX_S``). [passes on main; fails if a restart resets the drone's
    penalty at the relay: 19 word lives in the minute]"""
    lead = Lead()
    epoch = 1
    auth = auth_for(BUNDLE, 1, epoch=epoch)
    lead.hear(auth, b"\x01\x00", 0.0)
    lead.rematches()
    seconds, per_s = 60.0, 20
    for k in range(1, int(seconds * per_s)):
        now = k / per_s
        lead.run_to(now)
        if k % 6 == 0:
            epoch += 1
            auth = auth_for(BUNDLE, 1, epoch=epoch, now=now)
        lead.hear(auth, bytes((1, k & 0xFF)), now)
    lead.run_to(seconds + FLAP_HOLD_MAX_S)
    lead.sent()
    events = []
    while (e := lead.relay.next_event()) is not None:
        events.append(e)
    restarts = sum(isinstance(e, RemoteParticipantsRelayed) and e.restarted for e in events)
    words = sum(isinstance(e, RemoteNodeLiveness) and e.up for e in events)
    bound = FREE_LIVES + math.ceil((seconds + FLAP_HOLD_MAX_S) / FLAP_HOLD_MAX_S)
    assert 1 <= restarts <= bound
    assert words <= bound
    assert lead.relay.counters["remote_liveness_damped"] > 0


def test_the_engine_reports_a_restart_before_its_new_lifes_word() -> None:
    """The order the relay needs (swarmd.discovery.receive): ``PeerRestarted`` then the new
    life's word, reported even when it equals the old life's; a word of a life discovery
    holds is reported with its restart, not before. [fails on main: the word came first]"""
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))

    def hear(auth: SpdpAuth, word: bytes, now: float, sn: int) -> list[type[Event]]:
        e.receive_datagram(
            peer_datagram(BUNDLE, 1, sequence_number=sn, auth=auth, ros2_alive=word), UAV1, now
        )
        out: list[type[Event]] = []
        while (x := e.next_event()) is not None:
            if isinstance(x, PeerRestarted | PeerRos2Liveness):
                out.append(type(x))
        return out

    assert hear(auth_for(BUNDLE, 1, epoch=1), b"\x01\x02", 0.0, 1) == [PeerRos2Liveness]
    assert hear(auth_for(BUNDLE, 1, epoch=2, now=1.0), b"\x01\x00", 1.0, 1) == [
        PeerRestarted,
        PeerRos2Liveness,
    ]
    # the same word in the next life: reported, as that life's baseline
    assert hear(auth_for(BUNDLE, 1, epoch=3, now=2.0), b"\x01\x00", 2.0, 1) == [
        PeerRestarted,
        PeerRos2Liveness,
    ]
    # a restart within discovery's spacing (0.25 s): held, and its word with it
    held = auth_for(BUNDLE, 1, epoch=4, now=2.1)
    assert hear(held, b"\x01\x05", 2.1, 1) == []
    assert hear(held, b"\x01\x05", 2.5, 2) == [PeerRestarted, PeerRos2Liveness]
