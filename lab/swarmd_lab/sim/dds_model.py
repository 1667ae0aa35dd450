"""Stock DDS discovery at frame level: SPDP + reliable SEDP, with Fast DDS's or Cyclone's timing.

Frame-level means each datagram is a small Python tuple with the size the real one would
have on the wire; nothing is encoded. What the model keeps from the real protocols
(``shared/reference/rtps-and-baselines.md`` section numbers in brackets):

* SPDP DATA(p) to the multicast group: ``initial_count`` times ``initial_period_s`` apart at
  start, then every ``announce_period_s`` [2.1, 2.2]. A participant heard for the first time
  is answered with ``directed_replies`` unicast DATA(p), ``directed_period_s`` apart
  (Fast DDS: once; Cyclone: 4 at 1 s [1.12]). A participant silent for its lease is lost.
* SEDP [2.1]: once a participant is known, each of our two SEDP writers (publications:
  one DATA(w) per local writer; subscriptions: one DATA(r) per local reader) sends its whole
  TRANSIENT_LOCAL history to the peer's SEDP reader, unicast, packed into datagrams up to
  the MTU with a HEARTBEAT piggybacked on the last. Our SEDP readers send a pre-emptive
  ACKNACK to the peer's writers. A reader answers a HEARTBEAT with an ACKNACK after
  ``hb_response_delay_s`` listing what it misses; a writer resends what is NACKed after
  ``nack_response_delay_s`` and repeats HEARTBEATs every ``hb_period_s`` (Cyclone: doubling
  up to ``hb_period_max_s`` while nothing is acknowledged) until everything is ACKed.
* A reader ignores SEDP traffic from a participant it has not discovered through SPDP
  (RTPS matches builtin endpoints from SPDP; unmatched writers are dropped): that is what
  makes SEDP retransmissions necessary when DATA(p) is lost.
* ROS 2 nodes carry more endpoints than the one topic: rosout, parameter events and six
  parameter services per node (``ros2_writers``/``ros2_readers``) [2.4].

Not modelled (docs/simulator.md): the WLP/participant-message and TypeLookup endpoints,
GAP submessages, Cyclone's 100 ms second SPDP send, socket back-pressure.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from swarmd_lab.sim.channel import MULTICAST, Datagram, Kind
from swarmd_lab.sim.node import NodeContext, SimNode
from swarmd_lab.sim.phy import MAX_UDP_PAYLOAD

PUB, SUB = 0, 1  # SEDP publications (DATA(w)) and subscriptions (DATA(r)) channels

# RTPS header 20 + INFO_DST 16 + HEARTBEAT 32 (28-byte body) [1.3]
HEARTBEAT_BYTES: Final = 68
# RTPS header 20 + INFO_DST 16 + ACKNACK with a one-word bitmap 32 [1.3]
ACKNACK_BYTES: Final = 68
# a HEARTBEAT piggybacked on a DATA datagram (no second RTPS header)
PIGGYBACK_HB_BYTES: Final = 32
# per DATA submessage inside a packed datagram: submessage header and DATA header
DATA_SUBMESSAGE_OVERHEAD: Final = 24
RTPS_PREFIX_BYTES: Final = 20 + 16 + 12  # header + INFO_DST + INFO_TS


@dataclass(frozen=True, slots=True)
class DdsTiming:
    """One stock implementation's discovery defaults."""

    name: str
    lease_s: float
    initial_count: int
    initial_period_s: float
    announce_period_s: float
    directed_replies: int
    directed_period_s: float
    spdp_bytes: int
    sedp_sample_bytes: int
    hb_period_s: float
    hb_period_max_s: float
    nack_response_delay_s: float
    hb_response_delay_s: float
    ros2_writers: int = 8  # rosout, parameter_events, 6 parameter-service replies
    ros2_readers: int = 7  # parameter_events, 6 parameter-service requests
    lease_check_s: float = 1.0


# Fast DDS 2.x/3.x defaults [2.1]: 5 x 100 ms, then 3 s; lease 20 s; DATA(p) once to a new
# participant; EDP heartbeat 1 s, nack response delay 100 ms; reader heartbeat response
# delay 5 ms (ReaderTimes). DATA(p) ~ 450 B with ROS 2 properties; DATA(w)/(r) ~ 400 B.
FASTDDS: Final = DdsTiming(
    name="fastdds-model",
    lease_s=20.0,
    initial_count=5,
    initial_period_s=0.1,
    announce_period_s=3.0,
    directed_replies=1,
    directed_period_s=0.0,
    spdp_bytes=450,
    sedp_sample_bytes=400,
    hb_period_s=1.0,
    hb_period_max_s=1.0,
    nack_response_delay_s=0.1,
    hb_response_delay_s=0.005,
)

