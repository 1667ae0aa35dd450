"""Seeking lost peers: a short jittered multicast while bundle peers are lost (issue 20).

Why (docs/discovery.md, "Seeking lost peers"): after a split or a fly-out, the link comes
back with nothing on the air. Re-discovery then waits for whichever multicast comes next:
a vouched member does not renew at all, the others renew every 3.4-10 s (their Q-stretched
period), and the rejoin pull-in (``pullin.PullIn.rejoined``) only helps once one frame
has crossed. On the emulated channel that first frame crossed 2.1-6.1 s after the return
(``bench/results/flight-rejoin/``).

What: while a node has bundle peers it lost to a lease's end (adaptive mode, ANNOUNCE or
STEADY), it keeps a multicast DATA(p) going every U(``SEEK_MIN_S``, ``SEEK_MAX_S``): the
*seek* (tx kind ``seek``). Its heard digest omits the lost peers (they are unmarked when
lost), so a lost peer that hears it finds itself unlisted, re-discovers us and answers
within the rejoin delay (DDSI-RTPS 8.5.3 SPDP; the digest). A returning link therefore
carries a frame from each side within ``SEEK_MAX_S``, and the answers follow within the
rejoin delay (U(0, N / 50 fps): 0.2 s at N = 10, 0.4 s at N = 20).

Suppression (SSDP's and mDNS's duplicate-answer suppression, RFC 6762 section 7.4): a
multicast DATA(p) heard from a peer we currently have, whose heard digest omits every peer
we seek, seeks them as well as ours would: our own seek goes back one period from it. Any
multicast of our own counts as a seek too (it omits the lost peers). So a half of a split,
all seeking the same other half, puts about one seek per period on the air, not one per
drone.

A put-off bound while the loss is fresh: the frame we heard reaches the peers we seek only
if they are in its sender's range, and at the edge of a swarm strung out over more than
one radio range they may be in ours and not in its (docs/discovery.md, "A seek put off by a
frame that cannot reach"). So while a loss is fresh (a sought peer last heard, or a lost
peer heard again, within ``SEEK_PUT_OFF_FOR_S``), the suppression puts our seek off no
further than ``SEEK_PUT_OFF_MAX_S`` from our own last multicast: every drone seeks itself at
least that often, and the edge drone's seek reaches across. Past that window the outage is
a long one (a drone gone for good, a dead commander) and the suppression is whole again: one
seek per period per neighbourhood, as before, for the rest of ``SEEK_FOR_S``. The bound is
kept by a drone that heard few seekers lately (at most ``SEEK_PUT_OFF_SEEKERS_MAX`` within
``SEEK_SEEKERS_WINDOW_S``), and in a denser neighbourhood by the first
``SEEK_PUT_OFF_RANK_MAX`` of the seekers per sought peer, ranked by a keyed hash of the two
GUIDs: about that many per peer lost, whatever N, so a drone gone for good costs a few
bounded seekers, not N / 2.4 seeks a second, while a side that lost a whole other side (where
an edge drone may be the only one in reach) keeps most of its drones bounded
(docs/discovery.md, "The put-off bound at scale").

Bound: a peer not heard for ``SEEK_FOR_S`` is no longer sought (a drone really gone must not
cost the channel forever); the renewals, which still omit it, remain. Paper mode never
seeks: the paper's schedule is kept.

The answering half (``SoughtBy``; docs/discovery.md, "A peer that lost us while we kept
it"): a peer whose frames listed us and then stopped has lost us, and each of its frames that
still omits us seeks us. If we kept it (we hear it; it does not hear us: a drone at the edge
of range), the receive path answers such a frame promptly, spaced by ``SoughtBy``. Its state
lives here, in a table of the few peers that currently lost us, not on every ``Peer`` (four
fields there cost ~32 MB across the simulator's 1000 x 999 peers, for a rule that fires at
the edge of range only).

Pure and keyed by ``now`` (style rule 6): these classes decide when; the engine sends.
"""

from __future__ import annotations

import hashlib
import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.timers import Backoff

