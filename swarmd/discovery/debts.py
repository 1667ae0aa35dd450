"""Debts and retries: which peers are owed a frame, when, and how often we try.

A frame is owed to a discovered peer while it does not list us or we have not listed it to
it since we (re)discovered it (``Peer.lists_me``, ``Peer.told``), and to an undiscovered one
while the announcement campaign lasts (ANNOUNCE, STEADY). Each owed peer's
``RetrySchedule`` is armed at its next deadline: first after a reply holdoff (paper mode:
U(0, 0.1 s), the paper's immediate directed reply; adaptive: U(W, 2W), so a passive node's
own announcement, which lists the peer, replaces the reply), then with exponential backoff,
at most ``max_attempts`` times. Armed retries sit in a lazy min-heap (an entry carries its
schedule, which tells whether it is still live), so ``get_timer()`` stays O(1) amortised.

The engine pays the debts that fall due (``DiscoveryEngine._flush``: one multicast, or
directed frames) and tells this class which peers a frame covered (``covered``,
``covered_all``). The phase enters as two flags the engine sets on every transition.
"""

from __future__ import annotations

import heapq
import math
import random
from typing import Final

from swarmd.discovery.awareness import passive_window_s
from swarmd.discovery.config import EngineConfig, Timing
from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.renewals import Renewals
from swarmd.discovery.timers import Backoff, RetrySchedule

_UNDISCOVERED: Final = PeerState.UNDISCOVERED
_DISCOVERED: Final = PeerState.DISCOVERED


