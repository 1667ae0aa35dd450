"""The SPDP authenticator: who sent this DATA(p) or DATA(p[UD]), and is it new?

Wire (docs/wire.md, "Authenticator"): every SPDP datagram swarmd sends ends with

    ... | 04 8a LL LL | tags (4 x count) | start u16 | count u16 | epoch u32 | seq u32 |
          PID 0x8A04,   receiver tags (swarmd.auth.tags)          freshness
          length 76 + 4 x count
        | Ed25519 signature (64) | 01 00 00 00
                                   PID_SENTINEL

i.e. the swarmd vendor PID ``0x8A04`` is the last parameter before the sentinel of the last
parameter list (the DATA(p) payload, or the key payload of a DATA(p[UD])). The signature is
made with the sender's bundle Ed25519 key over the whole datagram except the 64 signature
octets: RTPS header (GUID prefix), INFO_DST (who it is for), INFO_TS, the DATA submessage
header (SN, flags, lengths), every parameter, the tags, the freshness and the sentinel.
Each tag is a MAC for one receiver under the key the sender and that receiver share
(``swarmd.auth.tags``). Stock stacks skip the PID (vendor range, 0x4000 clear) and see an
ordinary participant.

Why a signature and not only per-pair MACs here: SPDP is multicast, one datagram to N
receivers; a signature is one field that proves the sender to everyone, and a receiver
cannot forge it for another (the paper's Appendix B trial paid +110 % packets for its
runtime exchange; this costs +0 packets). The 4-octet tags are not the proof, only the
ticket to a verification: they make sure an outsider never spends one.

Receiving (``SpdpVerifier.check``), in order of cost, nothing changing before the end:

1. the tail is there and well-formed (else ``auth_missing``): slicing, no decoding;
2. the freshness, read at its fixed offset, is newer than the sender's replay window (else
   ``auth_replayed``): two integers, no object built, nothing copied;
3. my receiver tag, when the datagram carries one for me: one keyed BLAKE2b (else
   ``auth_bad_tag``), before any budget, so a forgery by anyone but the sender (an
   outsider, whatever prefix and source address it forges; a captured member posing as
   another) spends nothing a real peer needs;
4. a verification token: tagged, the sender's own budget, which nothing but the sender's
   datagrams reach. Untagged (a swarm larger than the tag window, between rotations): the
   issue-10 budgets, separate from the tagged one: the sender's own budget when the
   datagram comes from the address its last used verified datagram came from, otherwise a
   per-(prefix, address) budget *and* a global budget for unverified addresses (else
   ``auth_budget_sender`` / ``auth_budget_global``);
5. not a datagram that already failed its signature here (else ``auth_repeated_forgery``):
   one unkeyed BLAKE2b of the whole datagram against a bounded table of those that failed;
6. Ed25519 under the prefix's bundle key (else ``auth_bad_signature``; the datagram joins
   that table);
7. only then: the window accepts the freshness.

Why step 5: a forgery whose tag holds by chance (2^-16 per guess) fails its signature, so
the window never moves past its freshness and the same bytes pass steps 1-4 every time they
are sent again. An attacker cycling a fixed pool of forgeries therefore spent one
verification per copy of the lucky one, not one in all: in the spoofed-address attack test a
pool of 1,400 forgeries sent 214 times over (5,000/s for 60 s) held one lucky tag and cost the
lead drone 214 verifications (and as many tokens of the real sender's budget) where one was
due. With the table a lucky guess costs one verification, whatever the pool, so the cost of
a blind forger stays one in 65,536 of what it sends. The table is keyed by the whole
datagram (signature included): a genuine datagram, whose signature holds, can never be in
it, so racing a sniffed genuine datagram with a corrupted copy cannot get the genuine one
refused.

The caller (the discovery engine) looks the prefix up in the bundle first (strangers never
reach this) and changes its peer table only on a returned ``Freshness``. Once it has used
the datagram (it was for this node: not a directed reply to another), it calls
``note_address``: that source becomes the sender's known address for untagged datagrams.
Not before: a genuine directed datagram captured on its way to another node and replayed
to us from the attacker's address verifies, but must not move the sender's budget to that
address (the attacker could then starve the real address by spending the shared budget).
"""

from __future__ import annotations

import hashlib
import struct
from collections import OrderedDict
from enum import StrEnum
from typing import Final, Protocol