# The seek period U(SEEK_MIN_S, SEEK_MAX_S). The target is re-discovery within 2 s of the
# link's return (issue 20). The first frame across comes within SEEK_MAX_S; the side that
# hears it answers within the rejoin delay W1, and the seeker's side, now hearing those
# answers (which omit it), pulls its own in within W1 too: 1.2 + 2 x 0.4 = 2.0 s at N = 20,
# 1.6 s at N = 10. The jitter (+-20 %) keeps a half's seekers from firing together, so the
# one that fires first suppresses the others. At about one seek per second per side, a
# split costs ~2 frames/s on top of the renewals (N = 10 renews ~1-3 frames/s).
SEEK_MIN_S: Final = 0.8
SEEK_MAX_S: Final = 1.2
# How long a lost peer is sought, from when it was last heard: 10 minutes covers a split,
# a fly-out, a commander blackout and a drone behind a building many times over (the
# flights' outages last 30-60 s), and bounds what a drone really gone costs: ~600 seeks per
# neighbourhood (one seeker per side after suppression, each drone at least every
# SEEK_PUT_OFF_MAX_S in the first minute), then the renewals alone.
SEEK_FOR_S: Final = 600.0
# How far the suppression may put our seek off, from our own last multicast, while a loss is
# fresh: two periods. Without it each of a side's k seekers fires in about one period of
# k + 1, and an edge pair back in range waited 2.2-6.1 s (k = 5,
# tests/test_discovery_seek_reach.py on the engine before).
SEEK_PUT_OFF_MAX_S: Final = 2 * SEEK_MAX_S
# How long a loss is fresh, from when the sought peer was last heard (or a lost peer was heard
# again: a returning link brings the others back within seconds): the flights' outages last
# 30-60 s. What it costs: each drone that lost a peer seeks at least every
# SEEK_PUT_OFF_MAX_S for the rest of this window (the lease took the first ~20 s of it), then
# the neighbourhood's one seek per period; a drone gone for good costs its 9 peers at N = 10
# 613 seeks over SEEK_FOR_S, 1.16 x the 528 of unbounded suppression (seed 1,
# ``python -m bench.seek_cost``; docs/discovery.md).
SEEK_PUT_OFF_FOR_S: Final = 60.0
# Which drones keep the put-off bound: those that heard at most SEEK_PUT_OFF_SEEKERS_MAX other
# seekers of the peers they seek within SEEK_SEEKERS_WINDOW_S (a seeker: a bundle peer whose
# multicast put our seek off). With the bound on everywhere the fresh window cost ~N / 2.4
# seeks a second (a drone gone for good, seed 1: 543 seeks at N = 20 against 279 without the
# bound, 797 against 66 at N = 50; ``python -m bench.seek_cost``): every drone of a dense
# neighbourhood sought at least every 2.4 s although each reaches what the others reach. The
# bound is for the edge of a swarm strung out over more than one radio range, where a drone
# hears only the few of its side near it. 8: the bound's worst cost is then a neighbourhood of
# 10 (1.16x at N = 10, 1.19x at N = 9, what session 9 accepted), and a strung-out side of up
# to 9 drones keeps it (tests/test_discovery_seek_reach.py). A denser side: the rank below.
SEEK_PUT_OFF_SEEKERS_MAX: Final = 8
# How far back a seeker counts: every seeker of a dense neighbourhood sends a multicast within
# it (a seek put off by at most SEEK_PUT_OFF_MAX_S while the bound holds, or its renewal), so
# the count does not fall below the neighbourhood's size between its frames.
SEEK_SEEKERS_WINDOW_S: Final = 10.0
# Which drones of a denser neighbourhood keep the bound all the same: those ranked among the
# first SEEK_PUT_OFF_RANK_MAX for one of the peers they seek, ranking themselves and the
# seekers heard within SEEK_SEEKERS_WINDOW_S by a keyed hash of (participant, sought peer)
# (``_pair_rank``). Every drone of a side hears about the same seekers, so about this many
# keep the bound per sought peer, whatever the side's size, and a different few for each
# peer: a side that lost a whole other side (a split, a strung-out swarm cut in two) has
# each of its drones ranked first for one of them with a good chance, the edge drone
# included; a drone gone for good draws this many bounded seekers, not N. No draw from the
# engine's RNG: the simulator's seeded runs cannot move. 3: sides of 10-12 find their edge
# pair within 2 s (tests/test_discovery_seek_reach.py, ``python -m bench.seek_sides``);
# the cost at N = 20 and 50 in docs/discovery.md, "The put-off bound at scale".
SEEK_PUT_OFF_RANK_MAX: Final = 3
# The peers sought at once are the bundle's: bounded by N (no peer can grow the table).

# The lost_us rule's spacing: after our k-th prompt answer to a peer that lost us, the next
# waits LOST_US_GAP_S x 2^(k-1), at most LOST_US_GAP_MAX_S (1, 2, 4, 8, 8 ... s); the first
# waits only the re-ack gap since our last prompt answer to it (retransmit_min_gap_s,
# 0.5 s). No jitter: the cue is the peer's own frame. A drone that hears nobody (a deaf
# receiver) thus costs each peer one answer per 8 s, not one per seek (~1 s).
LOST_US_GAP_S: Final = 1.0
LOST_US_GAP_MAX_S: Final = 8.0
_LOST_US_SPACING: Final = Backoff(LOST_US_GAP_S, LOST_US_GAP_MAX_S, jitter=0.0)

_LOST: Final = PeerState.LOST


