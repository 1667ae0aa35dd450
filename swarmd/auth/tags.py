"""Receiver tags: the outsider filter in front of the SPDP signature (issue 18).

Why: an Ed25519 verification costs ~50-130 us here (several times that on a Jetson Nano),
so the verifier rations them per sender (``swarmd.auth.budget``). Before this, the budget
was keyed by the datagram's claims (GUID prefix, UDP source): any host on the link could
put the commander's prefix and exact source address on forged SPDP and spend the
commander's 20 verifications a second, and the real renewals lost the race (issue 18: the
members lost the commander at 100 forged datagrams a second). A budget can only protect a
sender if what spends it is something only that sender can make.

What: every SPDP datagram carries, inside its authenticator (PID 0x8A04, docs/wire.md),
one 2-octet tag per receiver (the block padded to 4 octets),

    tag(P -> R) = BLAKE2b-16(key = K_tag(P, R), datagram up to the tags ‖ start, count, freshness)
    K_tag(P, R) = HMAC-SHA256(pair_key(P, R), "swarmd spdp receiver tag v1")

with ``pair_key`` the 32-octet key both ends already derive from the bundle alone (static
X25519 + HKDF, ``swarmd.auth.keys.KeyRing.pair_key``: no message, no handshake). The
receiver checks *its own* tag (one keyed BLAKE2b, ~1-2 us) before it spends anything; a
datagram whose tag is wrong is refused (``auth_bad_tag``) having cost no budget, no
signature, no decode. Only the sender and this receiver hold K_tag(P, R), so:

- an outsider (no node key) never reaches a budget, whatever prefix and source it forges
  (a blind guess passes with probability 2^-16: at 20,000 forged datagrams a second, a
  token every ~3 s, at 10^5 a second 1.5 a second, against the 20 a second the real
  sender's budget refills: the forger cannot learn which guesses passed, and those that do
  still fail the signature);
- a captured member C holds K_tag(C, R) for every R but no K_tag(P, R) for P != C: its
  forgeries as the commander or another member fail the tag too, so it can spend only
  its *own* prefix's budget (its own datagrams are its to waste).

This is DDS-Security's answer for multicast, "receiver-specific MACs" (DDS Security 1.1,
9.5.3.3, the SecurePostfix's ``receiver_specific_macs``: a datagram sent once to many
readers carries one MAC per reader, keyed per pair, so no reader can forge for the sender
to another). DDS-Security pays 20 octets per reader (a 4-octet key id + a 16-octet
HMAC) because its MACs are the authenticators; here the Ed25519 signature stays the
authenticator and the tags only decide who may spend a verification, so 2 octets
(receivers found by bundle index, no key id) are enough: 4 would make a lucky guess
negligible rather than harmless, at twice the bytes (+64 octets on a 33-node swarm's
multicast, where the whole issue-10 authenticator was 76).

Which receivers: a datagram directed to one peer (INFO_DST) carries that peer's tag only;
a multicast one carries the tags of ``MAX_RECEIVER_TAGS`` peers in bundle order after the
sender, a window that rotates at each multicast datagram when the swarm has more peers
than that (up to 33 nodes, every receiver's tag is in every datagram). A receiver outside
the window checks the datagram under the old, address-keyed budgets, which are separate
from the budget tagged datagrams spend (docs/security.md, "Receiver tags").

Sans-IO: no clock, no files; hashlib and hmac only (no new dependency on the drone).
"""

from __future__ import annotations

import hashlib
import hmac
from typing import TYPE_CHECKING, Final, Protocol

if TYPE_CHECKING:
    from swarmd.auth.keys import KeyRing

# 2 octets: the tag is a ticket to a verification, not the authenticator (module docstring)
TAG_BYTES: Final = 2
# Tags in one multicast datagram. 32 x 4 = 128 octets at most; up to 33 nodes every peer is
# tagged in every datagram, beyond the window rotates (module docstring).
MAX_RECEIVER_TAGS: Final = 32
TAG_KEY_INFO: Final = b"swarmd spdp receiver tag v1"
_NO_TAG: Final = bytes(TAG_BYTES)


def tag_block_bytes(count: int) -> int:
    """Octets of ``count`` tags on the wire: padded to a multiple of 4 (parameter values in
    a parameter list are 4-aligned, DDSI-RTPS 9.4.2.11); the padding is zero."""
    return (TAG_BYTES * count + 3) & ~3


def compute_tag(key: bytes, head: bytes | memoryview, meta_fresh: bytes | memoryview) -> bytes:
    """``tag(P -> R)``: keyed BLAKE2b (RFC 7693, a MAC in keyed mode) truncated to 4 octets."""
    h = hashlib.blake2b(head, key=key, digest_size=TAG_BYTES)
    h.update(meta_fresh)
    return h.digest()


