"""The sans-IO discovery engine: network-aware SPDP with preloaded endpoints.

Theory of operation
===================

Every drone runs one ``DiscoveryEngine``. The signed bundle lists all N participants and
all their endpoints, so discovery reduces to one question per pair: "have we heard each
other?". SPDP ``DATA(p)`` answers it; SEDP is never sent (paper section 4.2): a peer's
endpoints are matched from the bundle (``Bundle.matches``) the moment it is heard.

Each DATA(p) we send carries, in swarmd's vendor PIDs, the bundle digest (peers flashed
with another bundle are foreign) and the *heard digest*: a bitmap over bundle indices of
the participants we currently hear. From a peer's latest DATA(p) we know whether it lists
us (``Peer.lists_me``); from our own sends whether we have listed it to it (``Peer.told``).
A frame is owed to a discovered peer while either is false, and to an undiscovered one
while the announcement campaign lasts. The engine's whole job is to pay those debts with
as few frames as possible:

* owed replies wait a short holdoff (paper mode: U(0, 0.1 s), the paper's immediate
  directed reply; adaptive: U(W, 2W), so a passive node's own announcement, which lists
  the peer, replaces the reply, and acks to several late announcers collapse into one);
* owing frames to ``multicast_threshold`` or more peers at once, one multicast replaces
  the directed frames (never in BOOT/PASSIVE: the passive phase never multicasts);
* while a debt persists it is retried with exponential backoff, at most ``max_attempts``;
* a peer that repeats a directed DATA(p) unchanged (same sequence number) has not seen us
  list it: that, and only that, makes us answer a peer that already lists us, so two
  engines never ping-pong.

With no loss, N engines send about 2N discovery frames in all: N announcements (each
listing the earlier ones) and about N acks (each listing the later ones). Lease renewals
(multicast, ``renewal_period_s``: denser when Q is low) then keep everyone alive. In
adaptive mode the swarm's renewals stay within ``renewal_budget_fps``: a swarm of several
hundred renews every N / budget seconds and advertises a lease of n(Q) such periods, so a
live peer is never lost for want of renewals (docs/discovery.md, "The renewal budget").

The receive path runs once per datagram per engine (in the simulator, ~3M times for 1000
drones), so it holds no O(N) work: decoding and what every receiver derives alike from a
datagram are memoised per payload (``_decode``), leases sit in an O(1)-per-renewal queue
(``timers.LeaseQueue``), retries in a lazy heap, and the heard digest is kept incrementally.

Phases (``phases.TRANSITIONS`` is the whole table)::

    BOOT ──link sample / boot timeout──▶ PASSIVE ──timer, debts──▶ ANNOUNCE ──settled──▶ STEADY
                                            └──────timer, nothing owed────────────────────▲
    any ──shutdown()──▶ STOPPED   (DATA(p[UD]) to the multicast group, and to each known peer
                                   while they are few: a bounded number of frames)

PASSIVE lasts T_passive ~ U(0, W) (paper eq. 3, ``awareness.passive_window_s``).

Driving sources (aioquic style): ``receive_datagram``, ``handle_timer``,
``update_link_quality``; plus the ``shutdown`` command. Outputs: ``datagrams_to_send``,
``get_timer`` (one earliest absolute deadline), ``next_event``. Time is the ``now``
argument (seconds, the driver's monotonic clock); randomness the injected ``rng``.

Invariant: ``receive_datagram`` never raises for any input; malformed input becomes a
``PacketDropped`` event and a counter. Any other exception escaping it is a bug.
"""

from __future__ import annotations

import heapq
import math
import random
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Final