class Seek:
    """The peers we seek (lost to a lease's end, last heard within ``SEEK_FOR_S``) and the
    next seek's deadline."""

    __slots__ = (
        "_mine",
        "_peer_at",
        "_rng",
        "due",
        "enabled",
        "fresh_at",
        "seekers",
        "sent_at",
        "sought",
    )

    def __init__(
        self,
        *,
        enabled: bool,
        rng: random.Random,
        peer_at: Sequence[Peer | None],
        my_guid_prefix: bytes,
    ) -> None:
        self.enabled = enabled  # adaptive mode: paper mode keeps the paper's schedule
        self._rng = rng
        # the engine's peers by bundle index (None: us, or an index the bundle skips) and our
        # GUID prefix: the rank's hash inputs, fixed by the signed bundle (no peer chooses
        # its rank)
        self._peer_at = peer_at
        self._mine = my_guid_prefix
        self.sought: dict[int, Peer] = {}  # by bundle index; a peer found again is dropped lazily
        self.due: float | None = None  # the next seek, None while nobody is sought
        self.sent_at = -math.inf  # our last multicast (which sought every lost peer)
        # the freshest loss: a sought peer's last hearing, or a lost peer heard again
        self.fresh_at = -math.inf
        # the peers whose multicast put our seek off while the loss was fresh: bundle index ->
        # the latest such frame, oldest first (re-inserted on each). Only an authenticated
        # bundle peer's frame reaches ``heard`` (receive.py), each under its own index: at
        # most the peer table's N - 1 rows, the bundle's cap; a forger or a stranger adds none
        self.seekers: dict[int, float] = {}

    def _period(self) -> float:
        return self._rng.uniform(SEEK_MIN_S, SEEK_MAX_S)

    def start(self, lost: list[Peer], now: float) -> None:
        """``lost`` just ended their leases (the engine is announcing or steady): seek them.
        The first seek comes one period on (the lease's end pulled a multicast in already,
        ``pullin.PullIn.lease_ended``)."""
        if not self.enabled or not lost:
            return
        for peer in lost:
            self.sought[peer.index] = peer
            if peer.last_heard is not None and peer.last_heard > self.fresh_at:
                self.fresh_at = peer.last_heard
        if self.due is None:
            self.due = now + self._period()

    def _prune(self, now: float) -> None:
        """Drop the peers found again (no longer LOST) and those sought long enough."""
        stale = [
            i
            for i, p in self.sought.items()
            if p.state is not _LOST or p.last_heard is None or now - p.last_heard >= SEEK_FOR_S
        ]
        for i in stale:
            del self.sought[i]
        if not self.sought:
            self.due = None
            self.seekers.clear()

    def fire(self, now: float) -> bool:
        """The seek's deadline came: True if a seek is to be sent now (someone is still
        sought); the next one is then set by ``sent``."""
        self._prune(now)
        return self.due is not None

    def sent(self, now: float) -> None:
        """We multicast a DATA(p) (a seek, a renewal, an announcement): it omits every lost
        peer, so it was a seek; the next one waits a period."""
        self.sent_at = now
        if self.due is not None:
            self.due = now + self._period()

    def returned(self, now: float) -> None:
        """A peer we had lost was heard again: the link is coming back, so the others still
        sought may be back within seconds, at the edge of range: the loss is fresh again."""
        self.fresh_at = now

    def heard(self, heard: bytes | None, now: float, seeker: int) -> None:
        """Bundle peer ``seeker`` (index), which we have, multicast a DATA(p) with heard digest
        ``heard``: if it omits every peer we seek, it sought them for us (suppression): ours
        waits a period from now; but while the loss is fresh, and we heard at most
        ``SEEK_PUT_OFF_SEEKERS_MAX`` such seekers lately, no later than
        ``SEEK_PUT_OFF_MAX_S`` after our own last multicast (that frame may not reach the
        peers we seek: we may be nearer them than the peer we heard)."""
        if self.due is None:
            return
        if heard is not None:
            for index in self.sought:
                octet = index >> 3
                if octet < len(heard) and heard[octet] >> (index & 7) & 1:
                    return  # it hears one we seek: its frame does not seek that one
        put_off = now + self._period()
        if now - self.fresh_at < SEEK_PUT_OFF_FOR_S:
            seekers = self.seekers
            seekers.pop(seeker, None)
            seekers[seeker] = now  # the newest last
            bound = self.sent_at + SEEK_PUT_OFF_MAX_S
            if bound < put_off and (self._few_seekers(now) or self._ranked_first(now)):
                put_off = bound
        self.due = max(self.due, put_off)

    def _few_seekers(self, now: float) -> bool:
        """Whether at most ``SEEK_PUT_OFF_SEEKERS_MAX`` seekers put our seek off within
        ``SEEK_SEEKERS_WINDOW_S``: newest first, so it reads at most that many + 1 rows."""
        count = 0
        for at in reversed(self.seekers.values()):
            if now - at >= SEEK_SEEKERS_WINDOW_S:
                return True  # the rest are older still
            count += 1
            if count > SEEK_PUT_OFF_SEEKERS_MAX:
                return False
        return True

    def _ranked_first(self, now: float) -> bool:
        """Whether, for one of the peers we seek, fewer than ``SEEK_PUT_OFF_RANK_MAX`` of the
        seekers heard within ``SEEK_SEEKERS_WINDOW_S`` rank before us (``_pair_rank``). Reads
        the seekers (at most N - 1, the bundle's cap) once per sought peer, stopping at the
        rank's cap."""
        seekers: list[bytes] = []
        peer_at = self._peer_at
        for index, at in reversed(self.seekers.items()):
            if now - at >= SEEK_SEEKERS_WINDOW_S:
                break  # the rest are older still
            seeker = peer_at[index]
            if seeker is not None:
                seekers.append(seeker.participant.guid_prefix.value)
        for peer in self.sought.values():
            if peer.state is not _LOST:
                continue  # found again, dropped at the next prune
            key = peer.participant.guid_prefix.value
            ours = _pair_rank(self._mine, key)
            before = 0  # the seekers ranked before us, counted up to the cap
            for prefix in seekers:
                if before >= SEEK_PUT_OFF_RANK_MAX:
                    break
                if _pair_rank(prefix, key) < ours:
                    before += 1
            if before < SEEK_PUT_OFF_RANK_MAX:
                return True
        return False