class Debts:
    """The armed retries, their heap, the reply holdoff and the retry backoff."""

    __slots__ = (
        "_backoff_now",
        "_config",
        "_peer_at",
        "_peers",
        "_pushed",
        "_rejoin_spread_s",
        "_renewals",
        "_rng",
        "_spread_at",
        "_swarm_size",
        "_timing",
        "announcing",
        "armed",
        "found_again",
        "late_copies",
        "late_due",
        "retries",
        "silent",
    )

    def __init__(
        self,
        peers: dict[int, Peer],
        peer_at: list[Peer | None],
        renewals: Renewals,
        *,
        config: EngineConfig,
        timing: Timing,
        rng: random.Random,
        swarm_size: int,
    ) -> None:
        self._peers = peers  # the engine's table, by bundle index
        self._peer_at = peer_at  # the same by list position (None: us, or a skipped index)
        self._renewals = renewals  # its Q sets adaptive mode's holdoff
        self._config = config
        self._timing = timing
        self._rng = rng
        self._swarm_size = swarm_size
        # the phase, as the debts see it (set by DiscoveryEngine._transition): undiscovered
        # peers are owed frames only while announcing; nothing is retried while silent
        self.announcing = False  # ANNOUNCE or STEADY
        self.silent = True  # BOOT or PASSIVE
        # peers whose RetrySchedule is armed, and a lazy min-heap of (deadline, index,
        # tie-break, the peer's schedule): the schedule itself tells whether an entry is
        # live, without a lookup in the peer table (the counter keeps heapq from comparing
        # schedules when a retry is re-armed at the same instant)
        self.armed: set[int] = set()
        # peers found again whose answer is our next pulled-in multicast (or went in one:
        # covered_all; and a peer that lost us, answered by multicast: receive.py): each may
        # also get a directed copy a re-ack gap later (defer_found_again). Bundle indices: at
        # most the bundle's peers
        self.found_again: set[int] = set()
        # those copies' deadlines, by bundle index (at most the bundle's peers), and the
        # earliest of them, read by the engine's get_timer() (None: none owed)
        self.late_copies: dict[int, float] = {}
        self.late_due: float | None = None
        self.retries: list[tuple[float, int, int, RetrySchedule]] = []
        self._pushed = 0
        self._spread_at = (math.nan, 0.0)  # (Q, spread_s() at that Q)
        # adaptive mode's W at Q = 1: N frames at the full announce budget (rejoin_delay)
        self._rejoin_spread_s = passive_window_s(
            "adaptive",
            1.0,
            swarm_size=swarm_size,
            t_min_s=timing.t_min_s,
            t_max_s=timing.t_max_s,
            announce_budget_fps=config.announce_budget_fps,
            q_floor=config.q_floor,
        )
        self._backoff_now = Backoff(math.nan, math.nan)

    def owes(self, peer: Peer) -> bool:
        """Whether a frame is owed to ``peer`` (see the module docstring)."""
        state = peer.state  # asked after every datagram while announcing: no property calls
        if state is _DISCOVERED:
            return not peer.told or not peer.lists_me
        return state is _UNDISCOVERED and self.announcing

    def pending_count(self) -> int:
        """Peers with an armed retry whose debt still stands (stale ones are disarmed)."""
        for index in [i for i in self.armed if not self.owes(self._peers[i])]:
            self.disarm(self._peers[index])
        return len(self.armed)

    def any_pending(self) -> bool:
        """Whether any armed debt still stands (stale ones seen on the way are disarmed)."""
        # runs after every datagram while announcing: stop at the first debt that stands
        # (no copy of the armed set), then disarm the stale ones seen before it
        stale: list[Peer] = []
        found = False
        peers = self._peer_at  # a list: one cache line per lookup, not a dict probe
        announcing = self.announcing
        for index in self.armed:
            peer = peers[index]
            assert peer is not None  # noqa: S101 - only peers are armed
            state = peer.state  # owes(peer), inline
            if state is _DISCOVERED:
                if not peer.told or not peer.lists_me:
                    found = True
                    break
            elif state is _UNDISCOVERED and announcing:
                found = True
                break
            stale.append(peer)
        for peer in stale:
            self.disarm(peer)
        return found

    def arm(self, peer: Peer, at: float) -> None:
        """Owe ``peer`` a frame at ``at`` (the earlier deadline wins; none once exhausted)."""
        retry = peer.retry
        due = retry.due  # retry.arm(at), inline: ~3M arms per 1000-drone run
        if retry.attempts < retry.max_attempts and (due is None or at < due):
            retry.due = at
            self.armed.add(peer.index)
            self._pushed += 1
            heapq.heappush(self.retries, (at, peer.index, self._pushed, retry))

    def disarm(self, peer: Peer) -> None:
        """The debt is paid or void: forget the deadline and the attempts."""
        peer.retry.reset()
        self.armed.discard(peer.index)

    def next_retry(self) -> float | None:
        """The earliest armed retry; entries of disarmed or re-armed retries are dropped."""
        heap = self.retries
        while heap:
            at, _, _, retry = heap[0]
            if retry.due == at:
                return at
            heapq.heappop(heap)
        return None

    def due(self, now: float) -> list[Peer]:
        """The owed peers whose retry is due at ``now``, in bundle order; armed peers owed
        nothing any more are disarmed on the way."""
        due: list[Peer] = []
        for index in sorted(self.armed):
            p = self._peers[index]
            deadline = p.retry.deadline()
            if deadline is None or deadline > now:
                continue
            if self.owes(p):
                due.append(p)
            else:
                self.disarm(p)
        return due

    def covered_all(self, now: float) -> None:
        """We just multicast a frame listing everyone we hear: ``covered`` for every peer,
        inline (O(N) per multicast, ~1.5M peers covered in a 1000-drone run; the phase and
        the backoff are the same for all of them)."""
        announcing = self.announcing
        silent = self.silent
        backoff: Backoff | None = None
        armed = self.armed
        for p in self._peers.values():
            state = p.state
            if state is _DISCOVERED:
                p.told, p.told_at = True, now
            retry = p.retry
            if retry.due is None:
                continue  # not in a retry cycle (settled, or given up): nothing to count
            retry.sent()
            armed.discard(p.index)
            # owes(p); a discovered peer was told just now
            if not (
                not p.lists_me if state is _DISCOVERED else state is _UNDISCOVERED and announcing
            ):
                self.disarm(p)
            elif silent:
                pass  # the paper: one directed reply per frame heard (see covered)
            else:
                if state is _DISCOVERED and retry.attempts == 1 and p.times_discovered > 1:
                    # our first answer to a peer found again went out in this multicast,
                    # not directed: the peer found last (no multicast was pulled in for
                    # it, receive.py) was owed a directed answer, and a multicast that
                    # covers it first is sent once, unacknowledged, and at the edge of
                    # range lost. It gets the directed copy a re-ack gap on if still
                    # unlisted, as the peers the multicast was pulled in for do
                    # (docs/benchmarks.md, "Where it stands (session 13)": the split at
                    # N = 20, 2.12 s)
                    self.found_again.add(p.index)
                if not retry.exhausted:
                    if backoff is None:
                        backoff = self.backoff()
                    self.arm(p, now + backoff.delay_s(retry.attempts, self._rng))

    def defer_found_again(self, now: float) -> None:
        """Our multicast just sent answers the peers found again since the last one: each
        that has not listed us a re-ack gap (``retransmit_min_gap_s``, the peer's
        ``Peer.reack``) from now gets it directed then (``take_late_copies``), which the MAC
        acknowledges and retries (802.11 sends a group frame once, unacknowledged, and at
        the edge of range it was the one lost: docs/discovery.md, "A seek put off by a frame
        that cannot reach"). In the clean case the peer hears the multicast and lists us
        within its rejoin delay U(0, W1), W1 <= the gap: no copy. A peer already waiting
        keeps its earlier deadline."""
        if not self.found_again:
            return
        found, self.found_again = self.found_again, set()
        at = now + self._config.retransmit_min_gap_s
        late = self.late_copies
        for i in found:
            late.setdefault(i, at)
        self.late_due = min(late.values())

    def take_late_copies(self, now: float) -> list[Peer]:
        """The peers whose copy falls due at ``now`` and that still do not list us, in
        bundle order: each gets our DATA(p) directed. Each copy takes the peer's re-ack gap
        (``Peer.reack``), as every cue-driven directed frame does: a captured member that
        is lost and found again over and over (dispose, DATA(p)) draws at most one directed
        frame per gap from us."""
        late = self.late_copies
        due = sorted(i for i, at in late.items() if at <= now)
        for i in due:
            del late[i]
        self.late_due = min(late.values()) if late else None
        peers = self._peers
        out: list[Peer] = []
        for i in due:
            p = peers[i]
            if (
                p.state is _DISCOVERED
                and not p.lists_me
                and p.target() is not None
                and p.reack.permits(now)
            ):
                p.reack.mark(now)
                out.append(p)
        return out

    def forget_found_again(self, index: int) -> None:
        """The peer is lost again: no copy is owed to it."""
        self.found_again.discard(index)
        if self.late_copies.pop(index, None) is not None:
            late = self.late_copies
            self.late_due = min(late.values()) if late else None

    def covered(self, peer: Peer, now: float) -> None:
        """``peer`` was just sent a frame listing everyone we hear: count the attempt."""
        if peer.discovered:
            peer.told, peer.told_at = True, now
        if peer.retry.deadline() is None:
            return  # not in a retry cycle (settled, or given up): nothing to count
        peer.retry.sent()
        self.armed.discard(peer.index)
        if not self.owes(peer):
            self.disarm(peer)
        elif self.silent:
            pass  # the paper: one directed reply per frame heard; retries wait for ANNOUNCE
        elif not peer.retry.exhausted:
            self.arm(peer, now + self.backoff().delay_s(peer.retry.attempts, self._rng))

    def reply_delay(self) -> float:
        """The holdoff before a first answer (paper: U(0, reply_delay_max_s); adaptive:
        U(W, 2W))."""
        if self._config.mode == "paper":
            return self._rng.uniform(0.0, self._config.reply_delay_max_s)
        spread = self.spread_s()
        # rng.uniform(spread, 2 * spread) as random.py defines it, a + (b - a) * random():
        # the same draw without uniform's Python frame (~10^6 replies per 1000-drone run)
        high = 2.0 * spread
        return spread + (high - spread) * self._rng.random()

    def prompt_delay(self) -> float:
        """The holdoff before an answer wanted at once (a probe): U(0, reply_delay_max_s),
        the paper's immediate directed reply in either mode."""
        return self._rng.uniform(0.0, self._config.reply_delay_max_s)

    def rejoin_delay(self) -> float:
        """The holdoff before our first frame to a peer we had lost and hear again (or the
        multicast a rejoin pulls in, ``pullin.PullIn.rejoined``): U(0, W1), W1 adaptive
        mode's window at Q = 1 (N / announce budget: 0.2 s at N = 10, 0.4 s at N = 20).

        Not U(W, 2W) at our Q: Q is read from the peers we heard over the last seconds, so
        after an outage it still says "nobody" (a commander out of everyone's range reads
        Q = 0) while the frame just heard shows the link is back. At Q <= q_floor the
        holdoff was U(2, 4) s at N = 10 and U(4, 8) s at N = 20: the re-discoveries of
        4.6-4.8 s on the emulated channel (docs/benchmarks.md, "Flight"). W1 still spreads
        a whole swarm's rejoin frames at the announce budget (each drone pulls in at most
        one multicast per re-ack gap), so a heal stays within the budget the start-up keeps.
        Paper mode: its reply delay U(0, reply_delay_max_s), as before."""
        if self._config.mode == "paper":
            return self._rng.uniform(0.0, self._config.reply_delay_max_s)
        return self._rejoin_spread_s * self._rng.random()

    def cue_delay(self, answerers: int) -> float:
        """The holdoff before our answer to a peer that lost us while we kept it (the lost_us
        rule, receive.py): U(0, min(W1, answerers / budget)), ``answerers`` the peers its
        frame omits (``seek.SoughtBy.omitted``), the only ones that may answer that frame.

        Not the rejoin delay U(0, W1), W1 = N / budget (0.4 s at N = 20): a drone at the edge
        of range is in range 0.25-1.5 s at a time (issue 20's fade), and an answer held back
        up to 0.4 s after the frame that cued it can land after the window closed
        (docs/discovery.md, "A peer that lost us while we kept it"). The answers one frame
        can draw are still spread at the announce budget: a drone that lost 3 of 19 peers
        draws them within 0.06 s, one that lost the whole swarm within W1, as before.
        Paper mode: U(0, reply_delay_max_s), as ``rejoin_delay``."""
        if self._config.mode == "paper":
            return self._rng.uniform(0.0, self._config.reply_delay_max_s)
        spread = min(self._rejoin_spread_s, answerers / self._config.announce_budget_fps)
        return spread * self._rng.random()

    def spread_s(self) -> float:
        """Adaptive mode's W at the current Q: the time N frames take at the budget rate."""
        q, spread = self._spread_at
        if q != self._renewals.q:  # computed once per Q: every held-back reply and retry asks
            q = self._renewals.q
            spread = passive_window_s(
                "adaptive",
                q,
                swarm_size=self._swarm_size,
                t_min_s=self._timing.t_min_s,
                t_max_s=self._timing.t_max_s,
                announce_budget_fps=self._config.announce_budget_fps,
                q_floor=self._config.q_floor,
            )
            self._spread_at = (q, spread)
        return spread

    def answer_window(self) -> float:
        """The longest a peer holds back its answer to a frame of ours (its reply delay)."""
        if self._config.mode == "paper":
            return self._config.reply_delay_max_s
        return 2.0 * self.spread_s()

    def backoff(self) -> Backoff:
        """The retry backoff at the current Q (one object per Q)."""
        # a retry must wait out the peer's own reply holdoff, or it races the answer
        base = max(self._config.retry_base_s, self.answer_window())
        backoff = self._backoff_now
        if backoff.base_s != base:  # Q moved (adaptive holdoff)
            backoff = self._backoff_now = Backoff(base, max(self._config.retry_max_s, base))
        return backoff
