"""An event-driven 802.11 DCF channel: who transmits when, and who receives what.

Theory of operation
===================

Each node has a MAC queue of datagrams (one datagram = one MPDU; nothing is fragmented).
The head of a non-empty queue contends for the medium with the DCF (IEEE 802.11-2016
10.3): a backoff of U{0..CW} slots that counts down only while the node has sensed the
medium idle for DIFS, and freezes while it is busy. The node whose countdown ends first
transmits; every other node whose countdown ends within ``CCA_WINDOW_S`` of it cannot have
sensed it yet and transmits too: that is a collision. Nodes out of carrier-sense range of a
sender keep counting (hidden terminals) and may overlap it as well.

Instead of ticking slots, the channel keeps per-node arrays (numpy): ``busy`` (how many
transmissions the node senses), ``bo`` (remaining slots), ``resume`` (when the countdown
restarts) and ``cont`` (whether it contends). The next access is one ``argmin`` of
``resume + bo * SLOT`` over idle contenders, and a transmission start/end updates the
column of nodes that sense the sender. No per-slot events, nothing O(N^2) per frame.

Reception of frame f at node j is decided when f ends, over every transmission that
overlapped it in time:

* j was transmitting during f (half-duplex) -> lost;
* j sensed another frame that started before f (it was synchronised to that one; like
  ns-3, no frame capture) -> lost;
* otherwise SINR = P(f) / (noise + sum of overlapping powers) -> PER(SINR, size, rate)
  (``phy.per``) -> one random draw.

Multicast goes at the basic rate, once, with no ACK. Unicast goes at the link's rate and
is acknowledged: the receiver answers after SIFS with an ACK (itself a transmission that can
collide); a sender that hears no ACK within the ACK timeout doubles CW and retries, up to
``retry_limit`` retransmissions, then drops the frame (a PHY drop in the paper's Table 2).
A full queue drops new datagrams and a datagram older than ``queue_max_delay_s`` when it
reaches the head is dropped (MAC drops; ns-3 WifiMacQueue MaxSize 500p / MaxDelay 500 ms).
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Final

import numpy as np
import numpy.typing as npt

from swarmd_lab.sim.clock import Timer, VirtualClock
from swarmd_lab.sim.phy import (
    ACK_BYTES,
    CCA_WINDOW_S,
    CW_MAX,
    CW_MIN,
    DIFS_S,
    MAX_UDP_PAYLOAD,
    PER_SLOPE_DB,
    RATES_MBPS,
    SIFS_S,
    SLOT_S,
    SNR10_DB,
    UDP_FRAME_OVERHEAD,
    FloatArray,
    Radio,
    ack_rate_mbps,
    ack_timeout_s,
    airtime_s,
    min_snr_db,
    per,
)

BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.int64]

MULTICAST: Final = -1
_EPS: Final = 1e-12


class Kind(IntEnum):
    """What a frame carries; ACKs are counted with the kind of the frame they acknowledge."""

    DISCOVERY = 0
    DATA = 1


@dataclass(slots=True)
class Datagram:
    """One UDP (or TCP segment) payload handed to the MAC. ``dst`` = ``MULTICAST`` or a node."""

    src: int
    dst: int
    size: int  # transport payload bytes
    kind: Kind
    payload: object = None
    port: int = 0
    overhead: int = UDP_FRAME_OVERHEAD  # MAC + LLC + IP + transport header bytes

    @property
    def mpdu_bytes(self) -> int:
        return self.size + self.overhead


@dataclass(frozen=True, slots=True)
class ChannelConfig:
    """MAC/PHY parameters; defaults are 802.11g with ns-3's defaults (docs/simulator.md)."""

    radio: Radio = field(default_factory=Radio)
    basic_rate_mbps: int = 6
    # None: per-link ideal rate from the link SNR (ns-3 IdealWifiManager); else a fixed rate
    unicast_rate_mbps: int | None = None
    queue_limit: int = 500
    queue_max_delay_s: float = 0.5
    retry_limit: int = 7
    cw_min: int = CW_MIN
    cw_max: int = CW_MAX
    # a station defers to any frame it can detect (ns-3 RxSensitivity -101 dBm)
    cs_threshold_dbm: float = -101.0
    bin_s: float = 1.0


