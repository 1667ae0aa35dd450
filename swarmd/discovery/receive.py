"""The receive path: one datagram in, checked, then heard (or counted and dropped).

Order (style.md rule 16, verify then change state): with authentication on, the RTPS
header's GUID prefix picks the check before anything is decoded (``receive_datagram``: a
bundle peer's datagram must pass ``SpdpAuth.check``, our own looped-back multicast is
counted, anything else is decoded only within the foreign-decode budget); then the decode
(``received.decode``, memoised per payload); then per DATA(p) the cheap checks (domain,
destination, bundle membership, vendor, bundle digest, locators: ``_on_alive``) and only
then the state change (``_heard``). A DATA(p[UD]) loses the peer (``_on_disposed``).

This runs once per datagram per engine (in the simulator, ~3M times for 1000 drones), so it
holds no O(N) work and reads plain attributes: what every receiver derives alike from a
datagram is computed once (``received.Alive``), and the objects of the other concerns it
calls into (the lease queue, the debts) are slots of its own, one attribute read away
(``self._debts.arm(...)``). Bound methods kept per engine (``self._arm = debts.arm``) were
tried: each is one more per-engine object, cold in the cache when hundreds of engines take a
datagram in a row, and at N = 300 they cost 3.6 % more simulated D1 misses and 0.6 % more
instructions (one cachegrind run each; docs/simulator.md, "Issue 20").

Invariant: ``receive_datagram`` never raises for any input; malformed input becomes a
``PacketDropped`` event and a counter. Any other exception escaping it is a bug.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Final

from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import Refusal, SpdpAuth
from swarmd.bundle.model import Bundle, Participant
from swarmd.discovery import received
from swarmd.discovery.debts import Debts
from swarmd.discovery.events import (
    DropReason,
    Event,
    PacketDropped,
    PeerDiscovered,
    PeerLocatorsChanged,
    PeerRestarted,
    PeerRos2Liveness,
)
from swarmd.discovery.foreign import ForeignParticipants
from swarmd.discovery.leases import Leases
from swarmd.discovery.peers import Peer, PeerState
from swarmd.discovery.phases import Phase
from swarmd.discovery.received import Alive
from swarmd.discovery.seek import Seek, SoughtBy
from swarmd.lives import LifeDamping
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.spdp import SpdpDisposed, Vouch

# Enum members bound once: in CPython 3.11 ``Phase.ANNOUNCE`` is a ~50 ns class-attribute
# lookup, and the receive path asks several of them per datagram.
_ANNOUNCE: Final = Phase.ANNOUNCE
_STOPPED: Final = Phase.STOPPED
_DISCOVERED: Final = PeerState.DISCOVERED

# A peer's restarts (its signed boot epoch rose: ``PeerRestarted``) are honoured at most once
# per this interval. Each one resets the data plane's pair session, makes the ROS 2 relay
# dispose and re-announce the peer's nodes to every local node, and writes log lines; a
# captured member's key signs any epoch, so it could restart on every datagram, 20 a second
# (its verification budget). A daemon raises its epoch once per start and sends its first
# datagram after READY=1 (swarmd.auth.epoch; docs/benchmarks.md, "Daemon start-up"), and a
# life is heard only if it sent before it died, so two rises of an honest peer are at least
# one start-up to the first SPDP apart: 0.288 s at the fastest of 60 measured starts, READY=1
# 0.268 s (``bench/daemon_start.py``, bench/results/daemon_start/, a 2-core x86 host; a
# Jetson Nano is slower; systemd waits RestartSec=2s after a crash). A faster rise is taken
# for freshness (the replay window moves with it) and counted (``restarts_coalesced``); the
# peer's first datagram past the interval honours its newest epoch, so a restart is late,
# never lost (docs/security.md, "Epoch churn"). The same interval holds a peer's return after
# its own signed dispose (``ReceivePath._disposed_at``): an honest daemon disposes only as it stops,
# and its next life sends no sooner than a start-up later (the figures above; ``systemctl
# restart`` starts it at once, a failure waits RestartSec=2s first: systemd/swarmd.service),
# so a return within the interval is a captured member leaving and returning, each a
# ``PeerLost`` and a ``PeerDiscovered`` at every drone. It is held (not listed, nothing
# moves), counted (``returns_held``), and honoured by the peer's first datagram past the
# interval: late by at most the interval, never lost (docs/security.md, "A captured member's
# lives"). Over time a peer's lives (honoured restarts and returns) are damped too
# (``lives.LifeDamping``, RFC 2439): past its first few, its next one waits up to
# ``lives.FLAP_HOLD_MAX_S``, held and honoured the same way.
RESTART_MIN_INTERVAL_S: Final = 0.25


class ReceivePath:
    """The engine's receive path and what it alone keeps: the drop counters, the received
    datagram count, the prefix -> peer lookup and the receiver's own address facts."""

    __slots__ = (
        "_auth",
        "_bundle",
        "_commander",
        "_debts",
        "_disposed_at",
        "_digest",
        "_domain_id",
        "_emit",
        "_foreign",
        "_index_of",
        "_lease_queue",
        "_leases",
        "_lives",
        "_local_dotted",
        "_local_octets",
        "_lose",
        "_me",
        "_my_bit",
        "_my_guid",
        "_my_octet",
        "_my_prefix",
        "_on_vouch",
        "_probe_at",
        "_rejoined",
        "_answer_seek",
        "_peer_at",
        "_pin_at",
        "_reack_gap_s",
        "_restarted_at",
        "_ros2_alive",
        "_seek",
        "_seekers",
        "_settle",
        "_held_until",
        "_vouching",
        "dropped",
        "lives_damped",
        "phase",
        "restarts_coalesced",
        "returns_held",
        "rx_datagrams",
        "sought_by",
    )

    def __init__(
        self,
        bundle: Bundle,
        me: Participant,
        peer_at: list[Peer | None],
        *,
        phase: Phase,
        auth: SpdpAuth | None,
        digest: bytes,
        local_ipv4: str,
        reack_gap_s: float,
        dropped: Counter[DropReason],
        leases: Leases,
        debts: Debts,
        seek: Seek,
        foreign: ForeignParticipants,
        emit: Callable[[Event], None],
        lose: Callable[[Peer, str], None],
        settle: Callable[[], None],
        on_vouch: Callable[[Vouch, float, bool], None],
        rejoined: Callable[[float], bool],
        answer_seek: Callable[[float, float], float | None],
    ) -> None:
        # the engine's phase, as the receive path sees it: set by DiscoveryEngine._transition
        # (a slot of our own: read twice per datagram)
        self.phase = phase
        self._bundle = bundle
        self._me = me
        self._auth = auth
        self._digest = digest
        self._domain_id = bundle.domain_id
        self._local_octets = received.ipv4_octets(local_ipv4)
        self._local_dotted = ".".join(map(str, self._local_octets))
        self._reack_gap_s = reack_gap_s
        # Bundle peers by GUID prefix octets (bytes hash and compare in C; GuidPrefix's
        # dataclass methods do not): bundle index by prefix in one table shared by every
        # engine of the same bundle (``received.index_map``), then our peer at that index. A
        # simulator hands one multicast to 999 engines in a row: one table stays in the CPU
        # cache, 999 per-engine dicts would not (~3 cache misses per datagram at N = 1000).
        self._index_of = received.index_map(bundle)
        # by bundle index: the address the bundle pins for that peer, if any (shared too)
        self._pin_at = received.pin_table(bundle)
        self._peer_at = peer_at
        self._my_guid = me.guid_prefix
        self._my_prefix = me.guid_prefix.value
        # where our bit sits in a peer's heard digest (digest.lists, inline on the hot path)
        self._my_octet, self._my_bit = me.index >> 3, me.index & 7
        # a Counter, so no reason can raise KeyError out of receive_datagram
        self.dropped = dropped
        self.rx_datagrams = 0
        self.restarts_coalesced = 0  # epoch rises within RESTART_MIN_INTERVAL_S, held back
        self.returns_held = 0  # DATA(p) within RESTART_MIN_INTERVAL_S of its sender's dispose
        # of both, those held by the peer's penalty past the interval (lives.LifeDamping)
        self.lives_damped = 0
        # its lives (honoured restarts and returns) damped over time: ours alone, by index
        self._lives = LifeDamping()
        # A peer's rare facts, by bundle index, kept off ``Peer``, which every engine reads
        # on every reception (its three such fields cost +1.6 % CPU at N = 1000:
        # docs/simulator.md, "Session 18"; docs/discovery.md, "Cost per datagram"): when its
        # own signed dispose lost it (its return waits; cleared once honoured), when we last
        # honoured its restart, and its relay's alive ROS 2 participants (PID 0x8A06) from
        # its latest accepted DATA(p). Only a bundle peer's verified frame writes a row, its
        # own: at most the bundle's N - 1 rows each, and empty in a swarm that never leaves,
        # restarts or runs a relay (the simulator).
        self._disposed_at: dict[int, float] = {}
        self._restarted_at: dict[int, float] = {}
        self._ros2_alive: dict[int, bytes] = {}
        self._foreign = foreign
        # the other concerns (each one attribute read per datagram; see the module docstring)
        self._leases = leases
        self._lease_queue = leases.queue
        self._held_until = leases.held_until  # the dict itself, never replaced
        self._probe_at = leases.probe_at  # the lease queue's key: the probe point
        self._commander = leases.commander
        self._vouching = leases.vouching
        self._debts = debts
        self._seek = seek
        # the peers that lost us while we kept them (seek.SoughtBy: the lost_us rule), ours
        # alone but for the engine's _lose, which forgets a lost peer; and its table, read
        # once per datagram (the dict itself, never replaced: empty on the usual path)
        self.sought_by = SoughtBy(bundle.size)
        self._seekers = self.sought_by.entries
        self._emit = emit
        self._lose = lose
        self._settle = settle
        self._on_vouch = on_vouch
        self._rejoined = rejoined
        self._answer_seek = answer_seek  # engine._answer_seek: the lost_us answer, multicast

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        """Handle one UDP payload from ``source``. Never raises for any ``data``."""
        self.rx_datagrams += 1  # an attribute, not a counters entry: one less dict per datagram
        if self.phase is _STOPPED:
            self.dropped[DropReason.STOPPED] += 1
            return
        raw = data if type(data) is bytes else bytes(data)
        fresh: Freshness | None = None
        if self._auth is not None:
            # Before decoding anything, by the RTPS header's prefix (the decoder requires
            # every DATA(p)/DATA(p[UD]) in the datagram to carry the same one):
            prefix = raw[8:20]
            if self.peer_by_prefix(prefix) is not None:
                # a bundle peer's: nothing is decoded, counted as heard or changed until the
                # authenticator holds; cheap checks first (swarmd.auth.spdp). A refusal is
                # counted, not reported per datagram.
                verdict = self._auth.check(prefix, raw, source, now)
                if isinstance(verdict, Refusal):
                    self.dropped[DropReason(verdict.value)] += 1
                    return
                fresh = verdict
            elif prefix == self._my_prefix:
                self.dropped[DropReason.OWN] += 1  # our own multicast, looped back
                return
            elif not self._foreign.may_decode(len(raw), now):
                # a flood, of datagrams or of octets: not even decoded
                self.dropped[DropReason.FOREIGN_BUDGET] += 1
                return
        try:
            sender, samples = received.decode(raw)
        except DecodeError:
            self._drop(DropReason.DECODE_ERROR, source)
            return
        if sender == self._my_prefix:
            # our own multicast, looped back by the kernel (IP_MULTICAST_LOOP): count only
            self.dropped[DropReason.OWN] += 1
            return
        if not samples:
            self._drop(DropReason.NOT_SPDP, source)
            return
        for sample in samples:
            if type(sample) is Alive:
                self._on_alive(sample, source, now, fresh)
            else:
                assert isinstance(sample, SpdpDisposed)  # noqa: S101 - decode makes no other
                self._on_disposed(sample, source, now)
        if self.phase is _ANNOUNCE and not self._debts.any_pending():
            self._settle()  # (asks any_pending again: the armed set is empty now)

    def lives_counters(self) -> dict[str, int]:
        """The holds of a peer's lives (``RESTART_MIN_INTERVAL_S``, ``lives.LifeDamping``)."""
        return {
            # a peer's epoch rises held: within the interval of its last honoured restart,
            # or while its penalty is above the limit
            "restarts_coalesced": self.restarts_coalesced,
            # a peer's DATA(p) held after its own dispose, for the same two reasons
            "returns_held": self.returns_held,
            # of both, those held by the penalty alone (past the interval)
            "lives_damped": self.lives_damped,
        }

    def peer_by_prefix(self, prefix: bytes) -> Peer | None:
        """The bundle peer whose GUID prefix octets are ``prefix``; None for us or a stranger."""
        index = self._index_of.get(prefix)
        return None if index is None else self._peer_at[index]

    def _on_alive(
        self, alive: Alive, source: tuple[str, int], now: float, fresh: Freshness | None
    ) -> None:
        # every check reads the flat Alive record (see its docstring): this runs per datagram
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
            self._see_foreign(alive, DropReason.NOT_IN_BUNDLE, now)
            return
        if not alive.is_swarmd:
            self._see_foreign(alive, DropReason.VENDOR_MISMATCH, now)
            return
        if alive.bundle_digest != self._digest:
            self._see_foreign(alive, DropReason.DIGEST_MISMATCH, now)
            return
        if peer is None:  # pragma: no cover - our own prefix is filtered by the header check
            self._drop(DropReason.OWN, source)
            return
        locators = alive.locators
        # Where the bundle pins the peer's address (the mission's ipv4), every UDPv4 unicast
        # locator it signs must name it, any port: a captured member keeps its key, so its
        # signature says nothing about the address, and every send to it (directed frames,
        # the data plane, the ROS 2 relay) goes there (docs/security.md, "Pinned
        # addresses"). Inline: a subset test on the pre-chewed octets, once per datagram.
        pinned = self._pin_at[peer.index]
        if not locators.usable(source[0], self._local_octets, self._local_dotted) or (
            pinned is not None and not locators.octets <= pinned
        ):
            self._drop(DropReason.BAD_LOCATOR, source)
            return
        if self._auth is not None:
            self._auth.note_address(prefix, source)  # used: its budget lives there now
        disposed = self._disposed_at
        disposed_at = disposed.get(peer.index) if disposed else None
        if disposed_at is not None:
            # set only as its own dispose lost it, cleared once it is heard again
            soon = now - disposed_at < RESTART_MIN_INTERVAL_S
            if soon or self._lives.held(peer.index, now):
                # back sooner than a daemon restarts after its dispose, or past its free
                # lives (lives.py): held, nothing moves; its first datagram past both counts
                self.returns_held += 1
                self.lives_damped += not soon
                return
            del disposed[peer.index]
            self._lives.honoured(peer.index, now)  # a life: its return, found below
        self._heard(peer, alive, source, now, fresh)

    def _heard(
        self,
        peer: Peer,
        alive: Alive,
        source: tuple[str, int],
        now: float,
        fresh: Freshness | None = None,
    ) -> None:
        # The hot path: at N = 1000 every engine runs this ~10^4 times a minute, almost
        # always for a renewal that changes nothing but the lease. Everything the sender
        # decides alike for all receivers (target, lease) was derived once in
        # ``received.decode``, and the common case reads plain attributes only (no property
        # or helper calls).
        sn = alive.sn
        last_sn = peer.last_sn
        restarted = last_sn is not None and sn < last_sn
        newly = peer.state is not _DISCOVERED
        previous_epoch = peer.epoch
        epoch_rose = False
        if fresh is not None:
            # a new life, whatever its SN (the epoch is signed: not a forger's word)
            epoch_rose = previous_epoch is not None and fresh.epoch > previous_epoch
            if epoch_rose and not newly:
                honoured_at = self._restarted_at.get(peer.index)
                soon = honoured_at is not None and now - honoured_at < RESTART_MIN_INTERVAL_S
                if soon or self._lives.held(peer.index, now):
                    # faster than a daemon starts, or past its free lives (lives.py): a
                    # captured member churning its epoch. Fresh all the same (its window
                    # moved); peer.epoch stays the honoured life's, so its first datagram
                    # past both honours the newest
                    epoch_rose = False
                    self.restarts_coalesced += 1
                    self.lives_damped += not soon
                else:
                    self._restarted_at[peer.index] = now
                    self._lives.honoured(peer.index, now)  # a life: its restart
                    peer.epoch = fresh.epoch
                    # its new life's first word is reported (below)
                    self._ros2_alive.pop(peer.index, None)
            else:
                peer.epoch = fresh.epoch
            restarted = restarted or epoch_rose
        meta, default = alive.metatraffic_locators, alive.default_locators
        # the lists are interned (``received.interned``): unchanged ones are the same object
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
        stopped_listing = False  # its frame no longer lists us: it lost us (see below)
        if listed != lists_me:
            stopped_listing = lists_me
            lists_me = peer.lists_me = not lists_me
            if lists_me:
                if self._seekers:  # empty on the usual path: a peer first listing us
                    self.sought_by.forget(peer.index)  # it found us: the lost_us rule is done
            else:
                self.sought_by.lost_us(peer.index)  # it lost us: the rule's spacing starts
            self._leases.listed_by += 1 if lists_me else -1
        if self._seekers and heard is not None:
            # while some peer has lost us (never on the usual path): if it is this one and
            # hears more peers than before, the rule's spacing starts over (SoughtBy.heard)
            self.sought_by.heard(peer.index, heard)
        peer.link_quality_permille = alive.link_quality_permille
        if epoch_rose and not newly and fresh is not None and previous_epoch is not None:
            # Before its relay's word below: the ROS 2 relay takes a new life's first word
            # as that life's baseline (its restart counts start again), not as its nodes'
            # restarts after the re-match this restart makes (swarmd.ros2.relay_remote)
            self._emit(
                PeerRestarted(
                    peer.participant.name, peer.participant.guid_prefix, fresh.epoch, previous_epoch
                )
            )
        ros2_alive = alive.ros2_alive
        if (
            ros2_alive is not None
            and ros2_alive != self._ros2_alive.get(peer.index)
            and (fresh is None or fresh.epoch == peer.epoch)
        ):
            # its ROS 2 nodes' liveness (absent: no relay there; the sim never sends it), of
            # the life we honour: a new life's word waits with its held restart (above)
            self._ros2_alive[peer.index] = ros2_alive
            self._emit(
                PeerRos2Liveness(peer.participant.name, peer.participant.guid_prefix, ros2_alive)
            )
        index = peer.index
        self._lease_queue.renew(peer, lease_s * self._probe_at, now)  # Leases.renew, inline
        if self._held_until:
            self._held_until.pop(index, None)  # its own lease runs again
        vouched = alive.vouched
        if vouched is not None and index == self._commander and not self._vouching:
            self._on_vouch(vouched, now, alive.destination is None)
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
        if self._seek.due is not None and not newly and not directed:
            self._seek.heard(heard, now, index)  # seek.py: its multicast may seek for us
        rejoin = False  # a lost peer heard again, answered by a frame of its own
        told = peer.told
        retry = peer.retry
        if restarted and not newly:
            # its SN went back (or its epoch rose): it restarted and forgot us; answer it
            # like a new peer, but within the rejoin delay U(0, W1), not the Q-stretched
            # holdoff U(W, 2W): it is a drone we had and hear again, as after an outage,
            # and Q read before its restart says nothing of the link now. On the channel the
            # holdoff made a rebooted drone wait up to 2.6 s for a corner drone's answer
            # (Q 0.30 at N = 20: W = 1.3 s), 3.8 s to list all 19 (docs/benchmarks.md, "The
            # rebooted drone at N = 20"). The same directed frames, sooner; once per re-ack
            # gap, so a peer restarting over and over cannot make us answer faster than that
            told = peer.told = False
            self._debts.disarm(peer)
            if peer.reack.permits(now):
                peer.reack.mark(now)
                rejoin = True
        elif newly:
            peer.state = _DISCOVERED
            self._leases.heard.mark(index)
            matches = peer.matches
            if matches is None:
                matches = peer.matches = tuple(self._bundle.matches(self._me, peer.participant))
            told = peer.told = False
            if retry.due is not None or retry.attempts:
                self._debts.disarm(peer)
            peer.times_discovered += 1
            if peer.times_discovered > 1:
                # a lost peer is back: the link evidently is too. Our pulled-in multicast
                # answers it; if none was pulled in, our answer to it alone comes as soon
                # (Debts.rejoin_delay), not after the Q-stretched holdoff
                rejoin = not self._rejoined(now)
                if not rejoin:
                    # the pulled-in multicast answers it, and a directed copy follows a gap on
                    # if it still does not list us (Debts.defer_found_again): at the edge of
                    # range a group frame, sent once and unacknowledged, is the one lost
                    # (docs/benchmarks.md, "The fly-out")
                    self._debts.found_again.add(index)
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
        elif directed and not lists_me and peer.reack.permits(now):
            # a directed DATA(p) from a peer we know that does not list us: a last-chance
            # probe (leases.PROBE_AT: it has not heard us for 3/4 of our lease) or a peer
            # that has never heard us. Either way an answer is wanted now, not after the
            # adaptive holdoff (U(W, 2W): 8-16 s at N = 200, past the probed lease's end):
            # the paper's immediate directed reply (section 4.1), within reply_delay_max_s.
            # MinInterval (the re-ack gap) bounds what a spoofer can make us send.
            peer.reack.mark(now)
            told = peer.told = False
            self._debts.disarm(peer)  # a fresh debt: its backoff and attempts start over
            self._debts.arm(peer, now + self._debts.prompt_delay())
            return
        elif (
            not lists_me
            and told
            and peer.times_discovered > 1
            and self._seek.enabled
            and peer.told_at is not None
            and now - peer.told_at >= self._reack_gap_s
            and peer.reack.permits(now)
        ):
            # a peer we had lost and found again still seeks us (seek.py: its multicast
            # omits us) although we listed it a re-ack gap ago: that frame was lost (a link
            # at the edge of range). Answer within the rejoin delay, not the Q-stretched
            # holdoff U(W, 2W) (2.7-8 s at Q near 0): on the channel such pairs waited
            # 2.4-6.1 s after the first frame had crossed. Once per re-ack gap, and only
            # while it seeks (bounded there); never at start-up (found once).
            peer.reack.mark(now)
            told = peer.told = False
            rejoin = True
        elif (
            not lists_me and peer.reack.permits(now) and self.sought_by.may_answer(peer.index, now)
        ):
            # The lost_us rule: it listed us, then lost us, and still seeks us (its frames
            # omit us) although we kept it: a peer that could not hear us while we heard it
            # (a drone at the edge of range), or one whose first answer from us was lost
            # too. Answer at once, within Debts.cue_delay (U(0, omitted / budget): only the
            # peers its frame omits may answer it too; not the rejoin delay U(0, N /
            # budget), which let an answer land after a 1 s window closed, nor the
            # Q-stretched holdoff), with one attempt left whatever the earlier need spent
            # (the retries spent while it could not hear us may be exhausted, and the
            # backoff or our next renewal outlasts its in-range window: in the irregular
            # fade at N = 20 such a pair waited 32 s). One answer, not a new series of
            # retries: its next frame that omits us is our next cue. Spaced by SoughtBy
            # (1, 2, 4, 8, 8 ... s after each answer, starting over when its frames list
            # more peers) and by the re-ack gap, whatever the peer sends: a drone that hears
            # nobody costs each peer one answer per 8 s, a peer toggling its digest one per
            # re-ack gap at most. (Never for a restarted peer: the branch above takes every
            # restart.)
            peer.reack.mark(now)
            self.sought_by.answered(peer.index, now)
            peer.told = False
            retry.leave_one_attempt()  # this answer only
            debts = self._debts
            delay = debts.cue_delay(self.sought_by.omitted(peer.index))
            # as a multicast (engine._answer_seek): the drones that held their seek back for
            # this one's hear it too (seek.Seek.heard assumes so); the debt falls due with it
            at = self._answer_seek(now, delay)
            debts.arm(peer, now + delay if at is None else at)
            if at is not None:
                # and directed a re-ack gap on if it still does not list us
                # (Debts.defer_found_again): at the edge of range the group frame, sent
                # once and unacknowledged, is the one lost, and the spacing holds our next
                # answer 1 s, past a window of 1-1.5 s (the fade at N = 10, run 3: 2.25 s;
                # docs/benchmarks.md, "Where it stands (session 13)")
                debts.found_again.add(peer.index)
            return
        elif (
            not lists_me
            and told
            and peer.told_at is not None
            and now - peer.told_at > self._debts.answer_window()
        ):
            # it still does not list us although it would have answered our last frame by
            # now: that frame was lost. Answer now instead of waiting out the backoff.
            told = peer.told = False
        if told and lists_me:  # Debts.owes(peer) for a discovered peer: the usual case
            if retry.due is not None or retry.attempts:
                self._debts.disarm(peer)
        elif not told or retry.due is None:
            # first answer after a holdoff; a peer we already told and are waiting on keeps
            # its backoff, since its frame may simply have crossed ours in flight
            debts = self._debts
            if stopped_listing and not restarted and peer.reack.permits(now):
                # A peer whose last frame listed us sends one that does not: it lost us (a
                # lease that ended, its DATA(p) after the loss: pullin.PullIn.lease_ended)
                # and we hear it, so the link is back now. Answer within the rejoin delay,
                # as for a rejoin, not after the Q-stretched holdoff U(W, 2W): issue 20's
                # fade gives a pair ~1.5 s in range, and the holdoff (0.3-0.6 s at N = 10,
                # up to 1.6 s at N = 20) let the window close first. Once per re-ack gap
                # (the MinInterval of the repeat and probe rules): a peer flipping its bit
                # cannot make us answer promptly more often than that.
                peer.reack.mark(now)
                rejoin = True
            delay = debts.rejoin_delay() if rejoin else debts.reply_delay()
            debts.arm(peer, now + delay)

    def _on_disposed(self, sample: SpdpDisposed, source: tuple[str, int], now: float) -> None:
        if sample.destination is not None and sample.destination != self._my_guid:
            self._drop(DropReason.NOT_FOR_ME, source)
            return
        peer = self.peer_by_prefix(sample.guid_prefix.value)
        if peer is None:
            self._foreign.disposed(sample.guid_prefix)
            return
        if peer.discovered:
            self._disposed_at[peer.index] = now  # its return waits (RESTART_MIN_INTERVAL_S)
            self._lose(peer, "disposed")

    def _see_foreign(self, alive: Alive, reason: DropReason, now: float) -> None:
        event = self._foreign.see(alive.sample.participant, reason, now)
        if event is not None:
            self._emit(event)

    def _drop(self, reason: DropReason, source: tuple[str, int]) -> None:
        self.dropped[reason] += 1
        self._emit(PacketDropped(reason, source))
