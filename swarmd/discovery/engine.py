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
datagram are memoised per payload (``received.decode``), leases sit in an O(1)-per-renewal
queue (``timers.LeaseQueue``), retries in a lazy heap, and the heard digest is kept
incrementally.

The engine is split by concern, each a small slotted class holding its own state; this
module keeps the public API and the phases, pays the debts that fall due, and wires the
others together:

* ``receive.ReceivePath``: the receive path (authentication pre-check, decode, checks,
  ``_heard``), the drop counters;
* ``debts.Debts``: which peers are owed a frame, the retry heap, holdoff and backoff;
* ``leases.Leases``: leases, the commander's vouches, the heard digest;
* ``renewals.Renewals``: our link quality, the renewal period, the advertised lease;
* ``seek.Seek``: a short multicast while peers are lost; ``seek.SoughtBy``, the peers that
  lost us while we kept them (the receive path's lost_us rule);
* ``foreign.ForeignParticipants``: participants outside the bundle, reports, decode budget;
* ``pullin.PullIn``: pulling our next multicast in after a rejoin or a lease's end;
* ``sending.Sender``: our DATA(p) and DATA(p[UD]), the sequence number, the outbox;
* ``status``: the typed views and JSON forms; ``received``: what a datagram says.

What the per-datagram path and ``get_timer()`` read of another concern is one attribute away
(``self._retries`` is the debts' heap itself; ``receive.py`` says why objects, not bound
methods). The phase is copied to the receive path and the debts on every transition.

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

import random
from collections import Counter, deque
from typing import Any, Final

from swarmd.auth.spdp import SpdpAuth
from swarmd.bundle.model import Bundle, Participant
from swarmd.discovery.awareness import draw_passive_timer_s, passive_window_s
from swarmd.discovery.config import EngineConfig, resolve_timing
from swarmd.discovery.debts import Debts
from swarmd.discovery.events import DropReason, Event, PacketDropped, PeerLost, PhaseChanged
from swarmd.discovery.foreign import ForeignParticipants
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.leases import Leases
from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.phases import Phase, Trigger, next_phase
from swarmd.discovery.pullin import PullIn
from swarmd.discovery.receive import ReceivePath
from swarmd.discovery.renewals import Renewals
from swarmd.discovery.seek import Seek
from swarmd.discovery.sending import Sender, Wallclock
from swarmd.discovery.status import (
    foreign_json,
    link_json,
    peer_json,
    peer_view,
    rates_json,
    timing_json,
)
from swarmd.discovery.timers import MinInterval, RetrySchedule
from swarmd.discovery.views import ForeignView, PeerView
from swarmd.rtps.locator import Locator
from swarmd.rtps.ports import (
    PARTICIPANT_GAIN,
    SPDP_MULTICAST_GROUP,
    metatraffic_unicast_port,
    spdp_multicast_port,
)
from swarmd.rtps.spdp import Vouch
from swarmd.rtps.types import GuidPrefix

# A driver that stops draining events (or a garbage flood, one PacketDropped per datagram)
# must not grow memory without bound: keep 1024, count the rest; a drop report never pushes
# a peer's event out (``_emit``).
MAX_PENDING_EVENTS: Final = 1024
# (The same for datagrams not collected yet: sending.MAX_PENDING_DATAGRAMS.)
BUNDLE_DIGEST_BYTES: Final = 16
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

# Enum members bound once: in CPython 3.11 ``Phase.ANNOUNCE`` is a ~50 ns class-attribute
# lookup, and get_timer() (after every input) asks several of them.
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

    # Slots: a simulator cycles through 1000 engines, and a slot read costs no per-engine
    # hash table probe (cache misses). ``__dict__`` keeps instances patchable (tests spy on
    # query methods).
    __slots__ = (
        "_auth",
        "_boot_deadline",
        "_bundle",
        "_by_name",
        "_config",
        "_debts",
        "_events",
        "_events_dropped",
        "_foreign",
        "_lease_queue",
        "_leases",
        "_me",
        "_outbox",
        "_passive_deadline",
        "_passive_timer",
        "_pull",
        "_passive_window",
        "_peer_by_prefix",
        "_peers",
        "_receive",
        "_renewal",
        "_renewals",
        "_retries",
        "_rng",
        "_seek",
        "_sender",
        "_timing",
        "_hold_heap",
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
        timing = self._timing = resolve_timing(bundle.discovery, config)
        last = max(bundle.participants, key=lambda p: p.index)
        size = last.index + 1
        self.metatraffic_port: int = bundle.metatraffic_port(me)
        self.user_port: int = bundle.user_port(me)
        self.spdp_multicast: tuple[str, int] = (
            SPDP_MULTICAST_GROUP,
            spdp_multicast_port(bundle.domain_id),
        )
        # A peer's bundle address: metatraffic port PB + DG * domain + d1 + PG * index
        # (DDSI-RTPS 9.6.1.1), i.e. the port of index 0 plus PG per index. Linear, so one
        # checked call for the highest index validates all: calling it per peer was 40 % of
        # the construction of a 1000-peer engine (the simulator builds 1000 of them).
        bundle.metatraffic_port(last)
        port0 = metatraffic_unicast_port(bundle.domain_id, 0)
        self._peers: dict[int, Peer] = {}
        # the same peers by bundle index (None: us, or an index the bundle skips)
        peer_at: list[Peer | None] = [None] * size
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
        self.phase: Phase = _BOOT
        self._boot_deadline: float | None = now + config.boot_link_timeout_s
        self._passive_deadline: float | None = None
        self._passive_window: float | None = None
        self._passive_timer: float | None = None
        self._events: deque[Event] = deque()
        self._events_dropped = 0

        # the concerns, each with its own state (see the theory of operation)
        swarm_size = len(bundle.participants)
        leases = self._leases = Leases(
            bundle, my_index, self._peers, config=config, timing=timing, size=size, now=now
        )
        renewals = self._renewals = Renewals(
            config, timing, swarm_size=swarm_size, vouching=leases.vouching, now=now
        )
        debts = self._debts = Debts(
            self._peers,
            peer_at,
            renewals,
            config=config,
            timing=timing,
            rng=rng,
            swarm_size=swarm_size,
        )
        digest = bundle.content_sha256[:BUNDLE_DIGEST_BYTES]
        sender = self._sender = Sender(
            bundle,
            me,
            digest=digest,
            static_locators=(
                (Locator.udpv4(local_ipv4, self.metatraffic_port),),
                (Locator.udpv4(*self.spdp_multicast),),
                (Locator.udpv4(local_ipv4, self.user_port),),
            ),
            spdp_multicast=self.spdp_multicast,
            auth=auth,
            wallclock=wallclock,
            leases=leases,
            renewals=renewals,
        )
        self._pull = PullIn(
            config, debts=debts, leases=leases, renewals=renewals, peer_count=len(self._peers)
        )
        seek = self._seek = Seek(
            enabled=config.mode == "adaptive",
            rng=rng,
            peer_at=peer_at,
            my_guid_prefix=me.guid_prefix.value,
        )
        dropped: Counter[DropReason] = Counter()
        foreign = self._foreign = ForeignParticipants(dropped, now)
        receive = self._receive = ReceivePath(
            bundle,
            me,
            peer_at,
            phase=self.phase,
            auth=auth,
            digest=digest,
            local_ipv4=local_ipv4,
            reack_gap_s=config.retransmit_min_gap_s,
            dropped=dropped,
            leases=leases,
            debts=debts,
            seek=seek,
            foreign=foreign,
            emit=self._emit,
            lose=self._lose,
            settle=self._settle_if_done,
            on_vouch=self._on_vouch,
            rejoined=self._rejoined,
            answer_seek=self._answer_seek,
        )
        # what get_timer() (after every input) reads, one attribute away: the concerns' own
        # objects (never replaced), not copies; and the receive path's prefix lookup
        self._renewal = renewals.timer
        self._outbox = sender.outbox
        self._lease_queue = leases.queue
        self._hold_heap = leases.hold_heap
        self._retries = debts.retries
        self._peer_by_prefix = receive.peer_by_prefix
        if link is not None:
            self.update_link_quality(link, now)

    # ------------------------------------------------------------------ inputs

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        """Handle one UDP payload from ``source``. Never raises for any ``data``
        (``receive.ReceivePath``)."""
        self._receive.receive_datagram(data, source, now)

    def handle_timer(self, now: float) -> None:
        """Act on every deadline at or before ``now`` (call at ``get_timer()``)."""
        if self.phase is _STOPPED:
            return
        if self.phase is _BOOT and self._boot_deadline is not None and now >= self._boot_deadline:
            self._start_passive(now, "no link sample before the boot timeout; default Q")
        # Leases.expire only when a probe point, a hold or a vouch came (most timers are retries and
        # renewals): earliest() is cached, and the call and its sort are not free
        earliest = self._lease_queue.earliest()
        hold_heap = self._hold_heap
        if (earliest is not None and now >= earliest[0]) or (hold_heap and hold_heap[0][0] <= now):
            probes: list[Peer] = []
            expired = self._leases.expire(now, probes)
            for peer in expired:
                self._lose(peer, "lease")
            if expired and self.phase in (_ANNOUNCE, _STEADY):
                self._pull.lease_ended(now)
                self._seek.start(expired, now)  # seek.py: a multicast every ~1 s while lost
            for peer in probes:
                self._probe(peer, now)
        if (
            self.phase is _PASSIVE
            and self._passive_deadline is not None
            and now >= self._passive_deadline
        ):
            self._end_passive(now)
        seek = self._seek
        if seek.due is not None and now >= seek.due and seek.fire(now):
            self._send(None, now, "seek")
        debts = self._debts
        if debts.late_due is not None and now >= debts.late_due:
            for p in debts.take_late_copies(now):  # MAC-acknowledged, where our multicast is not
                self._send(p, now, "reply")
        self._flush(now)
        self._settle_if_done()

    def update_link_quality(self, sample: LinkSample, now: float) -> None:
        """A new link reading: first one draws the passive timer (paper section 4.1);
        later ones steer the renewal period and the advertised link quality."""
        if self.phase is _STOPPED:
            return
        self._renewals.on_link(sample, now, self._rng)
        if self.phase is _BOOT:
            q = self._renewals.q
            self._start_passive(now, f"link quality read (Q={q:.2f}, {sample.source})")

    def set_ros2_alive(self, alive: bytes | None, now: float) -> None:
        """Our ROS 2 relay's alive participants changed (docs/ros2.md, "Node liveness"):
        carried from now on in every DATA(p) (PID 0x8A06, signed with the rest). A change
        pulls our next multicast in, to now or ``retransmit_min_gap_s`` after the last one
        (whichever is later), so the other drones hear it within that gap instead of a
        renewal period; a local process flapping a node cannot make us send more than one
        multicast per gap. Never called without a relay: the simulator's frames are as
        before."""
        sender = self._sender
        if alive == sender.ros2_alive:
            return
        sender.ros2_alive = alive
        if self.phase is not _ANNOUNCE and self.phase is not _STEADY:
            return  # BOOT/PASSIVE: our first announcement carries it
        self._pull.pull_in(now, 0.0)

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
        self._leases.renew(peer, now)

    def shutdown(self, now: float) -> None:
        """Leave: queue DATA(p[UD]) ``DISPOSE_MULTICAST_COPIES`` times to the multicast
        group and, while at most ``MAX_DISPOSE_UNICAST`` peers are discovered, once to each
        of them; a bounded number of frames (and signatures) whatever N."""
        if self.phase is _STOPPED:
            return
        targets = [
            (p.participant.guid_prefix, target)
            for p in self._peers.values()
            if p.discovered and (target := p.target()) is not None
        ]
        self._sender.dispose(
            targets if len(targets) <= MAX_DISPOSE_UNICAST else [],
            group_copies=DISPOSE_MULTICAST_COPIES,
        )
        for p in self._peers.values():
            self._debts.disarm(p)
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
        lease = self._lease_queue.earliest()
        if lease is not None and (best is None or lease[0] < best):
            best = lease[0]
        if self._hold_heap:
            vouched = self._leases.next_held()
            if vouched is not None and (best is None or vouched < best):
                best = vouched
        seek = self._seek.due
        if seek is not None and (best is None or seek < best):
            best = seek
        late = self._debts.late_due
        if late is not None and (best is None or late < best):
            best = late
        heap = self._retries
        if heap:
            # Debts.next_retry() inline for its usual answer: the heap's head is live
            retry: float | None = heap[0][0]
            if heap[0][3].due != retry:
                retry = self._debts.next_retry()
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
        return None if found is None else peer_view(found)

    def peers(self) -> tuple[PeerView, ...]:
        """Every bundle peer (all but us), in bundle order."""
        return tuple(peer_view(p) for p in sorted(self._peers.values(), key=lambda x: x.index))

    def peer_counts(self) -> tuple[int, int]:
        """(discovered, total) bundle peers."""
        return sum(1 for p in self._peers.values() if p.discovered), len(self._peers)

    def foreign(self, now: float) -> tuple[ForeignView, ...]:
        """Participants heard but never matched and not silent past their lease, least
        recently heard first."""
        return self._foreign.views(now)

    def lists_me_names(self) -> frozenset[str]:
        return frozenset(
            p.participant.name for p in self._peers.values() if p.discovered and p.lists_me
        )

    def counters(self) -> dict[str, Any]:
        dropped = self._receive.dropped
        sent = self._sender.counters
        return {
            "rx_datagrams": self._receive.rx_datagrams,
            "tx_datagrams": sent["tx_datagrams"],
            "tx_multicast": sent["tx_multicast"],
            "tx_unicast": sent["tx_unicast"],
            "events_dropped": self._events_dropped,
            **self._receive.lives_counters(),  # restarts and returns held (receive.py)
            "datagrams_dropped": sent["datagrams_dropped"],
            # new foreign participants folded into a later report
            "foreign_suppressed": self._foreign.suppressed_total,
            "tx_kind": dict(self._sender.tx_kind),
            "dropped": {str(reason): dropped[reason] for reason in DropReason},
            "foreign_evicted": self._foreign.table.evicted,
            # frames sent carrying the commander's vouch; the commander's vouches taken
            "vouches_sent": self._leases.vouches_sent.total,
            "vouches_received": self._leases.vouches_received.total,
            # signatures verified, tags made and checked (the refusals are in "dropped")
            "auth": {} if self._auth is None else self._auth.counters(),
        }

    def status(self, now: float) -> dict[str, Any]:
        """A JSON-ready snapshot of the engine's state at ``now`` (schema: docs/operations.md,
        ``swarmctl status --json``). A pure function of the state: it changes nothing, so a
        driver calls it when asked, never per datagram. O(N log N)."""
        passive_left = None
        if self.phase is _PASSIVE and self._passive_deadline is not None:
            passive_left = round(max(0.0, self._passive_deadline - now), 3)
        renewals = self._renewals
        peers = [peer_json(p, now) for p in self.peers()]
        foreign = [foreign_json(e) for e in self.foreign(now)]
        discovered, total = self.peer_counts()
        return {
            "node": self._me.name,
            "swarm": self._bundle.swarm,
            "phase": str(self.phase),
            "mode": self._config.mode,
            "link": link_json(renewals.q, renewals.link),
            "passive_timer_s": passive_left,
            "passive_window_s": self._passive_window,
            "timing": timing_json(
                self._timing, renewal_period_s=self._renewal.period_s, lease_s=renewals.lease_s()
            ),
            "rates": rates_json(
                now,
                renewals_sent=renewals.sent,
                vouches_sent=self._leases.vouches_sent,
                vouches_received=self._leases.vouches_received,
            ),
            "peers_discovered": discovered,
            "peers_total": total,
            "peers": peers,
            "foreign": foreign,
            "counters": self.counters(),
        }

    # ---------------------------------------------------------------- phases

    def _transition(self, trigger: Trigger, reason: str) -> None:
        old = self.phase
        new = self.phase = next_phase(old, trigger)
        # the receive path's and the debts' view of the phase: kept in step with every
        # transition (the only place the phase changes)
        self._receive.phase = new
        debts = self._debts
        debts.announcing = new is _ANNOUNCE or new is _STEADY
        debts.silent = new is _BOOT or new is _PASSIVE
        self._emit(PhaseChanged(old, new, reason))

    def _start_passive(self, now: float, reason: str) -> None:
        window = passive_window_s(
            self._config.mode,
            self._renewals.q,
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
        debts = self._debts
        if any(p.state is _UNDISCOVERED or debts.owes(p) for p in peers):
            self._transition(Trigger.TIMER_EXPIRED_NEEDED, "passive timer expired")
        else:
            self._transition(
                Trigger.TIMER_EXPIRED_SETTLED, "passive timer expired; every peer lists us"
            )
        # the paper's "standard PDP procedure ... targeting UAVs that have not yet been
        # discovered" (section 4.1); replies still held back ride on the same frame
        for p in peers:
            if p.state is _UNDISCOVERED or debts.owes(p):
                debts.arm(p, now)
        self._renewal.restart(now, self._rng)

    def _settle_if_done(self) -> None:
        if self.phase != _ANNOUNCE or self._debts.any_pending():
            return
        missing = [p for p in self._peers.values() if not (p.discovered and p.lists_me)]
        if missing:
            reason = f"gave up on {len(missing)} peer(s) after {self._config.max_attempts} tries"
        else:
            reason = "every bundle peer lists us"
        self._transition(Trigger.SETTLED, reason)

    # ---------------------------------------------------- paying debts, losing peers

    def _flush(self, now: float) -> None:
        """Pay the debts that are due: one multicast, or directed frames (section 4.1)."""
        debts = self._debts
        due = debts.due(now) if debts.armed else []
        renewal_due = self.phase in (_ANNOUNCE, _STEADY) and (
            (d := self._renewal.deadline()) is not None and d <= now
        )
        if not due and not renewal_due:
            return
        silent = self.phase in (_BOOT, _PASSIVE)
        pending = debts.pending_count()
        unreachable = any(p.target() is None for p in due)
        if renewal_due or (
            not silent and (pending >= self._config.multicast_threshold or unreachable)
        ):
            plain_renewal = renewal_due and not due and not self._pull.pulled_in
            self._send(None, now, "renewal" if plain_renewal else "announce")
            debts.covered_all(now)
            debts.defer_found_again(now)  # a directed copy each a gap on, if still unlisted
            return
        for p in due:
            target = p.target()
            if target is None:  # an undiscovered peer without a bundle address, while silent
                continue
            self._send(p, now, "reply")
            debts.covered(p, now)

    def _lose(self, peer: Peer, reason: str) -> None:
        peer.state = _LOST
        self._leases.forget(peer)
        peer.told = False
        self._debts.disarm(peer)
        self._debts.forget_found_again(peer.index)
        self._receive.sought_by.forget(peer.index)  # seek.SoughtBy: it lost us, we lost it
        self._emit(PeerLost(peer.participant.name, peer.participant.guid_prefix, reason))

    def _on_vouch(self, vouch: Vouch, now: float, multicast: bool) -> None:
        """The commander's vouch arrived (``Leases.apply_vouch``), in a multicast or in a
        DATA(p) directed to us."""
        self._leases.vouches_received.mark(now)
        listed = self._leases.apply_vouch(vouch, now)
        if listed and multicast and self.phase in (_ANNOUNCE, _STEADY):
            # the others hold our lease from this vouch: our renewal waits a full period
            # from here, and runs as before once the vouches stop (commander dead, or it
            # stopped hearing us). Only a multicast vouch: a directed one reached us alone,
            # and the others hold nothing from it (issue 20's blackout: the last member the
            # returning commander heard got the only vouch naming it in the commander's
            # directed answer, stopped renewing, and was probed by all the others 15 s on)
            self._renewal.restart(now, self._rng)

    def _rejoined(self, now: float) -> bool:
        """A lost peer was heard again (``pullin.PullIn.rejoined``): the others still lost may
        be back within seconds, so the seek's put-off bound holds again (``Seek.returned``)."""
        self._seek.returned(now)
        phase = self.phase
        return self._pull.rejoined(now, announcing=phase is _ANNOUNCE or phase is _STEADY)

    def _answer_seek(self, now: float, delay: float) -> float | None:
        """When our multicast answer to a peer that lost us and seeks us is due
        (``pullin.PullIn.answer_seek``), or None: answer it alone, directed (paper mode, or
        a phase that never multicasts)."""
        phase = self.phase
        if self._config.mode != "adaptive" or not (phase is _ANNOUNCE or phase is _STEADY):
            return None
        return self._pull.answer_seek(now, delay)

    def _probe(self, peer: Peer, now: float) -> None:
        """The last-chance probe (``leases.PROBE_AT``): our DATA(p) directed to ``peer`` with
        its bit cleared from our heard digest. A peer answers at once any frame that does
        not list it (receive.py: it owes us a frame while we do not list it), and its
        answer renews its lease here; ours is renewed there by the probe itself. Clearing
        ``told`` is the truth (this frame did not list it) and makes us list it in our
        answer to its reply."""
        if peer.target() is None:
            return
        heard = self._leases.heard
        heard.unmark(peer.index)
        self._sender.send(peer, now, "probe")
        heard.mark(peer.index)
        peer.told = False

    # --------------------------------------------------------------- sending

    def _send(self, peer: Peer | None, now: float, kind: str) -> None:
        """Our DATA(p) to ``peer``, or to the group (None): a multicast restarts the renewal."""
        self._sender.send(peer, now, kind)
        if peer is None:
            if kind == "renewal":
                self._renewals.sent.mark(now)
            self._renewals.last_multicast = now
            self._seek.sent(now)  # it omits every lost peer: it seeks them
            self._pull.sent(now, self._rng, announcing=self.phase in (_ANNOUNCE, _STEADY))

    def _emit(self, event: Event) -> None:
        events = self._events
        if len(events) >= MAX_PENDING_EVENTS:
            # Full (the owner is not draining, or one batch brought this many). A drop
            # report never displaces anything: one forged datagram of 1,024 refused samples
            # pushed a peer's PeerDiscovered out before the daemon drained it (review 16).
            # A peer's event makes room by displacing the oldest drop report, else the
            # oldest event (a scan, only when full).
            self._events_dropped += 1
            if type(event) is PacketDropped:
                return
            for i, old in enumerate(events):
                if type(old) is PacketDropped:
                    del events[i]
                    break
            else:
                events.popleft()
        events.append(event)