from swarmd.auth.budget import (
    GLOBAL_NEW_ADDRESS_BURST,
    GLOBAL_NEW_ADDRESS_RATE,
    MAX_NEW_ADDRESSES,
    NEW_ADDRESS_BURST,
    NEW_ADDRESS_RATE,
    SENDER_BURST,
    SENDER_RATE,
    BucketTable,
)
from swarmd.auth.freshness import Freshness, ReplayWindow, SendCounter
from swarmd.auth.keys import SIGNATURE_BYTES, KeyRing
from swarmd.auth.tags import (
    MAX_RECEIVER_TAGS,
    TAG_BYTES,
    ReceiverTags,
    Tagger,
    tag_block_bytes,
)
from swarmd.rtps.spdp import PID_SWARMD_AUTHENTICATOR
from swarmd.rtps.types import GuidPrefix
from swarmd.tokenbucket import TokenBucket

FRESHNESS_BYTES: Final = 8
SIGNED_TAIL_BYTES: Final = FRESHNESS_BYTES + SIGNATURE_BYTES  # 72, a multiple of 4
_META: Final = struct.Struct("<HH")  # tag window: start, count
# what the authenticator adds to a datagram with no tags: parameter header, tag window,
# freshness, signature; the tags add tag_block_bytes(count) more (2 each, padded to 4)
AUTHENTICATOR_OVERHEAD: Final = 4 + _META.size + SIGNED_TAIL_BYTES  # 80
# the template's placeholder (what encode_spdp writes before sealing): seal replaces it
PLACEHOLDER: Final = bytes(SIGNED_TAIL_BYTES)
AUTHENTICATOR_BYTES: Final = SIGNED_TAIL_BYTES  # the placeholder's length (templates only)
_PLACEHOLDER_HEAD: Final = struct.pack("<HH", PID_SWARMD_AUTHENTICATOR, SIGNED_TAIL_BYTES)
# the parameter header of a sealed authenticator with ``count`` tags, by count
_SEALED_HEADS: Final = tuple(
    struct.pack(
        "<HH", PID_SWARMD_AUTHENTICATOR, _META.size + SIGNED_TAIL_BYTES + tag_block_bytes(c)
    )
    for c in range(MAX_RECEIVER_TAGS + 1)
)
_SENTINEL: Final = struct.pack("<HH", 0x0001, 0)
_TEMPLATE_TAIL: Final = 4 + SIGNED_TAIL_BYTES + 4  # 80: parameter header, value, sentinel
_SEALED_TAIL: Final = AUTHENTICATOR_OVERHEAD + 4  # 84 + 4 x tags: ... and the sentinel
_RTPS_HEADER: Final = 20
_FRESHNESS: Final = struct.Struct("<II")  # Freshness.pack: epoch, seq, little-endian
_FRESHNESS_FROM_END: Final = 4 + SIGNATURE_BYTES + FRESHNESS_BYTES  # sentinel, signature
_META_FROM_END: Final = _FRESHNESS_FROM_END + _META.size
_INFO_DST: Final = 0x0E
# submessages whose octetsToNextHeader may be 0 without meaning "to the end of the message"
# (DDSI-RTPS 2.5, 9.4.5.1.3): PAD and INFO_TS (an INFO_TS with I set has no body)
_EMPTY_OK: Final = frozenset({0x01, 0x09})


class Refusal(StrEnum):
    """Why an SPDP datagram under a bundle prefix was refused (the engine's drop counters)."""

    MISSING = "auth_missing"
    REPLAYED = "auth_replayed"
    BAD_TAG = "auth_bad_tag"
    BUDGET_SENDER = "auth_budget_sender"
    BUDGET_GLOBAL = "auth_budget_global"
    BAD_SIGNATURE = "auth_bad_signature"
    REPEATED_FORGERY = "auth_repeated_forgery"


# Datagrams that failed their signature, remembered so a repeat costs no verification
# (module docstring, step 5): 16-octet digests, oldest forgotten first. 512 entries is about
# 40 KB; an attacker must find 512 lucky tags (2^25 forgeries on average) to push one out.
MAX_FAILED_DIGESTS: Final = 512
FAILED_DIGEST_BYTES: Final = 16


def authenticator_overhead(tags: int) -> int:
    """Octets the authenticator adds to a datagram carrying ``tags`` receiver tags."""
    return AUTHENTICATOR_OVERHEAD + tag_block_bytes(tags)