from swarmd.auth.budget import TokenBucket
from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import PLACEHOLDER, Refusal, SpdpAuth
from swarmd.bundle.model import Bundle, Participant, Role
from swarmd.discovery.awareness import (
    advertised_lease_s,
    draw_passive_timer_s,
    normalise_q,
    passive_window_s,
    renewal_period_s,
    vouch_period_s,
    vouched_lease_s,
)
from swarmd.discovery.config import EngineConfig, resolve_timing
from swarmd.discovery.digest import HeardBitmap
from swarmd.discovery.events import (
    DropReason,
    Event,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLocatorsChanged,
    PeerLost,
    PeerRestarted,
    PhaseChanged,
)
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.peers import (
    MAX_FOREIGN,
    MAX_PEER_LEASE_S,
    ForeignTable,
    Peer,
    PeerState,
    clamp_lease,
)
from swarmd.discovery.phases import Phase, Trigger, next_phase
from swarmd.discovery.timers import Backoff, LeaseQueue, MinInterval, Periodic, RetrySchedule
from swarmd.discovery.views import ForeignView, PeerView
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator, LOCATOR_KIND_UDPv4
from swarmd.rtps.ports import (
    PARTICIPANT_GAIN,
    SPDP_MULTICAST_GROUP,
    metatraffic_unicast_port,
    spdp_multicast_port,
)
from swarmd.rtps.spdp import (
    BES_SPDP_ONLY,
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    Vouch,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.types import Duration, GuidPrefix, Time

# A driver that stops draining events (or a garbage flood, one PacketDropped per datagram)
# must not grow memory without bound: keep the newest 1024, count the rest.
MAX_PENDING_EVENTS: Final = 1024
# The same for datagrams the driver has not collected yet.
MAX_PENDING_DATAGRAMS: Final = 4096
BUNDLE_DIGEST_BYTES: Final = 16
# A flood of DATA(p) under invented GUID prefixes (issue 10, attack 9) makes every datagram a
# "new foreign participant"; report about one a second (burst 10), each report carrying how
# many it stands for (``ForeignParticipantSeen.suppressed``), so the log is a summary.
MAX_FOREIGN_REPORTS_PER_S: Final = 1.0
FOREIGN_REPORT_BURST: Final = 10.0
# With authentication on, datagrams under prefixes outside the bundle (stock DDS nodes, a
# forger's invented participants, garbage) are decoded at most this often: a decode costs
# ~50 us (docs/benchmarks.md), so a 5,000/s flood would otherwise cost a quarter of a core.
# The commander's vouches kept (one every few seconds; older than any lease are dropped):
# bounds what a commander flooding frames can make a member hold.
MAX_VOUCHES: Final = 64
# A stock participant renews about once a second; beyond the budget it is only counted.
FOREIGN_DECODES_PER_S: Final = 50.0
FOREIGN_DECODE_BURST: Final = 50.0
# Leaving (docs/discovery.md, "Leaving"). A dispose only hastens what the lease does anyway
# (a peer that misses it drops us when our lease ends, 20 s by default), so it must cost the
# channel a constant, never one frame per peer: unicast to every peer at N = 1000 is 1000
# frames and 1000 Ed25519 signatures per leave, ~N^2 frames when a swarm powers down
# together (the flood swarmd exists to avoid: paper section 4.1, network awareness). 802.11
# group frames are neither acknowledged nor retried, so the group copy goes out this many
# times: all lost with probability p^3 were losses independent; they are not quite (fading
# outlasts three frames), but each copy draws its own DCF backoff, so one collision does
# not take them all.
DISPOSE_MULTICAST_COPIES: Final = 3
# Directed copies (acknowledged and retried by the 802.11 MAC: the reliable path) only while
# this few peers are discovered: the paper's real-world swarm (section 5.3) and our testbed
# fly 10 drones, so each of them still gets one per peer, as do the daemon's namespace tests;
# larger swarms rely on the group copies and, failing those, on the lease. A leave costs at
# most MAX_DISPOSE_UNICAST + DISPOSE_MULTICAST_COPIES frames and as many signatures.
MAX_DISPOSE_UNICAST: Final = 9

Wallclock = Callable[[], float]

# Enum members bound once: in CPython 3.11 ``Phase.ANNOUNCE`` is a ~50 ns class-attribute
# lookup, and the receive path asks several of them per datagram (~3M datagrams per
# simulated 1000-drone minute).
_BOOT: Final = Phase.BOOT
_PASSIVE: Final = Phase.PASSIVE
_ANNOUNCE: Final = Phase.ANNOUNCE
_STEADY: Final = Phase.STEADY
_STOPPED: Final = Phase.STOPPED
_UNDISCOVERED: Final = PeerState.UNDISCOVERED
_DISCOVERED: Final = PeerState.DISCOVERED
_LOST: Final = PeerState.LOST


class DiscoveryEngine:
    """Sans-IO SPDP discovery for one bundle participant.

    Driven by three sources: received datagrams (``receive_datagram``), timer expiry
    (``handle_timer`` at ``get_timer()``) and link-quality readings
    (``update_link_quality``). Never performs I/O, never reads a clock.
    """

    # Slots: ~60 attributes are too many for CPython's shared-key instance dicts, so each
    # engine would carry a hash table of its own, and every attribute read on the receive
    # path would probe it (two cache misses when a simulator cycles through 1000 engines).
    # ``__dict__`` keeps instances patchable (tests spy on query methods).
    __slots__ = (
        "_advertised_permille",
        "_armed",
        "_auth",
        "_backoff_now",
        "_boot_deadline",
        "_bundle",
        "_by_name",
        "_commander",
        "_config",
        "_content",
        "_counters",
        "_digest",
        "_domain_id",
        "_dropped",
        "_encoded",
        "_events",
        "_foreign",
        "_foreign_budget",
        "_foreign_reports",
        "_foreign_suppressed",
        "_heard_digest",
        "_index_of",
        "_last_multicast",
        "_leases",
        "_link",
        "_listed_by",
        "_local_dotted",
        "_local_ipv4",
        "_local_octets",
        "_me",
        "_my_bit",
        "_my_index",
        "_my_octet",
        "_my_prefix",
        "_outbox",
        "_passive_deadline",
        "_passive_timer",
        "_passive_window",
        "_peer_at",
        "_peers",
        "_q",
        "_reack_gap_s",
        "_renewal",
        "_retries",
        "_retries_pushed",
        "_rng",
        "_rx_datagrams",
        "_size",
        "_sn",
        "_spread_at",
        "_started",
        "_static_locators",
        "_timing",
        "_tx_kind",
        "_vouch_heap",
        "_vouch_window_ms",
        "_vouched_until",
        "_vouches",
        "_vouching",
        "_wallclock",
        "metatraffic_port",
        "phase",
        "spdp_multicast",
        "user_port",
        "__dict__",
    )

    def __init__(
        self,
        bundle: Bundle,
        local_name: str,
        *,
        config: EngineConfig,
        rng: random.Random,
        now: float,
        local_ipv4: str,
        wallclock: Wallclock | None = None,
        link: LinkSample | None = None,
        auth: SpdpAuth | None = None,
    ) -> None:
        """``wallclock`` (e.g. ``time.time``) stamps INFO_TS; None sends INFO_TS with the
        invalidate flag. ``link``: a first link sample, which skips the BOOT wait.

        ``auth``: sign every datagram sent and refuse every datagram under a bundle prefix
        whose authenticator does not hold, before anything changes (docs/security.md). The
        daemon always passes it; None (simulator, codec tests) sends and accepts plain SPDP.
        """
        me = bundle.member(local_name)  # NotAParticipant (ValueError) if it is not
        if len(bundle.content_sha256) < BUNDLE_DIGEST_BYTES:
            raise ValueError("bundle content_sha256 is shorter than 16 bytes; fix: rebuild it")
        if auth is not None and auth.own_prefix != me.guid_prefix:
            raise ValueError(f"auth keys are not {local_name!r}'s; fix: load this node's keys")
        self._auth = auth
        self._bundle = bundle
        self._me: Participant = me
        self._config = config
        self._rng = rng
        self._wallclock = wallclock
        self._timing = resolve_timing(bundle.discovery, config)
        self._local_ipv4 = local_ipv4
        self._local_octets = _ipv4_octets(local_ipv4)
        self._local_dotted = ".".join(map(str, self._local_octets))
        last = max(bundle.participants, key=lambda p: p.index)
        self._size = last.index + 1
        self._digest = bundle.content_sha256[:BUNDLE_DIGEST_BYTES]
        self.metatraffic_port: int = bundle.metatraffic_port(me)
        self.user_port: int = bundle.user_port(me)
        self.spdp_multicast: tuple[str, int] = (
            SPDP_MULTICAST_GROUP,
            spdp_multicast_port(bundle.domain_id),
        )
        self._static_locators = (
            (Locator.udpv4(local_ipv4, self.metatraffic_port),),
            (Locator.udpv4(*self.spdp_multicast),),
            (Locator.udpv4(local_ipv4, self.user_port),),
        )
        # A peer's bundle address: metatraffic port PB + DG * domain + d1 + PG * index
        # (DDSI-RTPS 9.6.1.1), i.e. the port of index 0 plus PG per index. Linear, so one
        # checked call for the highest index validates all: calling it per peer was 40 % of
        # the construction of a 1000-peer engine (the simulator builds 1000 of them).
        bundle.metatraffic_port(last)
        port0 = metatraffic_unicast_port(bundle.domain_id, 0)
        self._peers: dict[int, Peer] = {}
        # the same peers by bundle index (None: us, or an index the bundle skips)
        self._peer_at: list[Peer | None] = [None] * self._size
        peer_at = self._peer_at
        # N - 1 peers per engine, N engines in a simulation: loop invariants hoisted
        my_index, attempts, gap = me.index, config.max_attempts, config.retransmit_min_gap_s
        for p in bundle.participants:
            index = p.index
            if index == my_index:
                continue
            self._peers[index] = peer_at[index] = Peer(
                p,
                index,
                (p.ipv4, port0 + PARTICIPANT_GAIN * index) if p.ipv4 else None,
                RetrySchedule(attempts),
                MinInterval(gap),
            )
        self._by_name: dict[str, Peer] = {p.participant.name: p for p in self._peers.values()}
        # Bundle peers by GUID prefix octets (bytes hash and compare in C; GuidPrefix's
        # dataclass methods do not): bundle index by prefix in one table shared by every
        # engine of the same bundle (``_index_map``), then our peer at that index. A
        # simulator hands one multicast to 999 engines in a row: one table stays in the CPU
        # cache, 999 per-engine dicts would not (~3 cache misses per datagram at N = 1000).
        self._index_of = _index_map(bundle)
        self.phase: Phase = _BOOT
        self._started = now
        self._boot_deadline: float | None = now + config.boot_link_timeout_s
        self._passive_deadline: float | None = None
        self._passive_window: float | None = None
        self._passive_timer: float | None = None
        self._link: LinkSample | None = None
        self._q = normalise_q(config.default_link_quality)
        self._advertised_permille = round(self._q * 1000)
        # Vouching (adaptive mode, one commander in the bundle; docs/discovery.md): the
        # commander's renewals carry the members it heard directly in the last
        # ``vouch_window_s``; only the commander's (signed) vouch is believed.
        commander_role = Role.COMMANDER
        commanders = [p.index for p in bundle.participants if p.role == commander_role]
        # A vouch must be worth most of a lease, or vouched members (who stop renewing)
        # would lapse between vouches: with a 3 s lease and a 2.5 s window a vouch holds a
        # member for no time at all. Short leases (tests, fast-failover missions) keep plain
        # renewals.
        worthwhile = (
            vouched_lease_s(self._timing.lease_s, config.vouch_window_s) >= self._timing.lease_s / 2
        )
        self._commander: int | None = (
            commanders[0]
            if config.mode == "adaptive" and config.vouch and len(commanders) == 1 and worthwhile
            else None
        )
        self._vouching = self._commander == me.index
        self._vouch_window_ms = round(config.vouch_window_s * 1000)
        self._listed_by = 0  # discovered peers whose latest DATA(p) lists us
        # the commander's recent vouches (arrival, bitmap as an int, window s), oldest first,
        # and the peers whose own lease ran out but a vouch still holds: until when, in a
        # lazy heap (entries whose time no longer matches are stale)
        self._vouches: deque[tuple[float, int, float]] = deque()
        self._vouched_until: dict[int, float] = {}
        self._vouch_heap: list[tuple[float, int]] = []
        self._renewal = Periodic(self._renewal_period(), config.renewal_jitter)
        self._last_multicast: float | None = None
        self._sn = 0
        self._content: SpdpParticipant | None = None
        self._encoded: dict[GuidPrefix | None, bytes] = {}
        self._my_index = me.index
        # where our bit sits in a peer's heard digest (digest.lists, inline on the hot path)
        self._my_octet, self._my_bit = me.index >> 3, me.index & 7
        self._my_prefix = me.guid_prefix.value
        # the heard digest we send, kept up to date on discovery and loss rather than
        # rebuilt from all N peers on every send
        self._heard_digest = HeardBitmap(self._size)
        # peers whose RetrySchedule is armed, a lazy min-heap of their (deadline, index), and
        # the lease deadlines: get_timer() stays O(1) amortised per input, and a lease
        # renewal (the bulk of the traffic) costs O(1)
        self._armed: set[int] = set()
        # (deadline, index, tie-break, the peer's schedule): the schedule itself tells whether
        # an entry is live, without a lookup in the peer table (the counter keeps heapq from
        # comparing schedules when a retry is re-armed at the same instant)
        self._retries: list[tuple[float, int, int, RetrySchedule]] = []
        self._retries_pushed = 0
        self._leases = LeaseQueue()
        self._reack_gap_s = config.retransmit_min_gap_s
        self._spread_at = (math.nan, 0.0)  # (Q, _spread_s() at that Q)
        self._backoff_now = Backoff(math.nan, math.nan)
        self._domain_id = bundle.domain_id
        self._events: deque[Event] = deque()
        self._outbox: deque[tuple[bytes, tuple[str, int]]] = deque()
        self._foreign = ForeignTable(MAX_FOREIGN)
        self._foreign_reports = TokenBucket(MAX_FOREIGN_REPORTS_PER_S, FOREIGN_REPORT_BURST, now)
        self._foreign_suppressed = 0  # since the last ForeignParticipantSeen
        self._foreign_budget = TokenBucket(FOREIGN_DECODES_PER_S, FOREIGN_DECODE_BURST, now)
        self._rx_datagrams = 0
        self._counters: dict[str, int] = {
            "tx_datagrams": 0,
            "tx_multicast": 0,
            "tx_unicast": 0,
            "events_dropped": 0,
            "datagrams_dropped": 0,
            "foreign_suppressed": 0,  # new foreign participants folded into a later report
        }
        self._tx_kind: dict[str, int] = {"announce": 0, "reply": 0, "renewal": 0, "dispose": 0}
        # a Counter, so no reason can raise KeyError out of receive_datagram
        self._dropped: Counter[DropReason] = Counter()
        if link is not None:
            self.update_link_quality(link, now)

    # ------------------------------------------------------------------ inputs

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        """Handle one UDP payload from ``source``. Never raises for any ``data``."""
        self._rx_datagrams += 1  # an attribute, not a _counters entry: one less dict per datagram
        if self.phase is _STOPPED:
            self._dropped[DropReason.STOPPED] += 1
            return
        raw = data if type(data) is bytes else bytes(data)
        fresh: Freshness | None = None
        if self._auth is not None:
            # Before decoding anything, by the RTPS header's prefix (the decoder requires
            # every DATA(p)/DATA(p[UD]) in the datagram to carry the same one):
            prefix = raw[8:20]
            if self._peer_by_prefix(prefix) is not None:
                # a bundle peer's: nothing is decoded, counted as heard or changed until the
                # authenticator holds; cheap checks first (swarmd.auth.spdp). A refusal is
                # counted, not reported per datagram.
                verdict = self._auth.check(prefix, raw, source, now)
                if isinstance(verdict, Refusal):
                    self._dropped[DropReason(verdict.value)] += 1
                    return
                fresh = verdict
            elif prefix == self._my_prefix:
                self._dropped[DropReason.OWN] += 1  # our own multicast, looped back
                return
            elif not self._foreign_budget.take(now):
                self._dropped[DropReason.FOREIGN_BUDGET] += 1  # a flood: not even decoded
                return
        try:
            sender, samples = _decode(raw)
        except DecodeError:
            self._drop(DropReason.DECODE_ERROR, source)
            return
        if sender == self._my_prefix:
            # our own multicast, looped back by the kernel (IP_MULTICAST_LOOP): count only
            self._dropped[DropReason.OWN] += 1
            return
        if not samples:
            self._drop(DropReason.NOT_SPDP, source)
            return
        for sample in samples:
            if type(sample) is _Alive:
                self._on_alive(sample, source, now, fresh)
            else:
                assert isinstance(sample, SpdpDisposed)  # noqa: S101 - _decode makes no other
                self._on_disposed(sample, source, now)
        if self.phase is _ANNOUNCE and not self._any_pending():
            self._settle_if_done()  # (asks _any_pending again: the armed set is empty now)

    def handle_timer(self, now: float) -> None:
        """Act on every deadline at or before ``now`` (call at ``get_timer()``)."""
        if self.phase is _STOPPED:
            return
        if self.phase is _BOOT and self._boot_deadline is not None and now >= self._boot_deadline:
            self._start_passive(now, "no link sample before the boot timeout; default Q")
        self._expire_leases(now)
        if (
            self.phase is _PASSIVE
            and self._passive_deadline is not None
            and now >= self._passive_deadline
        ):
            self._end_passive(now)
        self._flush(now)
        self._settle_if_done()

    def update_link_quality(self, sample: LinkSample, now: float) -> None:
        """A new link reading: first one draws the passive timer (paper section 4.1);
        later ones steer the renewal period and the advertised link quality."""
        if self.phase is _STOPPED:
            return
        self._link = sample
        self._q = normalise_q(sample.q)
        permille = round(self._q * 1000)
        step = round(self._config.link_report_step * 1000)
        if abs(permille - self._advertised_permille) >= max(1, step):
            # hysteresis: a jittery reading must not bump our SN on every poll
            self._advertised_permille = permille
            period = self._renewal_period()
            if self._renewal.deadline() is not None and period != self._renewal.period_s:
                last = self._last_multicast if self._last_multicast is not None else now
                self._renewal.reschedule(period, last, self._rng)
            else:
                self._renewal.period_s = period
        if self.phase is _BOOT:
            self._start_passive(now, f"link quality read (Q={self._q:.2f}, {sample.source})")

    def peer_traffic(self, key: str | GuidPrefix, now: float) -> None:
        """Authenticated traffic from bundle peer ``key`` other than SPDP (a user-data
        datagram the data plane verified with the pair's key): the peer is alive, so its
        lease restarts as if a renewal had arrived. The driver feeds it; only the peer's
        own verified traffic may (never a relay's word). Adaptive mode only: paper mode
        keeps the paper's SPDP-only liveliness. Unknown or undiscovered peers: ignored
        (discovery needs its DATA(p), with its locators)."""
        if self.phase is _STOPPED or self._config.mode != "adaptive":
            return
        if isinstance(key, GuidPrefix):
            peer = self._peer_by_prefix(key.value)
        else:
            peer = self._by_name.get(key)
        if peer is None or peer.state is not _DISCOVERED:
            return
        peer.last_heard = now
        self._leases.renew(peer, peer.lease_s, now)
        if self._vouched_until:
            self._vouched_until.pop(peer.index, None)  # its own lease runs again

    def shutdown(self, now: float) -> None:
        """Leave: queue DATA(p[UD]) ``DISPOSE_MULTICAST_COPIES`` times to the multicast
        group and, while at most ``MAX_DISPOSE_UNICAST`` peers are discovered, once to each
        of them; a bounded number of frames (and signatures) whatever N."""
        if self.phase is _STOPPED:
            return
        self._sn += 1
        prefix, timestamp = self._me.guid_prefix, self._timestamp()
        placeholder = None if self._auth is None else PLACEHOLDER
        # one sample (one SN): the copies differ only in their freshness, each sealed on its
        # own so a receiver takes whichever arrives first and counts no replay for the rest
        group = encode_spdp_dispose(
            prefix, sequence_number=self._sn, timestamp=timestamp, authenticator=placeholder
        )
        self._queue(self._seal(group), self.spdp_multicast, multicast=True)
        self._tx_kind["dispose"] += 1
        targets = [
            (p.participant.guid_prefix, target)
            for p in self._peers.values()
            if p.discovered and (target := p.target()) is not None
        ]
        if len(targets) <= MAX_DISPOSE_UNICAST:
            for destination, target in targets:
                payload = encode_spdp_dispose(
                    prefix,
                    sequence_number=self._sn,
                    timestamp=timestamp,
                    destination=destination,
                    authenticator=placeholder,
                )
                self._queue(self._seal(payload), target, multicast=False)
                self._tx_kind["dispose"] += 1
        # the repeats after the directed frames: spaced by them when there are any
        for _ in range(DISPOSE_MULTICAST_COPIES - 1):
            self._queue(self._seal(group), self.spdp_multicast, multicast=True)
            self._tx_kind["dispose"] += 1
        for p in self._peers.values():
            self._disarm(p)
        self._renewal.stop()
        self._transition(Trigger.SHUTDOWN, "shutdown requested")

    # ----------------------------------------------------------------- outputs

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        """Every queued (payload, (host, port)); the queue is emptied."""
        if not self._outbox:
            return []
        out = list(self._outbox)
        self._outbox.clear()
        return out

    def get_timer(self) -> float | None:
        """The earliest absolute deadline (same clock as ``now``), or None."""
        phase = self.phase
        if phase is _STOPPED:
            return None
        # called after every input (a simulator: ~10^6 times per run), so no temporaries
        if phase is _BOOT:
            best = self._boot_deadline
        elif phase is _PASSIVE:
            best = self._passive_deadline
        else:
            best = self._renewal.due
        lease = self._leases.earliest()
        if lease is not None and (best is None or lease[0] < best):
            best = lease[0]
        if self._vouch_heap:
            vouched = self._next_vouched()
            if vouched is not None and (best is None or vouched < best):
                best = vouched
        heap = self._retries
        if heap:
            # _next_retry() inline for its usual answer: the heap's head is live
            retry: float | None = heap[0][0]
            if heap[0][3].due != retry:
                retry = self._next_retry()
            if retry is not None and (best is None or retry < best):
                best = retry
        return best

    def next_event(self) -> Event | None:
        return self._events.popleft() if self._events else None

    # ------------------------------------------------------------------ status

    @property
    def guid_prefix(self) -> GuidPrefix:
        return self._me.guid_prefix

    @property
    def passive_timer_s(self) -> float | None:
        """The drawn T_passive (seconds after entering PASSIVE), None before it is drawn."""
        return self._passive_timer

    @property
    def passive_window_s(self) -> float | None:
        return self._passive_window

    def peer(self, key: str | GuidPrefix) -> PeerView | None:
        """The bundle peer named ``key`` (its bundle name or GUID prefix); None if not a peer
        (our own name, a stranger). O(1) by prefix, O(N) by name."""
        if isinstance(key, GuidPrefix):
            found = self._peer_by_prefix(key.value)
        else:
            found = next((p for p in self._peers.values() if p.participant.name == key), None)
        return None if found is None else _view(found)

    def peers(self) -> tuple[PeerView, ...]:
        """Every bundle peer (all but us), in bundle order."""
        return tuple(_view(p) for p in sorted(self._peers.values(), key=lambda x: x.index))

    def peer_counts(self) -> tuple[int, int]:
        """(discovered, total) bundle peers."""
        return sum(1 for p in self._peers.values() if p.discovered), len(self._peers)

    def foreign(self, now: float) -> tuple[ForeignView, ...]:
        """Participants heard but never matched and not silent past their lease, least
        recently heard first."""
        return tuple(
            ForeignView(
                e.guid_prefix, e.vendor, e.name, e.reason, e.first_seen, e.last_seen, e.frames
            )
            for e in self._foreign.alive(now)
        )

    def lists_me_names(self) -> frozenset[str]:
        return frozenset(
            p.participant.name for p in self._peers.values() if p.discovered and p.lists_me
        )

    def counters(self) -> dict[str, Any]:
        return {
            "rx_datagrams": self._rx_datagrams,
            **self._counters,
            "tx_kind": dict(self._tx_kind),
            "dropped": {str(reason): self._dropped[reason] for reason in DropReason},
            "foreign_evicted": self._foreign.evicted,
            # signatures verified, tags made and checked (the refusals are in "dropped")
            "auth": {} if self._auth is None else self._auth.counters(),
        }

    def status(self, now: float) -> dict[str, Any]:
        """A JSON-ready snapshot of the engine's state at ``now`` (schema: docs/operations.md,
        ``swarmctl status --json``). A pure function of the state: it changes nothing, so a
        driver calls it when asked, never per datagram. O(N log N)."""
        link: dict[str, Any] = {"q": round(self._q, 3), "snr_db": None, "source": None}
        if self._link is not None:
            link = {
                "q": round(self._q, 3),
                "snr_db": self._link.snr_db,
                "source": self._link.source,
            }
        passive_left = None
        if self.phase is _PASSIVE and self._passive_deadline is not None:
            passive_left = round(max(0.0, self._passive_deadline - now), 3)
        peers = [
            {
                "name": p.name,
                "index": p.index,
                "state": str(p.state),
                "guid": f"{p.guid_prefix}:1c1",
                "last_heard_s": None if p.last_heard is None else round(now - p.last_heard, 3),
                "locator": None if p.locator is None else f"udp/{p.locator[0]}:{p.locator[1]}",
                "matched_endpoints": len(p.matches),
                "lists_me": p.lists_me,
                "epoch": p.epoch,  # its boot epoch (signed): a jump means it restarted
            }
            for p in self.peers()
        ]
        foreign = [
            {
                "guid": f"{e.guid_prefix}:1c1",
                "vendor": e.vendor,
                "name": e.name,
                "reason": str(e.reason),
            }
            for e in self.foreign(now)
        ]
        timing = self._timing
        discovered, total = self.peer_counts()
        return {
            "node": self._me.name,
            "swarm": self._bundle.swarm,
            "phase": str(self.phase),
            "mode": self._config.mode,
            "link": link,
            "passive_timer_s": passive_left,
            "passive_window_s": self._passive_window,
            "timing": {
                "t_min_s": timing.t_min_s,
                "t_max_s": timing.t_max_s,
                "lease_s": timing.lease_s,
                "sources": dict(timing.sources),
                "renewal_period_s": round(self._renewal.period_s, 3),
                "advertised_lease_s": round(self._lease_s(), 3),
            },
            "peers_discovered": discovered,
            "peers_total": total,
            "peers": peers,
            "foreign": foreign,
            "counters": self.counters(),
        }

    # ------------------------------------------------------------- receiving

    def _on_alive(
        self, alive: _Alive, source: tuple[str, int], now: float, fresh: Freshness | None
    ) -> None:
        # every check reads the flat _Alive record (see its docstring): this runs per datagram
        domain_id = alive.domain_id
        if (domain_id is not None and domain_id != self._domain_id) or not alive.plain_tag:
            self._drop(DropReason.WRONG_DOMAIN, source)
            return
        destination = alive.destination
        if destination is not None and destination != self._my_prefix:
            self._drop(DropReason.NOT_FOR_ME, source)
            return
        prefix = alive.prefix
        index = self._index_of.get(prefix)
        peer = None if index is None else self._peer_at[index]
        if peer is None and prefix != self._my_prefix:
            self._see_foreign(alive.sample.participant, DropReason.NOT_IN_BUNDLE, now)
            return
        if not alive.is_swarmd:
            self._see_foreign(alive.sample.participant, DropReason.VENDOR_MISMATCH, now)
            return
        if alive.bundle_digest != self._digest:
            self._see_foreign(alive.sample.participant, DropReason.DIGEST_MISMATCH, now)
            return
        if peer is None:  # pragma: no cover - our own prefix is filtered by the header check
            self._drop(DropReason.OWN, source)
            return
        if not alive.locators.usable(source[0], self._local_octets, self._local_dotted):
            self._drop(DropReason.BAD_LOCATOR, source)
            return
        if self._auth is not None:
            self._auth.note_address(prefix, source)  # used: its budget lives there now
        self._heard(peer, alive, source, now, fresh)

    def _peer_by_prefix(self, prefix: bytes) -> Peer | None:
        """The bundle peer whose GUID prefix octets are ``prefix``; None for us or a stranger."""
        index = self._index_of.get(prefix)
        return None if index is None else self._peer_at[index]

    def _heard(
        self,
        peer: Peer,
        alive: _Alive,
        source: tuple[str, int],
        now: float,
        fresh: Freshness | None = None,
    ) -> None:
        # The hot path: at N = 1000 every engine runs this ~10^4 times a minute, almost
        # always for a renewal that changes nothing but the lease. Everything the sender
        # decides alike for all receivers (target, lease) was derived once in ``_decode``,
        # and the common case reads plain attributes only (no property or helper calls).
        sn = alive.sn
        last_sn = peer.last_sn
        restarted = last_sn is not None and sn < last_sn
        newly = peer.state is not _DISCOVERED
        previous_epoch = peer.epoch
        epoch_rose = False
        if fresh is not None:
            # a new life, whatever its SN (the epoch is signed: not a forger's word)
            epoch_rose = previous_epoch is not None and fresh.epoch > previous_epoch
            restarted = restarted or epoch_rose
            peer.epoch = fresh.epoch
        meta, default = alive.metatraffic_locators, alive.default_locators
        # the lists are interned (``_interned``): unchanged ones are the same object
        moved = not newly and (
            (meta is not peer.metatraffic_locators and meta != peer.metatraffic_locators)
            or (default is not peer.default_locators and default != peer.default_locators)
        )
        # a directed DATA(p) repeated unchanged (same SN) after the re-ack gap
        last_rx = peer.last_rx
        repeat = last_sn == sn and last_rx is not None and now - last_rx >= self._reack_gap_s
        peer.last_heard = peer.last_rx = now
        peer.last_sn = sn
        lease_s = peer.lease_s = alive.lease_s
        # Authenticated, a peer's address is only what it signed: the UDP source of a relayed
        # genuine datagram is the relay's. Unauthenticated (simulator), the source will do.
        peer.locator = alive.target or (source if self._auth is None else peer.locator)
        peer.metatraffic_locators = meta
        peer.default_locators = default
        heard = alive.heard  # digest.lists(heard, our index), inline
        octet = self._my_octet
        listed = heard is not None and octet < len(heard) and (heard[octet] >> self._my_bit) & 1
        lists_me = peer.lists_me
        if listed != lists_me:
            lists_me = peer.lists_me = not lists_me
            self._listed_by += 1 if lists_me else -1
        peer.link_quality_permille = alive.link_quality_permille
        index = peer.index
        self._leases.renew(peer, lease_s, now)
        if self._vouched_until:
            self._vouched_until.pop(index, None)  # its own lease runs again
        vouched = alive.vouched
        if vouched is not None and index == self._commander and not self._vouching:
            self._apply_vouch(vouched, now)
        if moved:
            self._emit(
                PeerLocatorsChanged(
                    peer.participant.name,
                    peer.participant.guid_prefix,
                    meta,
                    default,
                )
            )
        directed = alive.destination is not None
        told = peer.told
        retry = peer.retry
        if restarted and not newly:
            # its SN went back (or its epoch rose): it restarted and forgot us; answer it
            # like a new peer
            told = peer.told = False
            self._disarm(peer)
            if epoch_rose and fresh is not None and previous_epoch is not None:
                self._emit(
                    PeerRestarted(
                        peer.participant.name,
                        peer.participant.guid_prefix,
                        fresh.epoch,
                        previous_epoch,
                    )
                )
        elif newly:
            peer.state = _DISCOVERED
            self._heard_digest.mark(index)
            matches = peer.matches
            if matches is None:
                matches = peer.matches = tuple(self._bundle.matches(self._me, peer.participant))
            told = peer.told = False
            if retry.due is not None or retry.attempts:
                self._disarm(peer)
            peer.times_discovered += 1
            self._emit(
                PeerDiscovered(
                    peer.participant.name,
                    peer.participant.guid_prefix,
                    matches,
                    "directed" if directed else "multicast",
                    meta,
                    default,
                    peer.epoch,
                )
            )
        elif directed and repeat and lists_me and told and peer.reack.permits(now):
            # the peer repeats a directed DATA(p) unchanged: it has not seen us list it
            # (our frame was lost). Only a repeat triggers this, so two engines never
            # ping-pong; MinInterval bounds what a spoofer can make us send.
            peer.reack.mark(now)
            told = peer.told = False
        elif (
            not lists_me
            and told
            and peer.told_at is not None
            and now - peer.told_at > self._answer_window()
        ):
            # it still does not list us although it would have answered our last frame by
            # now: that frame was lost. Answer now instead of waiting out the backoff.
            told = peer.told = False
        if told and lists_me:  # _owes(peer) for a discovered peer: the usual case
            if retry.due is not None or retry.attempts:
                self._disarm(peer)
        elif not told or retry.due is None:
            # first answer after a holdoff; a peer we already told and are waiting on keeps
            # its backoff, since its frame may simply have crossed ours in flight
            self._arm(peer, now + self._reply_delay())

    def _apply_vouch(self, vouch: Vouch, now: float) -> None:
        """The commander heard the members in ``vouch`` directly within its window: their
        leases here may run ``vouched_lease_s`` from ``now`` (never shortened, never past
        their last frame + lease); if it vouched for us, our own renewal waits a period.

        Lazily: the vouch is kept (arrival, bitmap as an int, window) and consulted only
        when a lease runs out (``_expire_leases``), so a vouch costs O(1) here instead of a
        lease update per vouched member (10^6 per vouch across a 1000-drone simulation).
        The newest vouch listing a peer gives its latest vouched deadline, which is what
        renewing every vouched lease at once would have left.

        Trusted only from the commander's prefix (signed, when authenticated), never passed
        on: a vouch moves leases only, never ``last_heard``, and the commander's bitmap is
        built from ``last_heard`` (its own direct hearing), so no vouch feeds another."""
        bits = int.from_bytes(vouch.bitmap, "little")  # bit i = index i (docs/wire.md)
        vouches = self._vouches
        vouches.append((now, bits, vouch.window_ms / 1000))
        while len(vouches) > MAX_VOUCHES or vouches[0][0] < now - MAX_PEER_LEASE_S:
            vouches.popleft()  # older than any lease: it can extend nothing
        me_vouched = bits >> self._my_index & 1
        if (
            me_vouched
            and self._listed_by == len(self._peers)
            and self.phase in (_ANNOUNCE, _STEADY)
        ):
            # the others hold our lease from this vouch: our renewal waits a full period
            # from here, and runs as before once the vouches stop (commander dead, or it
            # stopped hearing us). Only while every peer lists us: a peer that has not
            # discovered us gets nothing from a vouch, and our renewal multicast is what
            # repairs its missed announcement.
            self._renewal.restart(now, self._rng)

    def _on_disposed(self, sample: SpdpDisposed, source: tuple[str, int], now: float) -> None:
        if sample.destination is not None and sample.destination != self._me.guid_prefix:
            self._drop(DropReason.NOT_FOR_ME, source)
            return
        peer = self._peer_by_prefix(sample.guid_prefix.value)
        if peer is None:
            self._foreign.remove(sample.guid_prefix)
            return
        if peer.discovered:
            self._lose(peer, "disposed")

    def _see_foreign(self, part: SpdpParticipant, reason: DropReason, now: float) -> None:
        self._dropped[reason] += 1
        new = self._foreign.see(
            part.guid_prefix,
            vendor=part.vendor_id.name,
            name=part.entity_name,
            reason=reason,
            lease_s=clamp_lease(part.lease_duration.total_seconds()),
            now=now,
        )
        if not new:
            return
        if not self._foreign_reports.take(now):
            self._foreign_suppressed += 1
            self._counters["foreign_suppressed"] += 1
            return
        self._emit(
            ForeignParticipantSeen(
                part.guid_prefix,
                part.vendor_id.name,
                part.entity_name,
                reason,
                self._foreign_suppressed,
            )
        )
        self._foreign_suppressed = 0

    # ---------------------------------------------------------------- phases

    def _transition(self, trigger: Trigger, reason: str) -> None:
        old = self.phase
        self.phase = next_phase(old, trigger)
        self._emit(PhaseChanged(old, self.phase, reason))

    def _start_passive(self, now: float, reason: str) -> None:
        window = passive_window_s(
            self._config.mode,
            self._q,
            swarm_size=len(self._bundle.participants),
            t_min_s=self._timing.t_min_s,
            t_max_s=self._timing.t_max_s,
            announce_budget_fps=self._config.announce_budget_fps,
            q_floor=self._config.q_floor,
        )
        self._passive_window = window
        self._passive_timer = draw_passive_timer_s(self._rng, window)
        self._passive_deadline = now + self._passive_timer
        self._boot_deadline = None
        self._transition(Trigger.LINK_READ, reason)

    def _end_passive(self, now: float) -> None:
        self._passive_deadline = None
        peers = self._peers.values()
        if any(p.state is _UNDISCOVERED or self._owes(p) for p in peers):
            self._transition(Trigger.TIMER_EXPIRED_NEEDED, "passive timer expired")
        else:
            self._transition(
                Trigger.TIMER_EXPIRED_SETTLED, "passive timer expired; every peer lists us"
            )
        # the paper's "standard PDP procedure ... targeting UAVs that have not yet been
        # discovered" (section 4.1); replies still held back ride on the same frame
        for p in peers:
            if p.state is _UNDISCOVERED or self._owes(p):
                self._arm(p, now)
        self._renewal.restart(now, self._rng)

    def _settle_if_done(self) -> None:
        if self.phase != _ANNOUNCE or self._any_pending():
            return
        missing = [p for p in self._peers.values() if not (p.discovered and p.lists_me)]
        if missing:
            reason = f"gave up on {len(missing)} peer(s) after {self._config.max_attempts} tries"
        else:
            reason = "every bundle peer lists us"
        self._transition(Trigger.SETTLED, reason)

    # ----------------------------------------------------------------- debts

    def _owes(self, peer: Peer) -> bool:
        """Whether a frame is owed to ``peer`` (see the theory of operation)."""
        state = peer.state  # asked after every datagram while announcing: no property calls
        if state is _DISCOVERED:
            return not peer.told or not peer.lists_me
        return state is _UNDISCOVERED and self.phase in (_ANNOUNCE, _STEADY)

    def _pending_count(self) -> int:
        """Peers with an armed retry whose debt still stands (stale ones are disarmed)."""
        for index in [i for i in self._armed if not self._owes(self._peers[i])]:
            self._disarm(self._peers[index])
        return len(self._armed)

    def _any_pending(self) -> bool:
        # runs after every datagram while announcing: stop at the first debt that stands
        # (no copy of the armed set), then disarm the stale ones seen before it
        stale: list[Peer] = []
        found = False
        peers = self._peer_at  # a list: one cache line per lookup, not a dict probe
        announcing = self.phase in (_ANNOUNCE, _STEADY)
        for index in self._armed:
            peer = peers[index]
            assert peer is not None  # noqa: S101 - only peers are armed
            state = peer.state  # _owes(peer), inline
            if state is _DISCOVERED:
                if not peer.told or not peer.lists_me:
                    found = True
                    break
            elif state is _UNDISCOVERED and announcing:
                found = True
                break
            stale.append(peer)
        for peer in stale:
            self._disarm(peer)
        return found

    def _arm(self, peer: Peer, at: float) -> None:
        retry = peer.retry
        due = retry.due  # retry.arm(at), inline: ~3M arms per 1000-drone run
        if retry.attempts < retry.max_attempts and (due is None or at < due):
            retry.due = at
            self._armed.add(peer.index)
            self._retries_pushed += 1
            heapq.heappush(self._retries, (at, peer.index, self._retries_pushed, retry))

    def _disarm(self, peer: Peer) -> None:
        """The debt is paid or void: forget the deadline and the attempts."""
        peer.retry.reset()
        self._armed.discard(peer.index)

    def _next_retry(self) -> float | None:
        """The earliest armed retry; entries of disarmed or re-armed retries are dropped."""
        heap = self._retries
        while heap:
            at, _, _, retry = heap[0]
            if retry.due == at:
                return at
            heapq.heappop(heap)
        return None

    def _reply_delay(self) -> float:
        if self._config.mode == "paper":
            return self._rng.uniform(0.0, self._config.reply_delay_max_s)
        spread = self._spread_s()
        # rng.uniform(spread, 2 * spread) as random.py defines it, a + (b - a) * random():
        # the same draw without uniform's Python frame (~10^6 replies per 1000-drone run)
        high = 2.0 * spread
        return spread + (high - spread) * self._rng.random()

    def _spread_s(self) -> float:
        """Adaptive mode's W at the current Q: the time N frames take at the budget rate."""
        q, spread = self._spread_at
        if q != self._q:  # computed once per Q: every held-back reply and retry asks
            q = self._q
            spread = passive_window_s(
                "adaptive",
                q,
                swarm_size=len(self._bundle.participants),
                t_min_s=self._timing.t_min_s,
                t_max_s=self._timing.t_max_s,
                announce_budget_fps=self._config.announce_budget_fps,
                q_floor=self._config.q_floor,
            )
            self._spread_at = (q, spread)
        return spread

    def _answer_window(self) -> float:
        """The longest a peer holds back its answer to a frame of ours (its reply delay)."""
        if self._config.mode == "paper":
            return self._config.reply_delay_max_s
        return 2.0 * self._spread_s()

    def _backoff(self) -> Backoff:
        # a retry must wait out the peer's own reply holdoff, or it races the answer
        base = max(self._config.retry_base_s, self._answer_window())
        backoff = self._backoff_now
        if backoff.base_s != base:  # Q moved (adaptive holdoff); one object per Q
            backoff = self._backoff_now = Backoff(base, max(self._config.retry_max_s, base))
        return backoff

    def _renewal_period(self) -> float:
        config = self._config
        if self._vouching:
            return vouch_period_s(
                self._advertised_permille / 1000,
                lease_s=self._timing.lease_s,
                window_s=config.vouch_window_s,
                per_lease_min=config.renewals_per_lease_min,
                per_lease_max=config.renewals_per_lease_max,
            )
        return renewal_period_s(
            self._advertised_permille / 1000,
            lease_s=self._timing.lease_s,
            per_lease_min=config.renewals_per_lease_min,
            per_lease_max=config.renewals_per_lease_max,
            # paper mode keeps the bundle's lease and the plain n(Q) density
            swarm_size=len(self._bundle.participants),
            renewal_budget_fps=config.renewal_budget_fps if config.mode == "adaptive" else None,
        )

    def _lease_s(self) -> float:
        """The lease we advertise (awareness.advertised_lease_s)."""
        return advertised_lease_s(
            self._advertised_permille / 1000,
            lease_s=self._timing.lease_s,
            renewal_period_s=self._renewal.period_s,
            per_lease_min=self._config.renewals_per_lease_min,
            per_lease_max=self._config.renewals_per_lease_max,
        )

    def _flush(self, now: float) -> None:
        """Pay the debts that are due: one multicast, or directed frames (section 4.1)."""
        due: list[Peer] = []
        for index in sorted(self._armed):
            p = self._peers[index]
            deadline = p.retry.deadline()
            if deadline is None or deadline > now:
                continue
            if self._owes(p):
                due.append(p)
            else:
                self._disarm(p)
        renewal_due = self.phase in (_ANNOUNCE, _STEADY) and (
            (d := self._renewal.deadline()) is not None and d <= now
        )
        if not due and not renewal_due:
            return
        silent = self.phase in (_BOOT, _PASSIVE)
        pending = self._pending_count()
        unreachable = any(p.target() is None for p in due)
        if renewal_due or (
            not silent and (pending >= self._config.multicast_threshold or unreachable)
        ):
            self._send(None, now, "renewal" if renewal_due and not due else "announce")
            # _covered(p) for every peer, inline: O(N) per multicast (~1.5M peers covered in
            # a 1000-drone run). The phase and the backoff are the same for all of them.
            announcing = self.phase in (_ANNOUNCE, _STEADY)
            backoff: Backoff | None = None
            for p in self._peers.values():
                state = p.state
                if state is _DISCOVERED:
                    p.told, p.told_at = True, now
                retry = p.retry
                if retry.due is None:
                    continue  # not in a retry cycle (settled, or given up): nothing to count
                retry.sent()
                self._armed.discard(p.index)
                # _owes(p); a discovered peer was told just now
                if not (
                    not p.lists_me
                    if state is _DISCOVERED
                    else state is _UNDISCOVERED and announcing
                ):
                    self._disarm(p)
                elif silent:
                    pass  # the paper: one directed reply per frame heard (see _covered)
                elif not retry.exhausted:
                    if backoff is None:
                        backoff = self._backoff()
                    self._arm(p, now + backoff.delay_s(retry.attempts, self._rng))
            return
        for p in due:
            target = p.target()
            if target is None:  # an undiscovered peer without a bundle address, while silent
                continue
            self._send(p, now, "reply")
            self._covered(p, now)

    def _covered(self, peer: Peer, now: float) -> None:
        """``peer`` was just sent a frame listing everyone we hear: count the attempt."""
        if peer.discovered:
            peer.told, peer.told_at = True, now
        if peer.retry.deadline() is None:
            return  # not in a retry cycle (settled, or given up): nothing to count
        peer.retry.sent()
        self._armed.discard(peer.index)
        if not self._owes(peer):
            self._disarm(peer)
        elif self.phase in (_BOOT, _PASSIVE):
            pass  # the paper: one directed reply per frame heard; retries wait for ANNOUNCE
        elif not peer.retry.exhausted:
            self._arm(peer, now + self._backoff().delay_s(peer.retry.attempts, self._rng))

    # --------------------------------------------------------------- leases

    def _expire_leases(self, now: float) -> None:
        expired: list[Peer] = []
        while (earliest := self._leases.earliest()) is not None and now >= earliest[0]:
            peer = self._peers[earliest[1]]
            self._leases.remove(peer)
            self._expire_or_hold(peer, now, expired)
        heap = self._vouch_heap
        while heap and heap[0][0] <= now:
            at, index = heapq.heappop(heap)
            if self._vouched_until.get(index) == at:
                del self._vouched_until[index]
                self._expire_or_hold(self._peers[index], now, expired)
        for p in sorted(expired, key=lambda p: p.index):  # events in bundle order
            self._lose(p, "lease")

    def _expire_or_hold(self, peer: Peer, now: float, expired: list[Peer]) -> None:
        """``peer``'s lease ran out: a vouch may still hold it (then it waits in the vouch
        heap until that runs out too), else it is lost."""
        until = self._vouched_deadline(peer, now) if self._vouches else None
        if until is None:
            expired.append(peer)
            return
        self._vouched_until[peer.index] = until
        heapq.heappush(self._vouch_heap, (until, peer.index))

    def _vouched_deadline(self, peer: Peer, now: float) -> float | None:
        """When the newest vouch listing ``peer`` stops holding it, if after ``now``."""
        index = peer.index
        for received, bits, window_s in reversed(self._vouches):
            if bits >> index & 1:
                until = received + vouched_lease_s(peer.lease_s, window_s)
                return until if until > now else None
        return None

    def _next_vouched(self) -> float | None:
        """The earliest vouched deadline; stale heap entries are dropped."""
        heap = self._vouch_heap
        while heap:
            at, index = heap[0]
            if self._vouched_until.get(index) == at:
                return at
            heapq.heappop(heap)
        return None

    def _lose(self, peer: Peer, reason: str) -> None:
        peer.state = _LOST
        self._leases.remove(peer)
        self._vouched_until.pop(peer.index, None)
        self._heard_digest.unmark(peer.index)
        peer.told = False
        if peer.lists_me:
            peer.lists_me = False
            self._listed_by -= 1
        self._disarm(peer)
        self._emit(PeerLost(peer.participant.name, peer.participant.guid_prefix, reason))

    # --------------------------------------------------------------- sending

    def _vouch(self, now: float) -> Vouch | None:
        """The commander's vouch: the discovered members heard directly (their DATA(p) or
        verified user data; never a vouch) within the window. O(N), once per frame sent."""
        if not self._vouching:
            return None
        since = now - self._config.vouch_window_s
        bitmap = HeardBitmap(self._size)
        for p in self._peers.values():
            if p.state is _DISCOVERED and p.last_heard is not None and (p.last_heard >= since):
                bitmap.mark(p.index)
        return Vouch(self._vouch_window_ms, bitmap.to_bytes())

    def _participant_data(self, now: float) -> SpdpParticipant:
        meta_uc, meta_mc, user_uc = self._static_locators
        heard = self._heard_digest.to_bytes()
        return SpdpParticipant(
            self._me.guid_prefix,
            domain_id=self._bundle.domain_id,
            metatraffic_unicast_locators=meta_uc,
            metatraffic_multicast_locators=meta_mc,
            default_unicast_locators=user_uc,
            lease_duration=Duration.from_seconds(self._lease_s()),
            builtin_endpoints=BES_SPDP_ONLY,
            entity_name=f"{self._bundle.swarm}/{self._me.name}",
            bundle_digest=self._digest,
            heard=heard,
            link_quality_permille=self._advertised_permille,
            vouched=self._vouch(now),
            authenticator=None if self._auth is None else PLACEHOLDER,
        )

    def _send(self, peer: Peer | None, now: float, kind: str) -> None:
        content = self._participant_data(now)
        if content != self._content:
            # SPDP is a keyed history of depth 1: a new SN whenever the content changes
            self._content = content
            self._sn += 1
            self._encoded.clear()
        destination = None if peer is None else peer.participant.guid_prefix
        target = self.spdp_multicast if peer is None else peer.target()
        if target is None:  # callers check; an undiscovered peer without an address
            return
        payload = self._encoded.get(destination) if self._wallclock is None else None
        if payload is None:
            payload = encode_spdp(
                content,
                sequence_number=self._sn,
                timestamp=self._timestamp(),
                destination=destination,
            )
            if self._wallclock is None:
                self._encoded[destination] = payload
        # the memo keeps the unsigned template; every datagram gets its own freshness
        self._queue(self._seal(payload), target, multicast=peer is None)
        self._tx_kind[kind] += 1
        if peer is None:
            self._last_multicast = now
            if self.phase in (_ANNOUNCE, _STEADY):
                self._renewal.restart(now, self._rng)

    def _seal(self, template: bytes) -> bytes:
        return template if self._auth is None else self._auth.seal(template)

    def _queue(self, payload: bytes, target: tuple[str, int], *, multicast: bool) -> None:
        if len(self._outbox) >= MAX_PENDING_DATAGRAMS:
            self._outbox.popleft()
            self._counters["datagrams_dropped"] += 1
        self._outbox.append((payload, target))
        self._counters["tx_datagrams"] += 1
        self._counters["tx_multicast" if multicast else "tx_unicast"] += 1

    def _timestamp(self) -> Time | None:
        return None if self._wallclock is None else Time.from_seconds(self._wallclock())

    # ----------------------------------------------------------------- misc

    def _emit(self, event: Event) -> None:
        if len(self._events) >= MAX_PENDING_EVENTS:
            self._events.popleft()
            self._counters["events_dropped"] += 1
        self._events.append(event)

    def _drop(self, reason: DropReason, source: tuple[str, int]) -> None:
        self._dropped[reason] += 1
        self._emit(PacketDropped(reason, source))


def _view(p: Peer) -> PeerView:
    discovered = p.state is _DISCOVERED
    return PeerView(
        name=p.participant.name,
        index=p.index,
        guid_prefix=p.participant.guid_prefix,
        state=p.state,
        last_heard=p.last_heard,
        locator=p.target(),
        metatraffic_unicast_locators=p.metatraffic_locators,
        default_unicast_locators=p.default_locators,
        matches=(p.matches or ()) if discovered else (),
        lists_me=discovered and p.lists_me,
        lease_s=p.lease_s,
        link_quality_permille=p.link_quality_permille,
        times_discovered=p.times_discovered,
        epoch=p.epoch,
    )


@dataclass(frozen=True, slots=True)
class _Alive:
    """A received DATA(p) with what every receiver derives from it alike, computed once.

    The fields after ``lease_s`` copy (or pre-chew) the sample's so that the receive path,
    which runs once per datagram per engine (~3M times in a 1000-drone simulation), reads
    one flat slotted record instead of chains of dataclass attributes."""

    sample: SpdpAlive
    prefix: bytes  # the participant's GUID prefix octets
    is_swarmd: bool  # vendor id
    target: tuple[str, int] | None  # its first usable unicast metatraffic locator
    lease_s: float  # its advertised lease, clamped (peers.clamp_lease)
    sn: int
    destination: bytes | None  # INFO_DST's prefix octets, None when sent to everyone
    domain_id: int | None
    plain_tag: bool  # no domain tag (None or empty)
    bundle_digest: bytes | None
    heard: bytes | None
    link_quality_permille: int | None
    vouched: Vouch | None
    metatraffic_locators: tuple[Locator, ...]
    default_locators: tuple[Locator, ...]
    locators: _LocatorFacts


@dataclass(frozen=True, slots=True)
class _LocatorFacts:
    """Whether a bundle peer's unicast locators (metatraffic: SPDP replies; default: user
    data) are all addresses we may send to (issue 10, attack 7), split into what the datagram
    alone decides (computed once per payload) and what the receiver adds (``usable``).

    Refused: multicast (224/4), unspecified and broadcast; loopback (127/8) unless the
    datagram itself came over loopback (co-hosted daemons: tests, a ground station running
    several participants); and the receiver's own address unless the datagram came from it
    (co-hosted participants): a captured member announcing the receiver's own address would
    make the receiver send that member's traffic to itself, into any UDP service on it.
    Other locator kinds (shared memory, TCP) are never used for sending, so they pass."""

    octets: frozenset[bytes]  # every UDPv4 unicast locator's address
    refused: bool  # one is multicast, unspecified or broadcast
    loopback: bool  # one is in 127/8

    def usable(self, source_host: str, own_octets: bytes, own_dotted: str) -> bool:
        """For a receiver whose address is ``own_octets`` (b"" if unknown), dotted
        ``own_dotted``, of a datagram from ``source_host``."""
        if self.refused or (self.loopback and not source_host.startswith("127.")):
            return False
        return not (own_octets in self.octets and source_host != own_dotted)


def _locator_facts(part: SpdpParticipant) -> _LocatorFacts:
    octets: set[bytes] = set()
    refused = loopback = False
    for loc in (*part.metatraffic_unicast_locators, *part.default_unicast_locators):
        if loc.kind != LOCATOR_KIND_UDPv4:
            continue
        addr = loc.address[12:]
        octets.add(addr)
        first = addr[0]
        if 224 <= first <= 239 or addr in (b"\x00\x00\x00\x00", b"\xff\xff\xff\xff"):
            refused = True
        elif first == 127:
            loopback = True
    return _LocatorFacts(frozenset(octets), refused, loopback)


# (the RTPS header's GUID prefix octets, its DATA(p)s and DATA(p[UD])s)
_Decoded = tuple[bytes, tuple[_Alive | SpdpDisposed, ...]]

# Decoded datagrams kept for reuse, oldest evicted first. Decoding is pure and nothing
# decoded is ever mutated, so engines may share it: a simulator running N engines in one
# process hands the same multicast (the same bytes object) to N - 1 of them back to back.
# A daemon sees each datagram once; the memo then costs one dict lookup.
DECODE_MEMO_ENTRIES: Final = 256
_decoded: dict[bytes, _Decoded] = {}


def _decode(data: bytes) -> _Decoded:
    """``_decode_fresh``, memoised. Errors are not cached: garbage costs a full decode each
    time, as it should."""
    hit = _decoded.get(data)
    if hit is None:
        hit = _decode_fresh(data)
        if len(_decoded) >= DECODE_MEMO_ENTRIES:
            del _decoded[next(iter(_decoded))]
        _decoded[data] = hit
    return hit


def _decode_fresh(data: bytes) -> _Decoded:
    """``decode_spdp`` plus the per-datagram facts of each DATA(p)."""
    header, samples = decode_spdp(data)
    out: list[_Alive | SpdpDisposed] = []
    for sample in samples:
        if isinstance(sample, SpdpAlive):
            part = sample.participant
            destination = sample.destination
            meta = _interned(part.metatraffic_unicast_locators)
            default = _interned(part.default_unicast_locators)
            out.append(
                _Alive(
                    sample,
                    part.guid_prefix.value,
                    part.is_swarmd,
                    _unicast_target(part.metatraffic_unicast_locators),
                    clamp_lease(part.lease_duration.total_seconds()),
                    sample.sequence_number,
                    None if destination is None else destination.value,
                    part.domain_id,
                    part.domain_tag in (None, ""),
                    part.bundle_digest,
                    part.heard,
                    part.link_quality_permille,
                    part.vouched,
                    meta,
                    default,
                    _locator_facts(part),
                )
            )
        else:
            out.append(sample)
    return header.guid_prefix.value, tuple(out)


# Locator lists seen lately, so that a peer's unchanged lists are the same tuple object from
# one of its datagrams to the next and the receive path's "did it move?" test is an identity
# check in C (equal Locators compare through their dataclass __eq__, in Python). Bounded: a
# flood of invented locators only clears it.
MAX_INTERNED_LOCATOR_LISTS: Final = 1024
_locator_lists: dict[tuple[Locator, ...], tuple[Locator, ...]] = {}


def _interned(locators: tuple[Locator, ...]) -> tuple[Locator, ...]:
    found = _locator_lists.get(locators)
    if found is None:
        if len(_locator_lists) >= MAX_INTERNED_LOCATOR_LISTS:
            _locator_lists.clear()
        found = _locator_lists[locators] = locators
    return found


# Bundle index by GUID prefix octets, one table per bundle participant list (keyed by it),
# shared by every engine of that bundle; read-only. A process holds one bundle (a daemon)
# or a few (tests), so the bound only guards against a caller building endless bundles.
MAX_INDEX_MAPS: Final = 16
_index_maps: dict[tuple[tuple[bytes, int], ...], dict[bytes, int]] = {}


# The last participant tuple seen and its table: the same (immutable) tuple object needs no
# key built from its N prefixes (a simulator builds N engines of one bundle in a row). The
# reference held here keeps the tuple alive, so its identity cannot be reused.
_last_index_map: tuple[tuple[Participant, ...], dict[bytes, int]] | None = None


def _index_map(bundle: Bundle) -> Mapping[bytes, int]:
    global _last_index_map  # a one-entry cache in front of _index_maps
    participants = bundle.participants
    last = _last_index_map
    if last is not None and last[0] is participants:
        return last[1]
    key = tuple((p.guid_prefix.value, p.index) for p in participants)
    found = _index_maps.get(key)
    if found is None:
        if len(_index_maps) >= MAX_INDEX_MAPS:
            _index_maps.clear()
        found = _index_maps[key] = dict(key)
    _last_index_map = (participants, found)
    return found


def _unicast_target(locators: tuple[Locator, ...]) -> tuple[str, int] | None:
    """The first usable UDPv4 unicast locator (DDSI-RTPS 8.5.3.1 metatrafficUnicastLocatorList)."""
    for loc in locators:
        if loc.kind != LOCATOR_KIND_UDPv4 or not 0 < loc.port <= 0xFFFF:
            continue
        octets = loc.address[12:]
        # 224.0.0.0/4 is multicast (RFC 5771); 0.0.0.0 and the broadcast address name no peer.
        # Plain bytes tests: this runs per datagram, and ipaddress objects cost ~10 us here
        if 224 <= octets[0] <= 239 or octets in (b"\x00\x00\x00\x00", b"\xff\xff\xff\xff"):
            continue
        return ".".join(map(str, octets)), loc.port
    return None


def _ipv4_octets(host: str) -> bytes:
    """Four octets of a dotted IPv4 address; empty (matches nothing) if it is not one."""
    parts = host.split(".")
    if len(parts) != 4 or not all(p.isdigit() and int(p) < 256 for p in parts):
        return b""
    return bytes(int(p) for p in parts)
