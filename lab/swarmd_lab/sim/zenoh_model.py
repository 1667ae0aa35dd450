"""zenoh peer-mode discovery at frame level: multicast scouting, then one TCP session per pair.

From ``shared/reference/rtps-and-baselines.md`` section 3 (zenoh 1.x defaults):

* SCOUT to 224.0.0.224:7446 at start, then after 1, 2, 4, 8, 8, ... s (the orchestrator's
  scout period starts at 1 s, doubles, caps at 8 s); every peer answers a SCOUT with a
  unicast HELLO (``scouting.multicast.listen``).
* A HELLO from a peer without a session makes us open one (``autoconnect.peer`` and
  ``to_peer: always``, so both sides may open; the model merges two crossing opens into one):
  TCP SYN/SYN-ACK/ACK, then InitSyn/InitAck/OpenSyn/OpenAck, each request retransmitted on
  TCP's timeout (1 s for SYN, 200 ms doubling after) until answered.
* An open session carries each side's declarations (subscriber, publisher, liveliness token)
  and a gossip message, and each side gossips the new peer to its other open sessions; every
  segment is acknowledged by TCP; keep-alives every lease/4 = 2.5 s in each
  direction; a session silent for the 10 s lease closes.

The pair (i, j) counts as discovered at i once i's session to j is open and j's
declarations arrived. Every TCP segment is one MPDU with a TCP/IP header.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from swarmd_lab.sim.channel import MULTICAST, Datagram, Kind
from swarmd_lab.sim.node import NodeContext, SimNode
from swarmd_lab.sim.phy import TCP_FRAME_OVERHEAD, UDP_FRAME_OVERHEAD

SCOUT_BYTES: Final = 12
HELLO_BYTES: Final = 64  # zid, whatami, one TCP locator
SCOUT_INITIAL_S: Final = 1.0
SCOUT_MAX_S: Final = 8.0
LEASE_S: Final = 10.0
KEEP_ALIVE_S: Final = LEASE_S / 4
SYN_RTO_S: Final = 1.0
RTO_S: Final = 0.2
MAX_RETRIES: Final = 6
# handshake steps: (request bytes, response bytes) of TCP payload; 0 = a bare TCP segment
HANDSHAKE: Final = ((0, 0), (48, 96), (64, 24))  # SYN/SYN-ACK, InitSyn/Ack, OpenSyn/Ack
DECLARE_BYTES: Final = 160
GOSSIP_BYTES: Final = 48
KEEPALIVE_BYTES: Final = 4
MAX_SEGMENT_BYTES: Final = 1400


class _Session:
    __slots__ = ("peer", "initiator", "step", "open", "declared", "retries", "last_rx")

    def __init__(self, peer: int, initiator: bool, now: float) -> None:
        self.peer = peer
        self.initiator = initiator
        self.step = 0
        self.open = False
        self.declared = False
        self.retries = 0
        self.last_rx = now


class ZenohNode(SimNode):
    """One zenoh peer."""

    def __init__(self, ctx: NodeContext) -> None:
        super().__init__(ctx)
        self._sessions: dict[int, _Session] = {}
        self._scout_period = SCOUT_INITIAL_S
        self._started = False

    def _at(self, at: float, fn: Callable[[], None]) -> None:
        self.ctx.clock.call_at(at, fn)

    def _udp(self, dst: int, size: int, payload: tuple[object, ...]) -> None:
        self.ctx.send(Datagram(self.index, dst, size, Kind.DISCOVERY, payload))

    def _tcp(self, dst: int, size: int, payload: tuple[object, ...]) -> None:
        self.ctx.send(
            Datagram(
                self.index,
                dst,
                size + TCP_FRAME_OVERHEAD - UDP_FRAME_OVERHEAD,
                Kind.DISCOVERY,
                payload,
            )
        )

    # ------------------------------------------------------------ scouting

    def start(self, now: float) -> None:
        self._started = True
        self._scout()
        self._at(now + KEEP_ALIVE_S, self._keep_alive)

    def _scout(self) -> None:
        self._udp(MULTICAST, SCOUT_BYTES, ("scout",))
        self._at(self.ctx.clock.now + self._scout_period, self._scout)
        self._scout_period = min(self._scout_period * 2.0, SCOUT_MAX_S)

    def receive(self, dgram: Datagram, now: float) -> None:
        if not self._started:
            return
        msg = dgram.payload
        assert isinstance(msg, tuple)  # noqa: S101 - the model's own messages
        src = dgram.src
        kind = msg[0]
        if kind == "scout":
            self._udp(src, HELLO_BYTES, ("hello",))
        elif kind == "hello":
            if src not in self._sessions:
                self._sessions[src] = _Session(src, True, now)
                self._request(src)
        elif kind == "req":
            self._on_request(src, int(msg[1]), now)
        elif kind == "resp":
            self._on_response(src, int(msg[1]), now)
        elif kind in ("declare", "gossip", "keepalive"):
            s = self._sessions.get(src)
            if s is None:
                return
            if not s.open:
                # the peer completed the (merged) handshake first: its session is ours too
                self._opened(s, now)
            s.last_rx = now
            if kind != "keepalive":
                self._tcp(src, 0, ("ack",))
            if kind == "declare" and not s.declared:
                s.declared = True
                self.ctx.ledger.discovered(self.index, src, now)
        elif kind == "ack":
            s = self._sessions.get(src)
            if s is not None:
                s.last_rx = now

    # ------------------------------------------------------------ handshake

    def _request(self, peer: int) -> None:
        s = self._sessions.get(peer)
        if s is None or s.open or not s.initiator:
            return
        req, _ = HANDSHAKE[s.step]
        self._tcp(peer, req, ("req", s.step))
        if s.step == 1:
            self._tcp(peer, 0, ("ack",))  # the third segment of TCP's handshake
        rto = SYN_RTO_S if s.step == 0 else RTO_S
        step, retries = s.step, s.retries
        self._at(self.ctx.clock.now + rto * 2.0**retries, lambda: self._retry(peer, step))

    def _retry(self, peer: int, step: int) -> None:
        s = self._sessions.get(peer)
        if s is None or s.open or s.step != step or not s.initiator:
            return
        s.retries += 1
        if s.retries > MAX_RETRIES:
            del self._sessions[peer]  # give up; a later HELLO starts over
            return
        self._request(peer)

    def _on_request(self, src: int, step: int, now: float) -> None:
        # both sides opening at once (to_peer "always"): the model answers the peer's
        # handshake on the same session, so the two opens merge into one session
        s = self._sessions.get(src)
        if s is None:
            s = self._sessions[src] = _Session(src, False, now)
        s.last_rx = now
        _, resp = HANDSHAKE[step]
        self._tcp(src, resp, ("resp", step))
        if step == len(HANDSHAKE) - 1 and not s.open:
            self._opened(s, now)

    def _on_response(self, src: int, step: int, now: float) -> None:
        s = self._sessions.get(src)
        if s is None or not s.initiator or s.open or s.step != step:
            return
        s.last_rx = now
        s.step += 1
        s.retries = 0
        if s.step == len(HANDSHAKE):
            self._tcp(src, 0, ("ack",))
            self._opened(s, now)
        else:
            self._request(src)

    def _opened(self, s: _Session, now: float) -> None:
        s.open = True
        self._tcp(s.peer, DECLARE_BYTES, ("declare",))
        # the peer list, capped at one segment (zenoh splits longer ones into batches)
        gossip = min(GOSSIP_BYTES + 16 * len(self._sessions), MAX_SEGMENT_BYTES)
        self._tcp(s.peer, gossip, ("gossip",))
        # gossip (scouting.gossip, target peers): tell every other open session about it
        for other in sorted(self._sessions):
            o = self._sessions[other]
            if other != s.peer and o.open:
                self._tcp(other, GOSSIP_BYTES, ("gossip",))

    # ------------------------------------------------------------ liveness

    def _keep_alive(self) -> None:
        now = self.ctx.clock.now
        for peer in sorted(self._sessions):
            s = self._sessions[peer]
            if not s.open:
                continue
            if now - s.last_rx > LEASE_S:
                del self._sessions[peer]
                self.ctx.ledger.lost(self.index, peer, now)
                continue
            self._tcp(peer, KEEPALIVE_BYTES, ("keepalive",))
        self._at(now + KEEP_ALIVE_S, self._keep_alive)