def is_template(data: bytes) -> bool:
    """Whether ``data`` ends with the authenticator placeholder and the sentinel."""
    n = len(data)
    return (
        n >= _RTPS_HEADER + _TEMPLATE_TAIL
        and data[n - 4 :] == _SENTINEL
        and data[n - _TEMPLATE_TAIL : n - _TEMPLATE_TAIL + 4] == _PLACEHOLDER_HEAD
    )


def tail_window(data: bytes) -> tuple[int, int] | None:
    """(start, count) of a sealed datagram's tag window; None without a well-formed
    authenticator at the end (slicing and two integers: nothing is decoded)."""
    n = len(data)
    if n < _RTPS_HEADER + _SEALED_TAIL or data[n - 4 :] != _SENTINEL:
        return None
    start, count = _META.unpack_from(data, n - _META_FROM_END)
    if count > MAX_RECEIVER_TAGS:
        return None
    head_at = n - _SEALED_TAIL - tag_block_bytes(count)
    if head_at < _RTPS_HEADER or data[head_at : head_at + 4] != _SEALED_HEADS[count]:
        return None
    return start, count


def has_tail(data: bytes) -> bool:
    """Whether ``data`` ends with a sealed authenticator and the sentinel."""
    return tail_window(data) is not None


class Signer(Protocol):
    def sign(self, data: bytes) -> bytes: ...


def _destination(template: bytes) -> bytes | None:
    """The INFO_DST prefix of a datagram that starts with one (directed SPDP), else None."""
    if len(template) >= _RTPS_HEADER + 16 and template[_RTPS_HEADER] == _INFO_DST:
        return template[_RTPS_HEADER + 4 : _RTPS_HEADER + 16]
    return None


def _grow_last_submessage(head: bytearray, total: int, grow: int) -> None:
    """Add ``grow`` to the octetsToNextHeader of the last submessage of a ``total``-octet
    datagram whose first octets are ``head`` (the tags go inside the DATA that ends it;
    0 means "to the end of the message" and stays)."""
    at = _RTPS_HEADER
    while at + 4 <= len(head):
        order = "<H" if head[at + 1] & 1 else ">H"
        (length,) = struct.unpack_from(order, head, at + 2)
        if length == 0 and head[at] not in _EMPTY_OK:
            return
        following = at + 4 + length
        if following >= total:
            struct.pack_into(order, head, at + 2, length + grow)
            return
        at = following
    raise ValueError("template has no submessage that ends it")


def seal(
    template: bytes, freshness: Freshness, keyring: Signer, tags: Tagger | None = None
) -> bytes:
    """``template`` (encoded with ``PLACEHOLDER`` as its authenticator) sealed: the receiver
    tags of ``tags`` (none without it), the tag window, ``freshness`` and the signature of
    ``keyring`` (a ``KeyRing``, or any Ed25519 signer) over everything else."""
    if not is_template(template):
        raise ValueError("template does not end with the authenticator placeholder")
    n = len(template)
    start, count = (0, 0) if tags is None else tags.slots(_destination(template))
    head = bytearray(template[: n - _TEMPLATE_TAIL])
    _grow_last_submessage(head, n, _META.size + tag_block_bytes(count))
    head += _SEALED_HEADS[count]
    meta_fresh = _META.pack(start, count) + freshness.pack()
    head_bytes = bytes(head)
    block = b"" if tags is None or count == 0 else tags.make(start, count, head_bytes, meta_fresh)
    body = head_bytes + block + meta_fresh
    signature = keyring.sign(body + _SENTINEL)
    return body + signature + _SENTINEL


def open_tail(data: bytes) -> tuple[Freshness, bytes, bytes] | None:
    """(freshness, signature, signed octets) of an authenticated datagram; None without one."""
    if not has_tail(data):
        return None
    n = len(data)
    sig_at = n - 4 - SIGNATURE_BYTES
    freshness = Freshness.unpack(data[sig_at - FRESHNESS_BYTES : sig_at])
    return freshness, data[sig_at : n - 4], data[:sig_at] + _SENTINEL


