"""The attacker host: a namespace on the swarm's LAN, not in the bundle, holding no key.

It does what a laptop on the swarm's Wi-Fi does: listens to everything on the air (an
AF_PACKET socket in promiscuous mode on a LAN whose bridge floods every frame, as a radio
channel does), learns the members from their SPDP, and sends forged datagrams to the
multicast group or to a drone's ports. Every capture and every send loop is bounded.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Final

from swarmd_lab.netns import Namespace

from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import open_tail
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.spdp import SpdpAlive, SpdpParticipant, decode_spdp
from swarmd.rtps.types import GuidPrefix

ETH_P_ALL: Final = 0x0003
ETH_P_IP: Final = 0x0800
PACKET_OUTGOING: Final = 4
MAX_CAPTURED: Final = 50_000  # datagrams kept; older ones fall off (bounded memory)
SNAP_LEN: Final = 65_535


@dataclass(frozen=True, slots=True)
class Captured:
    """One UDP datagram seen on the air."""

    t: float  # time.monotonic() at capture
    src: tuple[str, int]
    dst: tuple[str, int]
    payload: bytes


@dataclass(frozen=True, slots=True)
class Learned:
    """A participant as its SPDP announced it."""

    participant: SpdpParticipant
    sn: int
    source: str  # IPv4 it sent from
    # (boot epoch, seq) of its SPDP authenticator: public, it travels in clear; an attacker
    # uses the epochs to make forgeries pass the cheap freshness checks
    freshness: Freshness | None = None
    raw: bytes = b""  # the datagram as captured, for replay


def _udp(frame: bytes) -> tuple[tuple[str, int], tuple[str, int], bytes] | None:
    """(src, dst, payload) of an Ethernet/IPv4/UDP frame, None for anything else."""
    if len(frame) < 14 + 20 + 8 or int.from_bytes(frame[12:14], "big") != ETH_P_IP:
        return None
    ip = frame[14:]
    ihl = (ip[0] & 0x0F) * 4
    if ip[9] != socket.IPPROTO_UDP or len(ip) < ihl + 8:
        return None
    if int.from_bytes(ip[6:8], "big") & 0x3FFF:  # a fragment: not ours to reassemble
        return None
    total = int.from_bytes(ip[2:4], "big")
    sport, dport, ulen = struct.unpack_from(">HHH", ip, ihl)
    payload = ip[ihl + 8 : min(total, ihl + ulen)]
    src = socket.inet_ntoa(ip[12:16])
    dst = socket.inet_ntoa(ip[16:20])
    return (src, sport), (dst, dport), payload


class Attacker:
    """Sniff and forge from namespace ``ns`` (start with ``start()``, end with ``close()``)."""

    def __init__(self, ns: Namespace, spdp_group: tuple[str, int]) -> None:
        self.ns = ns
        self.spdp_group = spdp_group
        self.captured: deque[Captured] = deque(maxlen=MAX_CAPTURED)
        self.learned: dict[GuidPrefix, Learned] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._raw: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._tx = ns.socket()
        self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
        self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 0)
        self._tx.bind((ns.address, 0))
        self.sent = 0

    # -- sniffing ------------------------------------------------------------------------

    def start(self) -> Attacker:
        self.ns.run(["ip", "link", "set", self.ns.ifname, "promisc", "on"])
        raw = self.ns.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        raw.bind((self.ns.ifname, 0))
        raw.settimeout(0.2)
        self._raw = raw
        self._thread = threading.Thread(target=self._sniff, name="attacker-sniff", daemon=True)
        self._thread.start()
        return self

    def _sniff(self) -> None:
        assert self._raw is not None
        while not self._stop.is_set():
            try:
                frame, addr = self._raw.recvfrom(SNAP_LEN)
            except TimeoutError:
                continue
            except OSError:
                return
            if addr[2] == PACKET_OUTGOING:
                continue
            parsed = _udp(frame)
            if parsed is None:
                continue
            src, dst, payload = parsed
            with self._lock:
                self.captured.append(Captured(time.monotonic(), src, dst, payload))
            if dst == self.spdp_group or payload[:4] == b"RTPS":
                self._learn(payload, src[0], to_group=dst == self.spdp_group)

    def _learn(self, payload: bytes, source: str, *, to_group: bool) -> None:
        try:
            _, samples = decode_spdp(payload)
        except DecodeError:
            return
        tail = open_tail(payload)
        freshness = tail[0] if tail is not None else None
        for s in samples:
            if isinstance(s, SpdpAlive):
                with self._lock:
                    known = self.learned.get(s.participant.guid_prefix)
                    # what a replay resends is the last DATA(p) to the group: it carries a
                    # receiver tag for every drone, where a directed one (the paper's staged
                    # announcements, a seek's answer) tags only its destination, so its
                    # replay elsewhere is refused as a bad tag, never as a replay: a capture
                    # that ended on a directed frame made the spoof test's replays vanish
                    # under load (a CI run: the lead counted 0 replays)
                    raw = payload if to_group or known is None else known.raw
                    self.learned[s.participant.guid_prefix] = Learned(
                        s.participant, s.sequence_number, source, freshness, raw
                    )

    def member(self, name: str) -> Learned | None:
        """What SPDP told about the participant whose ENTITY_NAME ends in ``/name``."""
        with self._lock:
            for learned in self.learned.values():
                entity_name = learned.participant.entity_name or ""
                if entity_name.split("/")[-1] == name:
                    return learned
        return None

    def capture(
        self, since: float, match: Callable[[Captured], bool] = lambda c: True
    ) -> list[Captured]:
        """Datagrams captured at or after ``since`` that ``match``."""
        with self._lock:
            return [c for c in self.captured if c.t >= since and match(c)]

    def wait_for(self, cond: Callable[[], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if cond():
                return True
            time.sleep(0.05)
        return cond()

    # -- forging -------------------------------------------------------------------------

    def send(self, datagram: bytes, to: tuple[str, int]) -> None:
        self._tx.sendto(datagram, to)
        self.sent += 1

    def multicast(self, datagram: bytes) -> None:
        self.send(datagram, self.spdp_group)

    def paced(
        self,
        datagrams: Iterable[bytes],
        to: tuple[str, int],
        *,
        rate_hz: float,
        max_count: int,
        max_s: float,
    ) -> int:
        """Send in a loop at ``rate_hz`` (bounded by count and by time); returns the count."""
        start = time.monotonic()
        sent = 0
        pool = list(datagrams)
        if not pool:
            return 0
        while sent < max_count:
            now = time.monotonic()
            if now - start >= max_s:
                break
            due = int((now - start) * rate_hz) + 1
            while sent < min(due, max_count):
                with contextlib.suppress(BlockingIOError):
                    self._tx.sendto(pool[sent % len(pool)], to)
                sent += 1
            time.sleep(min(0.002, 1.0 / rate_hz))
        self.sent += sent
        return sent

    def listener(self, port: int) -> socket.socket:
        """A UDP socket on this host's ``port``: where redirected traffic would arrive."""
        s = self.ns.socket()
        s.bind(("0.0.0.0", port))  # noqa: S104 - the attacker listens on every address
        s.settimeout(0.1)
        return s

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._raw is not None:
            self._raw.close()
        self._tx.close()


def drain(sock: socket.socket, seconds: float, max_datagrams: int = 10_000) -> list[bytes]:
    """What arrives on ``sock`` within ``seconds`` (bounded)."""
    out: list[bytes] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and len(out) < max_datagrams:
        try:
            out.append(sock.recv(SNAP_LEN))
        except TimeoutError:
            continue
    return out