def _pair_rank(participant: bytes, sought: bytes) -> int:
    """A participant's place among the seekers of peer ``sought``: BLAKE2b keyed by the sought
    peer's GUID prefix over the participant's (RFC 7693; deterministic across drones and
    runs, unlike Python's ``hash``). Every drone computes the same order from the bundle, a
    different one for each sought peer."""
    return int.from_bytes(hashlib.blake2b(participant, key=sought, digest_size=8).digest())


@dataclass(slots=True)
class _Seeker:
    """A peer that lost us: our prompt answers to it since, the last one's time, and how
    many peers its latest frame lists."""

    answers: int = 0
    answered_at: float | None = None
    hears: int = 0


class SoughtBy:
    """The peers that lost us while we kept them (their frames listed us, then stopped) and
    the spacing of our prompt answers to them (the receive path's lost_us rule).

    An entry is made when a peer's frame stops listing us (``lost_us``) and removed when
    one lists us again, or when we lose the peer (its lease ended, or it left: ``forget``).
    The table is keyed by bundle index and only an authenticated bundle peer's frame makes
    an entry, its own: it holds at most the peer table's N - 1 rows, the bundle's cap (no
    peer can add more than one, a stranger none)."""

    __slots__ = ("_swarm_size", "entries")

    def __init__(self, swarm_size: int) -> None:
        self._swarm_size = swarm_size  # N, the bundle's participants
        self.entries: dict[int, _Seeker] = {}  # by bundle index; empty on the usual path

    def lost_us(self, index: int) -> None:
        """Peer ``index``'s frame stopped listing us: its spacing starts fresh."""
        self.entries[index] = _Seeker()

    def forget(self, index: int) -> None:
        """It lists us again, or we lost it: the rule no longer applies."""
        self.entries.pop(index, None)

    def heard(self, index: int, heard: bytes) -> None:
        """A frame of peer ``index`` with heard digest ``heard``. If it lost us and hears
        more peers than in its last frame, its receiver works again (a drone back in range
        finds the others first), so our next answer may cross: the spacing starts over."""
        entry = self.entries.get(index)
        if entry is None:
            return
        hears = int.from_bytes(heard).bit_count()
        if hears > entry.hears:
            entry.answers, entry.answered_at = 0, None
        entry.hears = hears

    def may_answer(self, index: int, now: float) -> bool:
        """Whether peer ``index`` lost us and its spacing allows a prompt answer at ``now``."""
        entry = self.entries.get(index)
        if entry is None:
            return False
        at = entry.answered_at
        return at is None or now - at >= _LOST_US_SPACING.plain_s(entry.answers)

    def omitted(self, index: int) -> int:
        """How many bundle peers the latest frame of peer ``index`` omits (at least 1: us):
        the peers that may answer that same frame (those it lists owe it nothing)."""
        entry = self.entries.get(index)
        hears = 0 if entry is None else entry.hears
        return max(1, self._swarm_size - 1 - hears)

    def answered(self, index: int, now: float) -> None:
        """We answered peer ``index`` promptly at ``now`` (after ``may_answer``)."""
        entry = self.entries[index]
        entry.answers += 1
        entry.answered_at = now
