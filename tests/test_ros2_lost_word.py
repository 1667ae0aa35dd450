"""A drone's liveness word (PID 0x8A06) heard while swarmd has lost the drone (docs/ros2.md,
"Node liveness"), on hand-set time, discovery's engine and the relay joined as the daemon
joins them.

When a lost drone is heard again, the engine reports its relay's word before the drone is
found (swarmd.discovery.receive: the word in ``_heard``, ``PeerDiscovered`` after it). The
relay took that word's life (a node back) as one it acted on and added it to the drone's
damping penalty, though it sent nothing: the drone's nodes are announced when swarmd finds
it, and that return is discovery's (its own life, damped by discovery when it follows the
drone's own dispose; a lease loss, a fly-out and back, is no life). An honest fly-out in
which a node came back cost one of the drone's 4 free word lives. Now only a word that
re-matches something adds to the penalty. A captured member gains nothing by "lost, then
word": a word heard while lost moves nothing, and its return is damped by discovery."""

from __future__ import annotations

import math

from swarmd_lab.testing import auth_for, leave_or_return_datagram, run_to

from swarmd.discovery import PeerDiscovered, PeerLost
from swarmd.lives import FLAP_HOLD_MAX_S
from tests.test_ros2_liveness import UAV1
from tests.test_ros2_restart_word import BUNDLE, FREE_LIVES, Lead, free_lives_then_damped


def _route_losses(lead: Lead, now: float) -> list[str]:
    """The engine's timers up to ``now``; its losses routed to the relay as swarmd.daemon
    routes them (``peer_lost``). The reasons."""
    run_to(lead.engine, now)
    reasons = []
    while (e := lead.engine.next_event()) is not None:
        lead.events.append(e)
        if isinstance(e, PeerLost):
            lead.relay.peer_lost(e.name, now)
            reasons.append(e.reason)
    lead.sent()
    return reasons


def test_a_word_heard_while_the_drone_is_lost_adds_no_penalty() -> None:
    """drone-1's talker stops, then drone-1 flies out of range (a lease loss) and its talker
    starts again meanwhile. Back in range, its first DATA(p) carries the new word: the
    talker is announced once, when swarmd finds the drone, and the drone's penalty at the
    relay is untouched, so the talker's next 4 lives are acted on at once and the 5th is
    damped, as for a drone that never left. [fails on main: the word heard while lost
    counted as a life, the 4th was damped]"""
    lead = Lead()
    auth = auth_for(BUNDLE, 1, epoch=1)
    lead.hear(auth, b"\x01\x00", 0.0)
    assert lead.hear(auth, b"\x00\x00", 1.0) == ["dispose"]  # the talker stopped
    lead.rematches()
    now = 1.0
    reasons: list[str] = []
    while not reasons and now < 120.0:  # bounded: a lease is seconds
        now += 1.0
        reasons = _route_losses(lead, now)
    assert reasons == ["lease"]
    # back: the word (the talker alive again) is reported before the drone is found
    now += 5.0
    assert lead.hear(auth, b"\x01\x00", now) == ["alive"]
    assert lead.rematches() == 1
    free_lives_then_damped(lead, auth, now)


def test_a_lost_drones_word_is_not_held_by_its_penalty() -> None:
    """drone-1's talker has spent the drone's free lives (its penalty holds the next), then
    stops; drone-1 flies out, the talker starts again meanwhile, drone-1 comes back: the
    talker is announced at the return (discovery's; the word heard while lost re-matches
    nothing, so no penalty holds it). [fails on main: the word was held by the penalty, so
    the return announced the talker as stopped: nothing sent, the talker unmatched until
    the hold's end, up to ``FLAP_HOLD_MAX_S``]"""
    lead = Lead()
    auth = auth_for(BUNDLE, 1, epoch=1)
    lead.hear(auth, b"\x01\x00", 0.0)
    now = 0.0
    for n in range(1, FREE_LIVES + 1):
        now += 0.5
        assert lead.hear(auth, bytes((1, n)), now) == ["dispose", "alive"], n
    now += 0.5
    assert lead.hear(auth, bytes((0, FREE_LIVES)), now) == ["dispose"]  # a stop: not held
    reasons: list[str] = []
    while not reasons and now < 120.0:  # bounded: a lease is seconds
        now += 1.0
        reasons = _route_losses(lead, now)
    assert reasons == ["lease"]
    assert now + 1.0 < 0.5 * FREE_LIVES + FLAP_HOLD_MAX_S  # back within the hold
    assert lead.hear(auth, bytes((1, FREE_LIVES)), now + 1.0) == ["alive"]
    assert lead.relay.counters["remote_liveness_damped"] == 0


def test_a_captured_member_leaving_and_returning_with_new_words_stays_damped() -> None:
    """A captured drone-1 leaves (its signed dispose) and returns every 0.3 s for a minute,
    each return carrying a word that restarts its talker: every re-match of the talker is
    a return discovery honoured, within discovery's damping (the first 4, then one per
    ``FLAP_HOLD_MAX_S``); the words heard while lost re-match nothing. [passes on main
    too: the check that charging only the words acted on opens no way around damping]"""
    lead = Lead()
    auth = auth_for(BUNDLE, 1, epoch=1)
    lead.hear(auth, b"\x01\x00", 0.0)
    lead.rematches()
    before = len(lead.events)
    seconds, step = 60.0, 0.3
    alive = 0
    for k in range(1, int(seconds / step)):
        now = k * step
        if k % 2:  # leaves: its own dispose (an odd number)
            lead.sn += 1 + lead.sn % 2
            leave = leave_or_return_datagram(BUNDLE, 1, sequence_number=lead.sn, auth=auth)
            lead.engine.receive_datagram(leave, UAV1, now)
            _route_losses(lead, now)
        else:  # returns (the next, even, number), its talker restarted once more
            alive += lead.hear(auth, bytes((1, k & 0xFF)), now).count("alive")
    bound = FREE_LIVES + math.ceil((seconds + FLAP_HOLD_MAX_S) / FLAP_HOLD_MAX_S)
    finds = sum(isinstance(e, PeerDiscovered) for e in lead.events[before:])
    assert 1 <= alive == finds <= bound  # each re-match a return discovery honoured
    assert lead.engine.counters()["lives_damped"] > 0