class SpdpVerifier:
    """The receiving side: replay windows, receiver tags, budgets and signature checks, per
    bundle sender.

    Every table is bounded: windows, tag keys and known addresses by the bundle's size (only
    bundle prefixes get here, and windows only after verifying), new-address buckets by
    ``MAX_NEW_ADDRESSES``, failed datagrams by ``MAX_FAILED_DIGESTS``. ``counters`` counts
    each refusal and each verification run."""

    def __init__(self, keyring: KeyRing, now: float, tags: ReceiverTags | None = None) -> None:
        self._keyring = keyring
        self._tags = tags
        self._windows: dict[bytes, ReplayWindow] = {}
        self.windows_changed = False  # since the last ``snapshot`` (persisted windows)
        # the address each sender's own budget applies at: its last used verified source,
        # seeded with the bundle's address for it (ipv4 + metatraffic port, when the mission
        # gives one), so a member is heard at full budget from its first datagram on, even
        # while a flood spends the shared budget
        bundle = keyring.bundle
        self._known: dict[bytes, tuple[str, int]] = {
            p.guid_prefix.value: (p.ipv4, bundle.metatraffic_port(p))
            for p in bundle.participants
            if p.ipv4 is not None
        }
        size = max(1, keyring.size)
        # tagged datagrams (my tag held): only the sender (or a relay of its very datagram)
        # can spend this one, so it is never shared with what forgers reach
        self._tagged = BucketTable[bytes](SENDER_RATE, SENDER_BURST, size)
        # datagrams without a tag for me (a swarm larger than the tag window): the
        # address-keyed budgets of issue 10, separate from the tagged one
        self._sender = BucketTable[bytes](SENDER_RATE, SENDER_BURST, size)
        self._new_address = BucketTable[tuple[bytes, str, int]](
            NEW_ADDRESS_RATE, NEW_ADDRESS_BURST, MAX_NEW_ADDRESSES
        )
        self._global = TokenBucket(GLOBAL_NEW_ADDRESS_RATE, GLOBAL_NEW_ADDRESS_BURST, now)
        # digests of datagrams that reached Ed25519 and failed (step 5), at most
        # MAX_FAILED_DIGESTS, oldest first
        self._failed: OrderedDict[bytes, None] = OrderedDict()
        self.counters: dict[str, int] = {r.value: 0 for r in Refusal}
        self.counters["auth_verified"] = 0
        self.counters["auth_untagged"] = 0  # checked without a tag for me (rotating window)

    def check(
        self, prefix: bytes, data: bytes, source: tuple[str, int], now: float
    ) -> Freshness | Refusal:
        """The freshness of a datagram whose authenticator holds, or why it was refused.

        On success the sender's window has accepted the freshness: the caller must not
        count the same datagram twice. ``prefix`` must be a bundle participant's."""
        window_of_tags = tail_window(data)
        if window_of_tags is None:
            return self._refuse(Refusal.MISSING)
        n = len(data)
        window = self._windows.get(prefix)
        if window is not None:
            # the freshness read at its fixed offset from the end: a replay (half of a
            # flood under members' prefixes) is refused before anything is built or copied
            epoch, seq = _FRESHNESS.unpack_from(data, n - _FRESHNESS_FROM_END)
            if not window.is_fresh_at(epoch, seq):
                return self._refuse(Refusal.REPLAYED)
        tags = self._tags
        slot = None if tags is None else tags.slot_of_me(prefix, *window_of_tags)
        if tags is not None and slot is not None:
            # my tag: one keyed BLAKE2b, before any budget (swarmd.auth.tags)
            view = memoryview(data)
            head_end = n - _SEALED_TAIL + 4 - tag_block_bytes(window_of_tags[1])
            meta_at = n - _META_FROM_END
            tag = view[head_end + TAG_BYTES * slot : head_end + TAG_BYTES * (slot + 1)]
            head = view[:head_end]
            if not tags.holds(prefix, tag, head, view[meta_at : n - 4 - SIGNATURE_BYTES]):
                return self._refuse(Refusal.BAD_TAG)
            digest = self._failed_before(data)
            if digest is None:
                return self._refuse(Refusal.REPEATED_FORGERY)
            if not self._tagged.take(prefix, now):
                return self._refuse(Refusal.BUDGET_SENDER)
        elif tags is not None and (
            data[_RTPS_HEADER] == _INFO_DST or not tags.may_omit_me(prefix, window_of_tags[1])
        ):
            # no tag for me where every genuine datagram for me carries one: a directed
            # datagram for another node (nothing here to use) or a forgery
            return self._refuse(Refusal.BAD_TAG)
        else:
            self.counters["auth_untagged"] += 1
            digest = self._failed_before(data)
            if digest is None:
                return self._refuse(Refusal.REPEATED_FORGERY)
            if self._known.get(prefix) == source:
                if not self._sender.take(prefix, now):
                    return self._refuse(Refusal.BUDGET_SENDER)
            else:
                if not self._new_address.take((prefix, *source), now):
                    return self._refuse(Refusal.BUDGET_SENDER)
                if not self._global.take(now):
                    return self._refuse(Refusal.BUDGET_GLOBAL)
        opened = open_tail(data)
        if opened is None:  # tail_window held: unreachable, but the types need it
            return self._refuse(Refusal.MISSING)
        freshness, signature, signed = opened
        self.counters["auth_verified"] += 1
        if not self._keyring.verify(prefix, signed, signature):
            failed = self._failed
            failed[digest] = None
            if len(failed) > MAX_FAILED_DIGESTS:
                failed.popitem(last=False)
            return self._refuse(Refusal.BAD_SIGNATURE)
        if window is None:
            window = self._windows[prefix] = ReplayWindow()
        window.accept(freshness)
        self.windows_changed = True
        return freshness

    def _failed_before(self, data: bytes) -> bytes | None:
        """The datagram's digest, or None when these very octets already failed their
        signature here (step 5: a repeat is refused without a verification)."""
        digest = hashlib.blake2b(data, digest_size=FAILED_DIGEST_BYTES).digest()
        return None if digest in self._failed else digest

    @property
    def failed_remembered(self) -> int:
        """How many failed datagrams are remembered (at most ``MAX_FAILED_DIGESTS``)."""
        return len(self._failed)

    def note_address(self, prefix: bytes, source: tuple[str, int]) -> None:
        """A datagram from ``prefix`` that ``check`` verified came from ``source`` and was
        used: its later untagged datagrams from there spend the sender's own budget."""
        self._known[prefix] = source

    def high(self, prefix: bytes) -> Freshness | None:
        """The highest freshness verified from ``prefix`` (its epoch is its current life)."""
        window = self._windows.get(prefix)
        return None if window is None else window.high

    def snapshot(self) -> dict[bytes, Freshness]:
        """Every sender's highest verified freshness (to persist: ``swarmd.auth.windows``;
        the caller clears ``windows_changed`` once it is saved)."""
        return {p: w.high for p, w in self._windows.items() if w.high is not None}

    def restore(self, highs: dict[bytes, Freshness]) -> int:
        """Start from persisted windows (a restarted receiver): each bundle sender's stored
        highest value and everything below it count as seen, so a captured datagram of a
        sender's that this node had already passed stays a replay. Returns how many were
        restored; prefixes outside the bundle are ignored."""
        restored = 0
        for prefix, high in highs.items():
            if self._keyring.participant(prefix) is None or prefix in self._windows:
                continue
            window = self._windows[prefix] = ReplayWindow()
            window.restore(high)
            restored += 1
        return restored

    def _refuse(self, reason: Refusal) -> Refusal:
        self.counters[reason.value] += 1
        return reason