@dataclass(slots=True)
class Counters:
    """The paper's Table 2 counters, summed over nodes, plus per-second frame bins."""

    mac_enqueued: int = 0
    mac_tx: int = 0  # MAC transmission attempts (initial + retransmissions), ACKs excluded
    mac_drop_overflow: int = 0
    mac_drop_expired: int = 0
    phy_tx: int = 0  # every PPDU on the air, ACKs included
    phy_retx: int = 0
    phy_rx: int = 0  # successful receptions (per receiver)
    phy_rx_fail_collision: int = 0
    phy_rx_fail_error: int = 0
    phy_drop_retry: int = 0  # unicast frames given up after the retry limit
    collisions: int = 0  # transmissions that started while another was on the air
    tx_by_kind: list[int] = field(default_factory=lambda: [0, 0])
    # transport payload bytes of those frames (retries included): what the authenticator adds
    tx_bytes_by_kind: list[int] = field(default_factory=lambda: [0, 0])
    ack_by_kind: list[int] = field(default_factory=lambda: [0, 0])
    bins: list[list[int]] = field(default_factory=lambda: [[], []])

    def count_tx(self, kind: Kind, t: float, bin_s: float) -> None:
        b = int(t / bin_s)
        bins = self.bins[kind]
        if b >= len(bins):
            bins.extend([0] * (b + 1 - len(bins)))
        bins[b] += 1


class _Frame:
    __slots__ = ("dgram", "enqueued", "retries", "delivered", "mpdu", "rate")

    def __init__(self, dgram: Datagram, enqueued: float, rate: int) -> None:
        self.dgram = dgram
        self.enqueued = enqueued
        self.retries = 0
        self.delivered = False
        self.mpdu = dgram.mpdu_bytes
        self.rate = rate


class _Tx:
    __slots__ = ("sender", "start", "end", "frame", "ack_of", "overlaps", "rate", "mpdu")

    def __init__(
        self, sender: int, start: float, end: float, frame: _Frame | None, ack_of: _Frame | None
    ) -> None:
        self.sender = sender
        self.start = start
        self.end = end
        self.frame = frame  # the data frame carried, None for an ACK
        self.ack_of = ack_of  # the data frame this ACK acknowledges
        self.overlaps: list[_Tx] = []
        if frame is not None:
            self.rate, self.mpdu = frame.rate, frame.mpdu
        else:
            assert ack_of is not None  # noqa: S101 - internal invariant
            self.rate, self.mpdu = ack_rate_mbps(ack_of.rate), ACK_BYTES


Deliver = Callable[[int, Datagram, float], None]
# one multicast handed to every node that decoded it, in this order (one Python call per
# frame instead of one per receiver: a 1000-drone run has ~3M receptions)
DeliverMany = Callable[[list[int], Datagram, float], None]

_IDLE, _CONTEND, _TX, _WAIT_ACK = 0, 1, 2, 3


