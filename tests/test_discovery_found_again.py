"""A found-again peer that misses our pulled-in multicast gets it directed a re-ack gap later
(``Debts.defer_found_again``, ``Debts.take_late_copies``; issue 20, docs/benchmarks.md, "The
fly-out at N = 20").

At the edge of range the answer lost was a multicast: 802.11 sends a group frame once,
unacknowledged, while a directed one is acknowledged and retried by the MAC. So the multicast
a rejoin pulls in (``pullin.PullIn.rejoined``) is followed, a re-ack gap later, by a directed
copy to each peer found again since our last multicast that does not list us by then. The
shape on MemNet, virtual time: two sides of ``SIDE``, cut apart from ``T_CUT`` to ``T_BACK``;
after the return every multicast from the left side to the right one is lost (the right
side's reach the left), so the right side can only learn that the left heard it from a
directed frame.
"""

from __future__ import annotations

import math
from collections import Counter

import pytest
from swarmd_lab.testing import (
    ScriptedSender,
    Swarm,
    auth_for,
    build_swarm,
    leave_or_return_datagram,
    node_ipv4,
)

from swarmd import lives
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.events import PeerDiscovered

SEEDS = (1, 2, 3, 4, 5)
SIDE = 3
N = 2 * SIDE
T_CUT = 30.0
T_BACK = 60.0
REACK_GAP_S = EngineConfig().retransmit_min_gap_s  # 0.5 s
# the rejoin delay's 0.12 s at N = 6, then the re-ack gap the copy waits, with room
ANSWER_S = 0.12 + REACK_GAP_S + 0.1


def _left(i: int) -> bool:
    return i < SIDE


def _ms(t: float) -> int:
    """A send time in whole milliseconds: the copy's deadline is the multicast's + the gap."""
    return round(t * 1000.0)


def _healed_swarm(seed: int, until: float) -> Swarm:
    swarm = build_swarm(N, seed=seed)
    net = swarm.net

    def loss(a: int, b: int) -> float:
        if _left(a) == _left(b) or net.now < T_CUT:
            return 0.0
        if net.now < T_BACK:
            return 1.0
        # MemNet appends the transmission before it asks each receiver's loss
        return 1.0 if _left(a) and net.transmissions[-1].multicast else 0.0

    net.link_loss = loss
    swarm.run_until(until)
    return swarm


@pytest.mark.parametrize("seed", SEEDS)
def test_the_right_side_finds_the_left_again_by_its_directed_copies(seed: int) -> None:
    """Each right drone's first multicast after the return crosses, and the left drones that
    find it answer by a multicast (lost) and, a re-ack gap later, a directed copy: the right
    drone finds each of them within ANSWER_S of that frame (the rejoin delay U(0, N / 50 fps)
    is 0.12 s here, then the gap)."""
    swarm = _healed_swarm(seed, T_BACK + 10.0)
    for r in range(SIDE, N):
        asked = min(
            x.time
            for x in swarm.net.transmissions
            if x.node == r and x.multicast and x.time >= T_BACK
        )
        for left in range(SIDE):
            name = swarm.bundle.participants[left].name
            found = [
                t
                for t, e in swarm.events[r]
                if t >= T_BACK and isinstance(e, PeerDiscovered) and e.name == name
            ]
            assert found, (r, left)
            assert found[0] - asked <= ANSWER_S, (r, left, found[0] - asked)


def test_a_copy_goes_a_gap_after_the_multicast_and_only_to_peers_found_again() -> None:
    swarm = _healed_swarm(1, T_BACK + 10.0)
    sent = swarm.net.transmissions
    multicasts = {(x.node, _ms(x.time)) for x in sent if x.multicast and x.time >= T_BACK}
    right = {node_ipv4(i) for i in range(SIDE, N)}
    directed = [x for x in sent if not x.multicast and _left(x.node) and x.time >= T_BACK]
    copies = [x for x in directed if (x.node, _ms(x.time - REACK_GAP_S)) in multicasts]
    assert copies  # the left side answered the right's seeks by a multicast and late copies
    assert all(x.target[0] in right for x in copies)  # never to a peer it had not lost
    assert not [x for x in directed if (x.node, _ms(x.time)) in multicasts]  # none with it


def test_no_copy_to_a_peer_that_heard_the_multicast() -> None:
    """The clean case: every frame crosses after the return, so each peer found again hears
    our pulled-in multicast and lists us within its rejoin delay (under the gap): no
    directed copy at all (before: one per rejoining pair)."""
    swarm = build_swarm(N, seed=1)
    net = swarm.net

    def loss(a: int, b: int) -> float:
        return 1.0 if _left(a) != _left(b) and T_CUT <= net.now < T_BACK else 0.0

    net.link_loss = loss
    swarm.run_until(T_BACK + 10.0)
    assert swarm.all_discovered()
    sent = net.transmissions
    multicasts = {(x.node, _ms(x.time)) for x in sent if x.multicast and x.time >= T_BACK}
    copies = [
        x
        for x in sent
        if not x.multicast
        and x.time >= T_BACK
        and {(x.node, _ms(x.time)), (x.node, _ms(x.time - REACK_GAP_S))} & multicasts
    ]
    assert copies == []