# Cyclone DDS 0.10 defaults [2.2, 1.12, 1.13]: SPDP at creation then every 8 s (lease 10 s),
# 4 directed replies at 1 s to a new participant; DATA(p) 406-434 B (captured); heartbeat
# 100 ms growing to 8 s while unacknowledged; NackDelay 100 ms; AckDelay 10 ms.
CYCLONE: Final = DdsTiming(
    name="cyclone-model",
    lease_s=10.0,
    initial_count=1,
    initial_period_s=0.0,
    announce_period_s=8.0,
    directed_replies=4,
    directed_period_s=1.0,
    spdp_bytes=420,
    sedp_sample_bytes=380,
    hb_period_s=0.1,
    hb_period_max_s=8.0,
    nack_response_delay_s=0.1,
    hb_response_delay_s=0.01,
)


class _Writer:
    """Our SEDP writer on one channel towards one peer's reader."""

    __slots__ = ("unacked", "hb_period", "hb_due", "resend_due")

    def __init__(self, samples: int, hb_period: float) -> None:
        self.unacked: set[int] = set(range(1, samples + 1))
        self.hb_period = hb_period
        self.hb_due: float | None = None
        self.resend_due = False


class _Reader:
    """Our SEDP reader on one channel, receiving one peer's writer."""

    __slots__ = ("received", "last", "ack_due")

    def __init__(self) -> None:
        self.received: set[int] = set()
        self.last: int | None = None  # the writer's last SN, from a HEARTBEAT
        self.ack_due = False

    def complete(self) -> bool:
        return self.last is not None and len(self.received) >= self.last

    def ack_state(self) -> tuple[int, tuple[int, ...]]:
        """ACKNACK readerSNState: (base, missing) - everything below base except missing is
        acknowledged; before any HEARTBEAT it is (1, ()), the pre-emptive ACKNACK [1.3]."""
        if self.last is None:
            return 1, ()
        missing = tuple(sn for sn in range(1, self.last + 1) if sn not in self.received)
        return (missing[0] if missing else self.last + 1), missing


class _Peer:
    __slots__ = ("last_heard", "lease_s", "writers", "readers", "matched")

    def __init__(self, now: float, lease_s: float) -> None:
        self.last_heard = now
        self.lease_s = lease_s
        self.writers: list[_Writer] = []
        self.readers: list[_Reader] = [_Reader(), _Reader()]
        self.matched = False