class Channel:
    """The shared medium of ``n`` nodes at ``positions`` (metres, shape (n, 2))."""

    def __init__(
        self,
        clock: VirtualClock,
        positions: FloatArray,
        config: ChannelConfig,
        *,
        seed: int,
        deliver: Deliver,
        deliver_many: DeliverMany | None = None,
    ) -> None:
        """``deliver(j, dgram, now)``: node ``j`` decoded ``dgram``. ``deliver_many``, if
        given, takes a multicast's receivers at once (same order, same effect as calling
        ``deliver`` for each)."""
        self.clock = clock
        self.config = config
        self.n = n = len(positions)
        self._deliver = deliver
        self._deliver_many = deliver_many
        self._rng = random.Random(f"channel/{seed}")  # noqa: S311 - seeded simulation
        self._np_rng = np.random.default_rng([seed, 0x5157])
        radio = config.radio
        diff = positions[:, None, :] - positions[None, :, :]
        dist = np.sqrt((diff**2).sum(axis=-1))
        rx_dbm = radio.rx_power_dbm(dist)
        np.fill_diagonal(rx_dbm, np.inf)
        # receiver-major matrices: [receiver, sender]
        self.snr_db: FloatArray = rx_dbm - radio.noise_floor_dbm
        self._rx_mw: FloatArray = np.where(np.isinf(rx_dbm), 0.0, 10.0 ** (rx_dbm / 10.0))
        self._noise_mw = 10.0 ** (radio.noise_floor_dbm / 10.0)
        self._in_cs: BoolArray = rx_dbm >= config.cs_threshold_dbm  # diagonal: self-busy
        # sender-major copies: the column of nodes that sense sender s, contiguous
        self._cs_by_sender: BoolArray = np.ascontiguousarray(self._in_cs.T)
        self._cs_by_sender_int: IntArray = self._cs_by_sender.astype(np.int64)
        reach = self.snr_db >= radio.min_snr_db
        np.fill_diagonal(reach, False)
        self._reach_idx: list[IntArray] = [np.flatnonzero(reach[:, s]) for s in range(n)]
        self._rate: list[list[int]] = self._link_rates()
        self._airtime: dict[tuple[int, int], float] = {}
        self._per_scalar_cache: dict[tuple[int, int], float] = {}
        # DCF state
        self._busy = np.zeros(n, dtype=np.int64)
        self._cont = np.zeros(n, dtype=np.bool_)
        self._bo = np.zeros(n, dtype=np.float64)
        self._resume = np.zeros(n, dtype=np.float64)
        self._last_idle = np.full(n, -math.inf)
        self._state = [_IDLE] * n
        self._cw = [config.cw_min] * n
        self._queues: list[deque[_Frame]] = [deque() for _ in range(n)]
        self._ack_timer: list[Timer | None] = [None] * n
        self._active: list[_Tx] = []
        self._next_access: tuple[float, int] | None = None
        self._dirty = True
        self.counters = Counters()

    # ------------------------------------------------------------- set-up

    def _link_rates(self) -> list[list[int]]:
        fixed = self.config.unicast_rate_mbps
        if fixed is not None:
            if fixed not in SNR10_DB:
                raise ValueError(f"unicast rate {fixed} Mb/s is not an ERP-OFDM rate")
            return [[fixed] * self.n for _ in range(self.n)]
        # rate[s][d]: the ideal rate for the SNR at d of s's signal (snr_db is [rx, tx])
        rates = np.full((self.n, self.n), RATES_MBPS[0], dtype=np.int64)
        snr_tx_rx = self.snr_db.T
        for rate in RATES_MBPS:
            rates[snr_tx_rx >= min_snr_db(rate)] = rate
        return [list(map(int, row)) for row in rates]

    def link_rate(self, src: int, dst: int) -> int:
        return self._rate[src][dst]

    # ----------------------------------------------------------- sending

    def send(self, dgram: Datagram) -> None:
        """Queue ``dgram`` at its source's MAC (a MAC drop if the queue is full)."""
        if dgram.size > MAX_UDP_PAYLOAD:
            raise ValueError(
                f"datagram of {dgram.size} B exceeds {MAX_UDP_PAYLOAD} B; the simulator "
                "does not fragment"
            )
        now = self.clock.now
        s = dgram.src
        q = self._queues[s]
        c = self.counters
        c.mac_enqueued += 1
        if len(q) >= self.config.queue_limit:
            self._purge_expired(s, now)
            if len(q) >= self.config.queue_limit:
                c.mac_drop_overflow += 1
                return
        rate = self.config.basic_rate_mbps if dgram.dst == MULTICAST else self._rate[s][dgram.dst]
        q.append(_Frame(dgram, now, rate))
        if self._state[s] == _IDLE:
            self._contend(s, now, new_backoff=True)

    def queue_length(self, node: int) -> int:
        return len(self._queues[node])

    def _purge_expired(self, s: int, now: float) -> None:
        q = self._queues[s]
        keep_head = self._state[s] in (_TX, _WAIT_ACK)
        head = q.popleft() if keep_head and q else None
        limit = self.config.queue_max_delay_s
        while q and now - q[0].enqueued > limit:
            q.popleft()
            self.counters.mac_drop_expired += 1
        if head is not None:
            q.appendleft(head)

    # ----------------------------------------------------------- DCF

    def _contend(self, s: int, now: float, *, new_backoff: bool) -> None:
        if not self._queues[s]:
            self._state[s] = _IDLE
            self._cont[s] = False
            self._dirty = True
            return
        self._state[s] = _CONTEND
        if new_backoff:
            self._bo[s] = self._rng.randint(0, self._cw[s])
        self._cont[s] = True
        if self._busy[s] == 0:
            self._resume[s] = max(now, self._last_idle[s] + DIFS_S)
        self._dirty = True

    def next_access(self) -> float | None:
        """When the next backoff countdown ends, or None if nobody contends."""
        if self._dirty:
            self._dirty = False
            mask = self._cont & (self._busy == 0)
            if not mask.any():
                self._next_access = None
            else:
                tx_at = np.where(mask, self._resume + self._bo * SLOT_S, np.inf)
                i = int(np.argmin(tx_at))
                self._next_access = (float(tx_at[i]), i)
        return None if self._next_access is None else self._next_access[0]

    def access(self) -> None:
        """Start every transmission whose backoff ends now (within the CCA window)."""
        if self.next_access() is None:
            return
        assert self._next_access is not None  # noqa: S101 - set by next_access
        t = self._next_access[0]
        self.clock.now = max(self.clock.now, t)
        mask = self._cont & (self._busy == 0)
        tx_at = np.where(mask, self._resume + self._bo * SLOT_S, np.inf)
        starters = [int(i) for i in np.flatnonzero(tx_at <= t + CCA_WINDOW_S)]
        now = t
        for s in starters:
            self._cont[s] = False
            self._bo[s] = 0
        self._dirty = True
        for s in starters:
            frame = self._head_for_tx(s, now)
            if frame is None:
                continue
            self._state[s] = _TX
            self._start_tx(s, now, frame, None)

    def _head_for_tx(self, s: int, now: float) -> _Frame | None:
        q = self._queues[s]
        limit = self.config.queue_max_delay_s
        while q and q[0].retries == 0 and now - q[0].enqueued > limit:
            q.popleft()
            self.counters.mac_drop_expired += 1
        if not q:
            self._state[s] = _IDLE
            return None
        return q[0]

    def _start_tx(self, s: int, now: float, frame: _Frame | None, ack_of: _Frame | None) -> None:
        tx = _Tx(s, now, now, frame, ack_of)
        key = (tx.mpdu, tx.rate)
        dur = self._airtime.get(key)
        if dur is None:
            dur = self._airtime[key] = airtime_s(tx.mpdu, tx.rate)
        tx.end = now + dur
        in_cs_s = self._cs_by_sender[s]
        for other in self._active:
            other.overlaps.append(tx)
            tx.overlaps.append(other)
            self.counters.collisions += 1
        self._active.append(tx)
        # freeze the countdown of contenders that now sense the medium busy
        newly = in_cs_s & (self._busy == 0) & self._cont
        if newly.any():
            idx = np.flatnonzero(newly)
            consumed = np.floor(np.maximum(now - self._resume[idx], 0.0) / SLOT_S + _EPS)
            self._bo[idx] = np.maximum(self._bo[idx] - consumed, 0.0)
        self._busy += self._cs_by_sender_int[s]
        self._dirty = True
        c = self.counters
        c.phy_tx += 1
        bin_s = self.config.bin_s
        if frame is not None:
            kind = frame.dgram.kind
            c.mac_tx += 1
            c.tx_by_kind[kind] += 1
            c.tx_bytes_by_kind[kind] += frame.dgram.size
            if frame.retries:
                c.phy_retx += 1
        else:
            assert ack_of is not None  # noqa: S101
            kind = ack_of.dgram.kind
            c.ack_by_kind[kind] += 1
        c.count_tx(kind, now, bin_s)
        self.clock.call_at(tx.end, lambda: self._end_tx(tx))

    def _end_tx(self, tx: _Tx) -> None:
        now = tx.end
        self._active.remove(tx)
        s = tx.sender
        col = self._cs_by_sender_int[s]
        self._busy -= col
        went_idle = (col > 0) & (self._busy == 0)
        if went_idle.any():
            self._last_idle[went_idle] = now
            self._resume[went_idle] = now + DIFS_S
        self._dirty = True
        if tx.ack_of is not None:
            self._end_ack(tx, now)
        else:
            assert tx.frame is not None  # noqa: S101
            if tx.frame.dgram.dst == MULTICAST:
                self._end_multicast(tx, now)
            else:
                self._end_unicast(tx, now)

    # ------------------------------------------------------------ reception

    def _received(self, tx: _Tx, j: int) -> tuple[bool, bool]:
        """(received, collided) for one receiver ``j`` of ``tx``."""
        interference = 0.0
        collided = False
        for o in tx.overlaps:
            if o.sender == j:
                return False, True
            if o.start < tx.start and self._in_cs[j, o.sender]:
                return False, True
            p = self._rx_mw[j, o.sender]
            if self._in_cs[j, o.sender]:
                collided = True
            interference += p
        if interference == 0.0:
            p_err = self._per_scalar(tx, j)
        else:
            sinr = self._rx_mw[j, tx.sender] / (self._noise_mw + interference)
            p_err = float(per(10.0 * math.log10(max(sinr, 1e-30)), tx.mpdu, tx.rate))
        return self._rng.random() >= p_err, collided

    def _per_scalar(self, tx: _Tx, j: int) -> float:
        snr = float(self.snr_db[j, tx.sender])
        snr50 = SNR10_DB[tx.rate] - PER_SLOPE_DB * math.log(9.0)
        x = max(-50.0, min(50.0, (snr - snr50) / PER_SLOPE_DB))
        per_ref = 1.0 / (1.0 + math.exp(x))
        return float(1.0 - (1.0 - per_ref) ** (tx.mpdu / 1000.0))

    def _end_multicast(self, tx: _Tx, now: float) -> None:
        frame = tx.frame
        assert frame is not None  # noqa: S101
        s = tx.sender
        cand = self._reach_idx[s]
        c = self.counters
        if len(cand):
            snr = self.snr_db[cand, s]
            lost = np.zeros(len(cand), dtype=np.bool_)
            collided = np.zeros(len(cand), dtype=np.bool_)
            if tx.overlaps:
                interference = np.zeros(len(cand))
                for o in tx.overlaps:
                    hears = self._in_cs[cand, o.sender]
                    lost |= cand == o.sender
                    if o.start < tx.start:
                        lost |= hears
                    collided |= hears | (cand == o.sender)
                    interference += self._rx_mw[cand, o.sender]
                sinr = self._rx_mw[cand, s] / (self._noise_mw + interference)
                snr = 10.0 * np.log10(np.maximum(sinr, 1e-30))
            p_err = per(snr, tx.mpdu, tx.rate)
            ok = (self._np_rng.random(len(cand)) >= p_err) & ~lost
            n_ok = int(ok.sum())
            c.phy_rx += n_ok
            fails = ~ok
            c.phy_rx_fail_collision += int((fails & collided).sum())
            c.phy_rx_fail_error += int((fails & ~collided).sum())
            receivers = cand[ok].tolist()
        else:
            receivers = []
        self._finish(s, now)
        dgram = frame.dgram
        if self._deliver_many is not None:
            if receivers:
                self._deliver_many(receivers, dgram, now)
            return
        for j in receivers:
            self._deliver(j, dgram, now)

    def _end_unicast(self, tx: _Tx, now: float) -> None:
        frame = tx.frame
        assert frame is not None  # noqa: S101
        s, d = tx.sender, frame.dgram.dst
        ok, collided = self._received(tx, d)
        self._state[s] = _WAIT_ACK
        timeout = ack_timeout_s(frame.rate)
        self._ack_timer[s] = self.clock.call_at(now + timeout, lambda: self._ack_timeout(s))
        if not self._count_reception(ok, collided):
            return
        self.clock.call_at(now + SIFS_S, lambda: self._start_tx(d, self.clock.now, None, frame))
        if not frame.delivered:
            # a retransmission whose ACK was lost arrives twice; the MAC filters duplicates
            frame.delivered = True
            self._deliver(d, frame.dgram, now)

    def _count_reception(self, ok: bool, collided: bool) -> bool:
        """Count one unicast frame (DATA or ACK) at its receiver's PHY: received, or lost to
        a collision or to the channel's error; whether it was received."""
        c = self.counters
        if ok:
            c.phy_rx += 1
        elif collided:
            c.phy_rx_fail_collision += 1
        else:
            c.phy_rx_fail_error += 1
        return ok

    def _end_ack(self, tx: _Tx, now: float) -> None:
        frame = tx.ack_of
        assert frame is not None  # noqa: S101
        s = frame.dgram.src
        if not self._count_reception(*self._received(tx, s)):
            return
        timer = self._ack_timer[s]
        if timer is None or self._state[s] != _WAIT_ACK or not self._queues[s]:
            return
        if self._queues[s][0] is not frame:
            return
        timer.cancel()
        self._ack_timer[s] = None
        self._finish(s, now)

    def _ack_timeout(self, s: int) -> None:
        now = self.clock.now
        self._ack_timer[s] = None
        q = self._queues[s]
        frame = q[0]
        if frame.retries >= self.config.retry_limit:
            self.counters.phy_drop_retry += 1
            self._finish(s, now)
            return
        frame.retries += 1
        self._cw[s] = min(2 * self._cw[s] + 1, self.config.cw_max)
        self._contend(s, now, new_backoff=True)

    def _finish(self, s: int, now: float) -> None:
        """The head frame is done (sent, acknowledged or given up): next one, new backoff."""
        q = self._queues[s]
        if q:
            q.popleft()
        self._cw[s] = self.config.cw_min
        self._contend(s, now, new_backoff=True)