class SpdpAuth:
    """What the discovery engine needs to authenticate SPDP: seal on send, check on receive.

    ``epoch`` is this node's boot epoch, already durable (``swarmd.auth.epoch``). Every
    datagram sealed carries the receiver tags of ``swarmd.auth.tags``."""

    def __init__(self, keyring: KeyRing, epoch: int, now: float) -> None:
        self.keyring = keyring
        self.counter = SendCounter(epoch)
        self.tags = ReceiverTags(keyring)
        self.verifier = SpdpVerifier(keyring, now, self.tags)

    @property
    def epoch(self) -> int:
        return self.counter.epoch

    @property
    def own_prefix(self) -> GuidPrefix:
        """The prefix this node signs as (the engine checks it is its own)."""
        return self.keyring.own_prefix

    def seal(self, template: bytes) -> bytes:
        return seal(template, self.counter.next(), self.keyring, self.tags)

    def check(
        self, prefix: bytes, data: bytes, source: tuple[str, int], now: float
    ) -> Freshness | Refusal:
        return self.verifier.check(prefix, data, source, now)

    def note_address(self, prefix: bytes, source: tuple[str, int]) -> None:
        self.verifier.note_address(prefix, source)

    def counters(self) -> dict[str, int]:
        """Work done (signatures verified, datagrams checked without a tag for this node,
        tags made and checked); the refusals are the engine's drop counters."""
        v = self.verifier.counters
        return {
            "verified": v["auth_verified"],
            "untagged": v["auth_untagged"],
            "tags_made": self.tags.tags_made,
            "tags_checked": self.tags.tags_checked,
        }