class DdsNode(SimNode):
    """One ROS 2 participant with stock SPDP/SEDP discovery at ``timing``."""

    def __init__(self, ctx: NodeContext, timing: DdsTiming, *, writers: int, readers: int) -> None:
        super().__init__(ctx)
        self.t = timing
        self._samples = (writers + timing.ros2_writers, readers + timing.ros2_readers)
        self._peers: dict[int, _Peer] = {}
        self._started = False

    # ------------------------------------------------------------ helpers

    def _at(self, at: float, fn: Callable[[], None]) -> None:
        self.ctx.clock.call_at(at, fn)

    def _send(self, dst: int, size: int, payload: tuple[object, ...]) -> None:
        self.ctx.send(Datagram(self.index, dst, size, Kind.DISCOVERY, payload))

    # -------------------------------------------------------------- SPDP

    def start(self, now: float) -> None:
        self._started = True
        t = self.t
        for k in range(t.initial_count):
            self._at(now + k * t.initial_period_s, self._announce_once)
        first_periodic = now + (t.initial_count - 1) * t.initial_period_s + t.announce_period_s
        self._at(first_periodic, self._announce_periodic)
        self._at(now + t.lease_check_s, self._check_leases)

    def _announce_once(self) -> None:
        self._send(MULTICAST, self.t.spdp_bytes, ("spdp",))

    def _announce_periodic(self) -> None:
        self._announce_once()
        self._at(self.ctx.clock.now + self.t.announce_period_s, self._announce_periodic)

    def _check_leases(self) -> None:
        now = self.ctx.clock.now
        for p in [p for p, peer in self._peers.items() if now - peer.last_heard > peer.lease_s]:
            del self._peers[p]
            self.ctx.ledger.lost(self.index, p, now)
        self._at(now + self.t.lease_check_s, self._check_leases)

    def receive(self, dgram: Datagram, now: float) -> None:
        if not self._started:
            return
        msg = dgram.payload
        assert isinstance(msg, tuple)  # noqa: S101 - the model's own messages
        kind = msg[0]
        src = dgram.src
        if kind == "spdp":
            self._on_spdp(src, now)
            return
        peer = self._peers.get(src)
        if peer is None:
            return  # SEDP from a participant we have not discovered: unmatched, dropped
        peer.last_heard = now  # any RTPS traffic from a participant renews its lease
        if kind == "data":
            _, channel, sns, hb_last = msg
            reader = peer.readers[channel]
            reader.received.update(sns)
            if hb_last is not None:
                self._on_heartbeat(src, peer, channel, hb_last)
            self._check_matched(src, peer, now)
        elif kind == "hb":
            _, channel, last = msg
            self._on_heartbeat(src, peer, channel, last)
        elif kind == "acknack":
            _, channel, base, missing = msg
            self._on_acknack(src, peer, channel, base, missing)

    def _on_spdp(self, src: int, now: float) -> None:
        peer = self._peers.get(src)
        if peer is not None:
            peer.last_heard = now
            return
        peer = self._peers[src] = _Peer(now, self.t.lease_s)
        t = self.t
        for k in range(t.directed_replies):
            self._at(now + k * t.directed_period_s, lambda: self._directed(src))
        # SEDP: our writers' whole history to its readers, our readers pre-emptively NACK
        peer.writers = [_Writer(self._samples[c], t.hb_period_s) for c in (PUB, SUB)]
        for c in (PUB, SUB):
            self._send_samples(src, c, sorted(peer.writers[c].unacked))
            self._arm_heartbeat(src, peer, c, now)
            self._send(src, ACKNACK_BYTES, ("acknack", c, 1, ()))

    def _directed(self, dst: int) -> None:
        if dst in self._peers:
            self._send(dst, self.t.spdp_bytes, ("spdp",))

    # -------------------------------------------------------------- SEDP

    def _send_samples(self, dst: int, channel: int, sns: list[int]) -> None:
        per_sample = self.t.sedp_sample_bytes + DATA_SUBMESSAGE_OVERHEAD
        room = MAX_UDP_PAYLOAD - RTPS_PREFIX_BYTES - PIGGYBACK_HB_BYTES
        per_dgram = max(1, room // per_sample)
        last = self._samples[channel]
        for i in range(0, len(sns), per_dgram):
            chunk = tuple(sns[i : i + per_dgram])
            final = i + per_dgram >= len(sns)
            size = RTPS_PREFIX_BYTES + len(chunk) * per_sample
            if final:
                size += PIGGYBACK_HB_BYTES
            self._send(dst, size, ("data", channel, chunk, last if final else None))

    def _arm_heartbeat(self, dst: int, peer: _Peer, channel: int, now: float) -> None:
        w = peer.writers[channel]
        if w.hb_due is not None:
            return
        w.hb_due = now + w.hb_period
        self._at(w.hb_due, lambda: self._heartbeat(dst, channel))

    def _heartbeat(self, dst: int, channel: int) -> None:
        peer = self._peers.get(dst)
        if peer is None or not peer.writers:
            return
        w = peer.writers[channel]
        w.hb_due = None
        if not w.unacked:
            return
        self._send(dst, HEARTBEAT_BYTES, ("hb", channel, self._samples[channel]))
        w.hb_period = min(w.hb_period * 2.0, self.t.hb_period_max_s)
        self._arm_heartbeat(dst, peer, channel, self.ctx.clock.now)

    def _on_heartbeat(self, src: int, peer: _Peer, channel: int, last: int) -> None:
        reader = peer.readers[channel]
        reader.last = last
        if reader.ack_due:
            return
        reader.ack_due = True
        self._at(
            self.ctx.clock.now + self.t.hb_response_delay_s, lambda: self._acknack(src, channel)
        )

    def _acknack(self, dst: int, channel: int) -> None:
        peer = self._peers.get(dst)
        if peer is None:
            return
        reader = peer.readers[channel]
        reader.ack_due = False
        base, missing = reader.ack_state()
        self._send(dst, ACKNACK_BYTES, ("acknack", channel, base, missing))

    def _on_acknack(
        self, src: int, peer: _Peer, channel: int, base: int, missing: tuple[int, ...]
    ) -> None:
        if not peer.writers:
            return
        w = peer.writers[channel]
        requested = set(missing)
        w.unacked = {sn for sn in w.unacked if sn >= base or sn in requested}
        if not w.unacked:
            w.hb_period = self.t.hb_period_s
            return
        if not missing:
            return
        if w.resend_due:
            return
        w.resend_due = True
        self._at(
            self.ctx.clock.now + self.t.nack_response_delay_s, lambda: self._resend(src, channel)
        )

    def _resend(self, dst: int, channel: int) -> None:
        peer = self._peers.get(dst)
        if peer is None or not peer.writers:
            return
        w = peer.writers[channel]
        w.resend_due = False
        if w.unacked:
            self._send_samples(dst, channel, sorted(w.unacked))
            self._arm_heartbeat(dst, peer, channel, self.ctx.clock.now)

    def _check_matched(self, src: int, peer: _Peer, now: float) -> None:
        if not peer.matched and all(r.complete() for r in peer.readers):
            peer.matched = True
            self.ctx.ledger.discovered(self.index, src, now)