class Tagger(Protocol):
    """What ``swarmd.auth.spdp.seal`` needs to fill the tags in."""

    def slots(self, destination: bytes | None) -> tuple[int, int]: ...

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        """``tag_block_bytes(count)`` octets: the tags, then zero padding."""
        ...


class ReceiverTags:
    """This node's tags, sending and receiving, from the key ring (``Tagger`` for ``seal``).

    Slots: for a sender at bundle index ``s`` among ``n`` nodes, the other nodes in bundle
    order after it form a ring of ``m = n - 1`` positions (receiver ``r`` at position
    ``(r - s - 1) mod n``); a datagram's ``start, count`` name the positions
    ``start .. start + count - 1`` (mod m) whose tags it carries, in that order. Keys are
    derived on first use and kept per bundle index (at most the bundle's size)."""

    def __init__(self, keyring: KeyRing) -> None:
        self._keyring = keyring
        self._order: list[bytes] = [p.guid_prefix.value for p in keyring.bundle.participants]
        self._index: dict[bytes, int] = {prefix: i for i, prefix in enumerate(self._order)}
        self._n = len(self._order)
        self._me = self._index[keyring.own_prefix.value]
        self._keys: dict[int, bytes | None] = {}
        self._next_start = 0
        self.tags_made = 0
        self.tags_checked = 0

    @property
    def peers(self) -> int:
        return self._n - 1

    def key(self, index: int) -> bytes | None:
        """K_tag between this node and the node at bundle ``index``; None without a pair key
        (this node itself, or a bundle key that yields no shared secret)."""
        if index in self._keys:
            return self._keys[index]
        pair = self._keyring.pair_key(self._order[index])
        key = None if pair is None else hmac.digest(pair, TAG_KEY_INFO, "sha256")
        self._keys[index] = key
        return key

    # ---- sending -------------------------------------------------------------------------

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        """(start, count) for the next datagram: the destination's slot alone when directed,
        else the next window of up to ``MAX_RECEIVER_TAGS`` peers."""
        m = self._n - 1
        if m <= 0:
            return 0, 0
        if destination is not None:
            r = self._index.get(destination)
            if r is None or r == self._me:
                return 0, 0
            return (r - self._me - 1) % self._n, 1
        count = min(m, MAX_RECEIVER_TAGS)
        start = self._next_start
        self._next_start = (start + count) % m if count < m else 0
        return start, count

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        """The ``count`` tags from position ``start``, over the datagram's ``head`` (every
        octet before the tags) and ``meta_fresh`` (start, count, freshness)."""
        m, n, me = self._n - 1, self._n, self._me
        out: list[bytes] = []
        for i in range(count):
            r = (me + 1 + (start + i) % m) % n
            key = self.key(r)
            out.append(_NO_TAG if key is None else compute_tag(key, head, meta_fresh))
        self.tags_made += count
        block = b"".join(out)
        return block + bytes(tag_block_bytes(count) - len(block))

    # ---- receiving -----------------------------------------------------------------------

    def slot_of_me(self, sender: bytes, start: int, count: int) -> int | None:
        """Which of a datagram's ``count`` tags is mine (sender ``sender``), None if the
        datagram carries none for me (or names positions outside the ring)."""
        s = self._index.get(sender)
        m = self._n - 1
        if s is None or m <= 0 or count == 0 or start >= m or count > m:
            return None
        k = ((self._me - s - 1) % self._n - start) % m
        return k if k < count else None

    def may_omit_me(self, sender: bytes, count: int) -> bool:
        """Whether a genuine multicast datagram of ``sender`` with ``count`` tags may carry
        none for me: only a full window in a swarm larger than one (``MAX_RECEIVER_TAGS``
        peers). Up to 33 nodes every multicast datagram tags every peer, so one without my
        tag is forged."""
        return sender in self._index and self._n - 1 > MAX_RECEIVER_TAGS == count

    def holds(
        self, sender: bytes, tag: bytes | memoryview, head: memoryview, meta: memoryview
    ) -> bool:
        """Whether ``tag`` is ``sender``'s tag for me over ``head`` and ``meta``."""
        s = self._index.get(sender)
        key = None if s is None else self.key(s)
        self.tags_checked += 1
        if key is None:
            return False
        return hmac.compare_digest(compute_tag(key, head, meta), tag)


class ZeroTags:
    """The tags' bytes without keys: ``count`` zero tags per datagram, the window rotating
    as ``ReceiverTags`` rotates it. For the simulator (``swarmd-auth``: bytes and airtime,
    not CPU) and benches; it authenticates nothing."""

    def __init__(self, n: int) -> None:
        self._m = max(0, n - 1)
        self._next_start = 0

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        m = self._m
        if m == 0:
            return 0, 0
        if destination is not None:
            return 0, 1
        count = min(m, MAX_RECEIVER_TAGS)
        start = self._next_start
        self._next_start = (start + count) % m if count < m else 0
        return start, count

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        return bytes(tag_block_bytes(count))