# ------------------------------------------------------------------ a captured member's attack

ATTACK_N = 10
ATTACKER = ATTACK_N - 1  # uav9, captured: its genuine key, the attacker's firmware
HONEST = range(ATTACK_N - 2)
MISSING = ATTACK_N - 2  # uav8, cut off: every honest drone has a peer still missing
T_ATTACK = 60.0
ATTACK_FOR_S = 30.0  # the bounded virtual-time window
ATTACK_PERIOD_S = 0.05  # a leave and a return every 0.1 s: 600 frames in all
# a slow cycle: back for 0.8 s each time, long enough for the copy a gap after the
# pulled-in multicast to fall due while it is back (and it never lists anyone)
SLOW_PERIOD_S = 0.8


class _LeavingAndReturning(ScriptedSender):
    """uav9 after capture: every ``ATTACK_PERIOD_S`` a multicast sealed with its real key,
    alternately a DATA(p[UD]) (it leaves: the others lose it) and a DATA(p) that lists
    nobody (it is back: the others find it again, and owe it a copy of their next
    multicast). Sending stops at ``T_ATTACK + ATTACK_FOR_S``."""

    def __init__(self, swarm: Swarm, now: float, period_s: float = ATTACK_PERIOD_S) -> None:
        super().__init__(now)
        self._swarm = swarm
        self._period_s = period_s
        self._auth = auth_for(swarm.bundle, ATTACKER, now=now)
        self._sn = 10_000  # above its honest life's
        self.sent = 0

    def handle_timer(self, now: float) -> None:
        group = self._swarm.engines[0].spdp_multicast
        while self._next is not None and self._next <= now:
            self._sn += 1  # odd first: it leaves, then it is back
            frame = leave_or_return_datagram(
                self._swarm.bundle, ATTACKER, sequence_number=self._sn, auth=self._auth
            )
            self._out.append((frame, group))
            self.sent += 1
            self._next += self._period_s
            if self._next > T_ATTACK + ATTACK_FOR_S:
                self._next = None


@pytest.mark.parametrize("period_s", [ATTACK_PERIOD_S, SLOW_PERIOD_S])
def test_a_captured_member_leaving_and_returning_draws_at_most_one_copy_per_reack_gap(
    period_s: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The copy is a send path driven by a peer's frames: at most one is owed per peer at a
    time (``Debts.defer_found_again``), each falls due a re-ack gap after our multicast and
    takes the peer's gap (``Debts.take_late_copies``), so a captured member that leaves and
    returns draws at most one directed frame per gap from each honest drone (10 times a
    second: none falls due, each loss cancels it; every 1.6 s: about one per return), and
    the honest drones' multicasts stay at one per gap too (``PullIn.pull_in``). The bound
    must hold on its own, so the lives' damping (``lives.py``: after 4 returns it holds
    the member's next for up to 25 s, and the attack would not take hold) is off here."""
    monkeypatch.setattr(lives, "FLAP_PENALTY_LIMIT", math.inf)
    swarm = build_swarm(ATTACK_N, seed=7, authenticated=True)
    swarm.run_until(30.0)
    assert swarm.all_discovered(), "the swarm did not form before the attack"
    swarm.net.isolate(MISSING)  # lost by everyone by T_ATTACK: somebody is missing
    swarm.run_until(T_ATTACK)
    attacker = _LeavingAndReturning(swarm, T_ATTACK, period_s)
    swarm.net.replace(ATTACKER, attacker)
    start = len(swarm.net.transmissions)
    swarm.run_until(T_ATTACK + ATTACK_FOR_S)
    assert attacker.sent >= ATTACK_FOR_S / period_s  # the attack ran, ...
    found = Counter(
        i
        for i in HONEST
        for t, e in swarm.events[i]
        if t >= T_ATTACK and isinstance(e, PeerDiscovered) and e.name == "uav9"
    )
    took_hold = ATTACK_FOR_S / REACK_GAP_S if period_s == ATTACK_PERIOD_S else 5
    assert min(found[i] for i in HONEST) >= took_hold  # ... and took hold
    sent = swarm.net.transmissions[start:]
    copies = Counter(x.node for x in sent if not x.multicast and x.target[0] == node_ipv4(ATTACKER))
    multicasts = Counter(x.node for x in sent if x.multicast and x.node in HONEST)
    bound = ATTACK_FOR_S / REACK_GAP_S + 1
    for i in HONEST:  # one per gap, and (a copy is owed once per return) one per return
        assert copies[i] <= min(bound, found[i] + 1), (i, copies, found)
    assert max(multicasts.values()) <= bound, multicasts
    if period_s == SLOW_PERIOD_S:  # the late copies were drawn where they could be
        assert all(copies[i] >= found[i] / 2 for i in HONEST), (copies, found)
