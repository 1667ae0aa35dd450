"""A peer that lost us while we kept it (``swarmd/discovery/receive.py``, the lost_us rule;
issue 20: re-discovery within 2 s).

On the emulated channel, in the irregular fade at N = 20 (``bench/results/flight-stagger/``,
``flight-fade-swarmd-n20-r1.json``), the fading uav20 lost uav16 at 62.8 s while uav16 kept
uav20 (it heard uav20's frames, uav20 did not hear its own), and found it again only 32 s
later. uav16 answered uav20's first seek promptly (the rule for a frame that stops listing
us), that answer was lost, its retries ran out, and after that only its renewals could
reach uav20. The same shape on MemNet, virtual time: from ``T_CUT`` every frame *to* the
fader is lost (it hears nobody; everyone hears it), until ``T_BACK``. It loses all its peers,
they keep it, and once it hears again it must find every one within the rule's own bound:
its next seek (at most ``SEEK_MAX_S`` after the return), the answers of the peers whose
spacing allows one (within ``Debts.cue_delay``, at most W1 = N / 50 = 0.4 s), its pull-in
multicast, which now lists the peers it found (W1), and the others' answers to that (W1):
2.4 s. That
is harsher than the flight's fade (there the fader hears in every window; here it heard
nobody for 40 s, so every peer's spacing had grown to its cap), and the issue's 2 s target
is judged on the flight runs. Before the rule: 2.9-6.5 s. And a drone that stays deaf must
not cost its peers more than about one frame each per 8 s (answering every seek would be
about one per second each).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import pytest
from swarmd_lab.testing import (
    ScriptedSender,
    Swarm,
    auth_for,
    build_swarm,
    drain,
    engine_for,
    make_bundle,
    node_ipv4,
    peer_datagram,
    run_to,
)

from swarmd.auth.spdp import PLACEHOLDER
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.events import PeerDiscovered, PeerLost, PeerRestarted
from swarmd.discovery.seek import LOST_US_GAP_MAX_S, SEEK_MAX_S
from swarmd.rtps.ports import spdp_multicast_port
from swarmd.rtps.spdp import encode_spdp_dispose

N = 20
FADER = N - 1
T_FORMED = 60.0
T_CUT = 60.0
T_BACK = 100.0
W1 = N / 50  # the rejoin delay's window (Debts.rejoin_delay): 0.4 s at N = 20
BOUND_S = SEEK_MAX_S + 3 * W1  # module doc: 2.4 s


def _deaf_fader(seed: int, q: float, until: float) -> Swarm:
    swarm = build_swarm(N, seed=seed, q=q)
    swarm.run_until(T_FORMED)
    assert swarm.all_discovered(), "the swarm did not form before the cut"

    def loss(src: int, dst: int) -> float:
        return 1.0 if dst == FADER and T_CUT <= swarm.net.now < until else 0.0

    swarm.net.link_loss = loss
    return swarm


def _lost_by(swarm: Swarm, observer: int, peer: int) -> bool:
    return any(
        t >= T_CUT and isinstance(e, PeerLost) and swarm.index_of[e.name] == peer
        for t, e in swarm.events[observer]
    )


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("q", [0.05, 0.5])
def test_a_drone_that_could_not_hear_finds_every_peer_soon_after_hearing_again(
    seed: int, q: float
) -> None:
    swarm = _deaf_fader(seed, q, until=T_BACK)
    swarm.run_until(T_BACK + 30.0)
    lost = [j for j in range(N - 1) if _lost_by(swarm, FADER, j)]
    assert len(lost) == N - 1  # the shape holds: it lost them all ...
    assert not any(_lost_by(swarm, i, FADER) for i in range(N - 1))  # ... they kept it
    for j in lost:
        found = [
            t
            for t, e in swarm.events[FADER]
            if t >= T_BACK and isinstance(e, PeerDiscovered) and swarm.index_of[e.name] == j
        ]
        assert found, f"uav{j} never found again"
        assert found[0] - T_BACK <= BOUND_S, (j, found[0] - T_BACK)


@pytest.mark.parametrize("q", [0.05, 0.5])
def test_a_drone_that_stays_deaf_costs_each_peer_about_one_answer_per_8_s(q: float) -> None:
    swarm = _deaf_fader(1, q, until=float("inf"))
    swarm.run_until(120.0)  # its leases of every peer have ended: it seeks them all

    def replies() -> int:
        return sum(swarm.engines[i].counters()["tx_kind"]["reply"] for i in range(N - 1))

    before = replies()
    swarm.run_until(240.0)
    per_peer_per_s = (replies() - before) / (N - 1) / 120.0
    # about one answer per LOST_US_GAP_MAX_S, not one per seek (~1/s); a little slack for
    # the answers the ordinary rules still send
    assert per_peer_per_s <= 1.5 / LOST_US_GAP_MAX_S, per_peer_per_s


# --------------------------------------------------------------------------- the side table


def test_the_side_table_holds_only_the_peers_that_lost_us_and_forgets_them() -> None:
    """seek.SoughtBy: an entry per peer whose frames stopped listing us, removed when one
    lists us again, when its lease ends and when it leaves (a signed DATA(p[UD]))."""
    bundle = make_bundle(3)
    a1 = auth_for(bundle, 1)
    engine = engine_for(bundle, 0, auth=auth_for(bundle, 0))
    table = engine._receive.sought_by.entries  # noqa: SLF001 - the table under test
    addr = (node_ipv4(1), bundle.metatraffic_port(bundle.participants[1]))

    def frame(now: float, heard: tuple[int, ...], *, sn: int) -> None:
        engine.receive_datagram(
            peer_datagram(bundle, 1, heard=heard, sequence_number=sn, auth=a1), addr, now
        )

    frame(0.1, (0, 1), sn=1)
    assert table == {}  # it lists us: nothing kept
    frame(0.2, (1,), sn=2)
    assert list(table) == [1]  # it stopped listing us: it lost us
    frame(0.3, (0, 1), sn=3)
    assert table == {}  # it lists us again
    frame(0.4, (1,), sn=4)
    assert list(table) == [1]
    run_to(engine, 60.0)  # its lease ends (we hear nothing more from it)
    view = engine.peer("uav1")
    assert view is not None and not view.discovered
    assert table == {}
    frame(61.0, (0, 1), sn=5)
    frame(61.1, (1,), sn=6)
    assert list(table) == [1]
    template = encode_spdp_dispose(
        bundle.participants[1].guid_prefix,
        sequence_number=7,
        timestamp=None,
        authenticator=PLACEHOLDER,
    )
    engine.receive_datagram(a1.seal(template), addr, 61.2)  # it leaves
    assert any(isinstance(e, PeerLost) and e.reason == "disposed" for e in drain(engine))
    assert table == {}


# ------------------------------------------------------------------ the answer's holdoff


@pytest.mark.parametrize("seed", range(1, 11))
def test_the_answer_to_a_peer_that_lost_few_goes_within_their_share_of_the_budget(
    seed: int,
) -> None:
    """The residual of the fade at N = 20 (docs/discovery.md, "The residual"): a window of
    1 s, the cue most likely late in it, and an answer held back by the rejoin delay
    U(0, N / 50) = U(0, 0.4 s) can land after it closed. Only the peers the cue omits may
    answer it, so the holdoff is spread over them: U(0, 3 / 50 s) when it omits 3 (us and
    two others); before, up to 0.4 s (9 of these 10 seeds fail then)."""
    bundle = make_bundle(N)
    engine = engine_for(bundle, 0, seed=seed, q=0.5)
    addr = (node_ipv4(FADER), bundle.metatraffic_port(bundle.participants[FADER]))
    for i in range(1, N):  # every peer heard, each listing everyone
        frame = peer_datagram(bundle, i, heard=tuple(range(N)), sequence_number=1)
        source = (node_ipv4(i), bundle.metatraffic_port(bundle.participants[i]))
        engine.receive_datagram(frame, source, 1.0)
    run_to(engine, 5.0)  # we announced, listing them all: nothing owed
    assert engine.counters()["tx_kind"]["reply"] == 0
    cue_at = 5.5
    omits = (0, 1, 2)  # its frame omits us and two others
    heard = tuple(i for i in range(N) if i not in omits)
    cue = peer_datagram(bundle, FADER, heard=heard, sequence_number=2)
    engine.receive_datagram(cue, addr, cue_at)
    window = len(omits) / EngineConfig().announce_budget_fps  # 0.06 s
    sent = run_to(engine, cue_at + window)
    # the answer is a multicast since h-seek-answer (the drones that held their seek back
    # hear it too: tests/test_discovery_seek_answer.py); directed before
    group_port = spdp_multicast_port(bundle.domain_id)
    answers = [t for t, _, to in sent if to == addr or to[1] == group_port]
    assert answers, "no answer within 0.06 s of the cue"


# ------------------------------------------------------------------ a captured member's attack

ATTACK_N = 10
ATTACKER = ATTACK_N - 1  # uav9, captured: its genuine key, the attacker's firmware
HONEST = range(ATTACK_N - 1)
T_ATTACK = 60.0
ATTACK_FOR_S = 60.0  # the bounded virtual-time window
ATTACK_PERIOD_S = 0.05  # 20 frames a second, to every honest peer
REACK_GAP_S = EngineConfig().retransmit_min_gap_s  # 0.5 s: the bound the docs claim, ~2/s
HONEST_FADER = ATTACK_N - 2  # deaf during the attack: its service must not suffer
ATTACK_CUT, ATTACK_BACK = 70.0, 100.0
ATTACK_W1 = ATTACK_N / 50  # the rejoin delay's window at N = 10
Digest = Callable[[int], tuple[int, ...]]  # the heard digest it sends to a victim


class _CapturedMember(ScriptedSender):
    """uav9 after capture, on the net in its own place: every ``ATTACK_PERIOD_S`` a DATA(p)
    sealed with its real key (a new life: boot epoch 2) whose heard digest is the next of
    ``digests`` (per victim), multicast or directed to each honest peer; it answers
    nothing. Sending stops at ``T_ATTACK + ATTACK_FOR_S`` (bounded in count and time)."""

    def __init__(
        self,
        swarm: Swarm,
        digests: list[Digest],
        *,
        directed: bool,
        now: float,
    ) -> None:
        super().__init__(now)
        self._swarm = swarm
        self._digests = digests
        self._directed = directed
        self._auth = auth_for(swarm.bundle, ATTACKER, epoch=2, now=now)
        self._sn = 10_000  # above its former life's: only the epoch says "restarted"
        self.sent = 0

    def _frame(self, victim: int | None, heard: tuple[int, ...]) -> bytes:
        bundle = self._swarm.bundle
        destination = None if victim is None else bundle.participants[victim].guid_prefix
        return peer_datagram(
            bundle,
            ATTACKER,
            heard=heard,
            sequence_number=self._sn,
            destination=destination,
            auth=self._auth,
        )

    def handle_timer(self, now: float) -> None:
        while self._next is not None and self._next <= now:
            digest = self._digests[self.sent % len(self._digests)]
            self._sn += 1
            engines = self._swarm.engines
            if self._directed:
                for v in HONEST:
                    target = (node_ipv4(v), engines[v].metatraffic_port)
                    self._out.append((self._frame(v, digest(v)), target))
            else:
                self._out.append((self._frame(None, digest(0)), engines[0].spdp_multicast))
            self.sent += 1
            self._next += ATTACK_PERIOD_S
            if self._next > T_ATTACK + ATTACK_FOR_S:
                self._next = None


def _all_honest(victim: int) -> tuple[int, ...]:
    return tuple(HONEST)


def _nobody(victim: int) -> tuple[int, ...]:
    return ()


def _all_but(victim: int) -> tuple[int, ...]:
    return tuple(i for i in HONEST if i != victim)


def _itself(victim: int) -> tuple[int, ...]:
    return (ATTACKER,)


# the digest patterns, frame after frame: lists us / stops; never lists us but its hear
# count grows every other frame; lists us, stops, grows
ATTACKS: dict[str, tuple[list[Digest], bool]] = {
    "toggle": ([_all_honest, _nobody], False),
    "grow-directed": ([_nobody, _all_but], True),
    "list-stop-grow": ([_all_honest, _nobody, _itself], False),
}


@pytest.mark.parametrize("attack", sorted(ATTACKS))
def test_a_captured_member_toggling_its_digest_draws_at_most_one_answer_per_reack_gap(
    attack: str,
) -> None:
    digests, directed = ATTACKS[attack]
    swarm = build_swarm(ATTACK_N, seed=5, q=0.5, authenticated=True)
    swarm.run_until(T_ATTACK)
    assert swarm.all_discovered(), "the swarm did not form before the attack"
    attacker = _CapturedMember(swarm, digests, directed=directed, now=T_ATTACK)
    swarm.net.replace(ATTACKER, attacker)
    # meanwhile an honest drone goes deaf and comes back (the lost_us rule's own case)
    swarm.net.link_loss = lambda src, dst: (
        1.0 if dst == HONEST_FADER and ATTACK_CUT <= swarm.net.now < ATTACK_BACK else 0.0
    )
    start = len(swarm.net.transmissions)
    swarm.run_until(T_ATTACK + ATTACK_FOR_S)
    assert attacker.sent >= ATTACK_FOR_S / ATTACK_PERIOD_S  # the attack ran, ...
    for i in HONEST:  # ... and every honest peer took its frames as uav9's (a real key)
        assert [e.epoch for _, e in swarm.events[i] if isinstance(e, PeerRestarted)] == [2]
        view = swarm.engines[i].peer("uav9")
        assert view is not None and view.discovered
    answers = Counter(
        t.node
        for t in swarm.net.transmissions[start:]
        if not t.multicast and t.target[0] == node_ipv4(ATTACKER)
    )
    bound = ATTACK_FOR_S / REACK_GAP_S + 1  # one per re-ack gap: ~2/s per peer
    assert max(answers.values()) <= bound, answers
    # the lost_us answer is a multicast since h-seek-answer (pullin.PullIn.answer_seek): each
    # honest peer's multicasts, answers, seeks and renewals together, stay within the same
    # bound (its 20 frames a second cannot make a peer multicast faster than the gap allows)
    multicasts = Counter(
        t.node for t in swarm.net.transmissions[start:] if t.multicast and t.node in HONEST
    )
    assert max(multicasts.values()) <= bound, multicasts
    # the others' service: no honest pair lost but the deaf drone's, and the deaf drone
    # found every honest peer again within the rule's bound after it heard again
    for i in HONEST:
        lost = {swarm.index_of[e.name] for t, e in swarm.events[i] if isinstance(e, PeerLost)}
        assert lost <= ({HONEST_FADER} if i != HONEST_FADER else set(range(ATTACK_N))), (i, lost)
    found = {
        swarm.index_of[e.name]: t - ATTACK_BACK
        for t, e in reversed(swarm.events[HONEST_FADER])
        if t >= ATTACK_BACK and isinstance(e, PeerDiscovered)
    }
    assert set(found) >= set(HONEST) - {HONEST_FADER}, found
    assert max(found[j] for j in HONEST if j != HONEST_FADER) <= SEEK_MAX_S + 3 * ATTACK_W1
