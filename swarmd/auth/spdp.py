"""The SPDP authenticator: who sent this DATA(p) or DATA(p[UD]), and is it new?

Wire (docs/wire.md, "Authenticator"): every SPDP datagram swarmd sends ends with

    ... | 04 8a 48 00 | epoch u32 LE | seq u32 LE | Ed25519 signature (64) | 01 00 00 00
          PID 0x8A04,   freshness (swarmd.auth.freshness)                   PID_SENTINEL
          length 72

i.e. the swarmd vendor PID ``0x8A04`` is the last parameter before the sentinel of the last
parameter list (the DATA(p) payload, or the key payload of a DATA(p[UD])). The signature is
made with the sender's bundle Ed25519 key over the whole datagram except the 64 signature
octets: RTPS header (GUID prefix), INFO_DST (who it is for), INFO_TS, the DATA submessage
header (SN, flags, lengths), every parameter, the freshness and the sentinel. Stock stacks
skip the PID (vendor range, 0x4000 clear) and see an ordinary participant.

Why a signature and not per-pair MACs here: SPDP is multicast, one datagram to N receivers;
a signature costs one field, MACs would cost N (the paper's Appendix B trial paid +110 %
packets for its runtime exchange; this costs +0 packets and 76 octets).

Receiving (``SpdpVerifier.check``), in order of cost, nothing changing before the end:

1. the 80-octet tail is there (else ``auth_missing``): slicing, no decoding;
2. the freshness, read at its fixed offset, is newer than the sender's replay window (else
   ``auth_replayed``): two integers, no object built, nothing copied;
3. a verification token: the sender's own budget when the datagram comes from the address
   its last verified datagram came from; otherwise a per-(prefix, address) budget *and*
   a global budget for unverified addresses, so a flood spoofing a member's prefix from
   other addresses never spends the member's budget (else ``auth_budget_sender`` /
   ``auth_budget_global``);
4. Ed25519 under the prefix's bundle key (else ``auth_bad_signature``);
5. only then: the window accepts the freshness.

The caller (the discovery engine) looks the prefix up in the bundle first (strangers never
reach this) and changes its peer table only on a returned ``Freshness``. Once it has used
the datagram (it was for this node: not a directed reply to another), it calls
``note_address``: that source becomes the sender's known address. Not before: a genuine
directed datagram captured on its way to another node and replayed to us from the
attacker's address verifies, but must not move the sender's budget to that address (the
attacker could then starve the real address by spending the shared budget).
"""

from __future__ import annotations

import struct
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
    TokenBucket,
)
from swarmd.auth.freshness import Freshness, ReplayWindow, SendCounter
from swarmd.auth.keys import SIGNATURE_BYTES, KeyRing
from swarmd.rtps.spdp import PID_SWARMD_AUTHENTICATOR
from swarmd.rtps.types import GuidPrefix

FRESHNESS_BYTES: Final = 8
AUTHENTICATOR_BYTES: Final = FRESHNESS_BYTES + SIGNATURE_BYTES  # 72, a multiple of 4
# what the authenticator adds to a datagram: parameter header + value
AUTHENTICATOR_OVERHEAD: Final = 4 + AUTHENTICATOR_BYTES  # 76
PLACEHOLDER: Final = bytes(AUTHENTICATOR_BYTES)  # what encode_spdp writes before sealing
_PARAM_HEAD: Final = struct.pack("<HH", PID_SWARMD_AUTHENTICATOR, AUTHENTICATOR_BYTES)
_SENTINEL: Final = struct.pack("<HH", 0x0001, 0)
_TAIL: Final = 4 + AUTHENTICATOR_BYTES + 4  # 80: parameter header, value, sentinel
_RTPS_HEADER: Final = 20
_FRESHNESS: Final = struct.Struct("<II")  # Freshness.pack: epoch, seq, little-endian
_FRESHNESS_FROM_END: Final = 4 + SIGNATURE_BYTES + FRESHNESS_BYTES  # sentinel, signature


class Refusal(StrEnum):
    """Why an SPDP datagram under a bundle prefix was refused (the engine's drop counters)."""

    MISSING = "auth_missing"
    REPLAYED = "auth_replayed"
    BUDGET_SENDER = "auth_budget_sender"
    BUDGET_GLOBAL = "auth_budget_global"
    BAD_SIGNATURE = "auth_bad_signature"


def has_tail(data: bytes) -> bool:
    """Whether ``data`` ends with a (placeholder or real) authenticator and the sentinel."""
    n = len(data)
    return (
        n >= _RTPS_HEADER + _TAIL
        and data[n - 4 :] == _SENTINEL
        and data[n - _TAIL : n - _TAIL + 4] == _PARAM_HEAD
    )


class Signer(Protocol):
    def sign(self, data: bytes) -> bytes: ...


def seal(template: bytes, freshness: Freshness, keyring: Signer) -> bytes:
    """``template`` (encoded with ``PLACEHOLDER`` as its authenticator) with ``freshness``
    and the signature of ``keyring`` (a ``KeyRing``, or any Ed25519 signer) filled in."""
    if not has_tail(template):
        raise ValueError("template does not end with the authenticator placeholder")
    n = len(template)
    body = template[: n - 4 - SIGNATURE_BYTES - FRESHNESS_BYTES] + freshness.pack()
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
    """The receiving side: replay windows, budgets and signature checks, per bundle sender.

    Every table is bounded: windows and known addresses by the bundle's size (only bundle
    prefixes get here, and only after verifying), new-address buckets by
    ``MAX_NEW_ADDRESSES``. ``counters`` counts each refusal and each verification run."""

    def __init__(self, keyring: KeyRing, now: float) -> None:
        self._keyring = keyring
        self._windows: dict[bytes, ReplayWindow] = {}
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
        self._sender = BucketTable[bytes](SENDER_RATE, SENDER_BURST, max(1, keyring.size))
        self._new_address = BucketTable[tuple[bytes, str, int]](
            NEW_ADDRESS_RATE, NEW_ADDRESS_BURST, MAX_NEW_ADDRESSES
        )
        self._global = TokenBucket(GLOBAL_NEW_ADDRESS_RATE, GLOBAL_NEW_ADDRESS_BURST, now)
        self.counters: dict[str, int] = {r.value: 0 for r in Refusal}
        self.counters["auth_verified"] = 0

    def check(
        self, prefix: bytes, data: bytes, source: tuple[str, int], now: float
    ) -> Freshness | Refusal:
        """The freshness of a datagram whose authenticator holds, or why it was refused.

        On success the sender's window has accepted the freshness: the caller must not
        count the same datagram twice. ``prefix`` must be a bundle participant's."""
        if not has_tail(data):
            return self._refuse(Refusal.MISSING)
        window = self._windows.get(prefix)
        if window is not None:
            # the freshness read at its fixed offset from the end: a replay (half of a
            # flood under members' prefixes) is refused before anything is built or copied
            epoch, seq = _FRESHNESS.unpack_from(data, len(data) - _FRESHNESS_FROM_END)
            if not window.is_fresh_at(epoch, seq):
                return self._refuse(Refusal.REPLAYED)
        if self._known.get(prefix) == source:
            if not self._sender.take(prefix, now):
                return self._refuse(Refusal.BUDGET_SENDER)
        else:
            if not self._new_address.take((prefix, *source), now):
                return self._refuse(Refusal.BUDGET_SENDER)
            if not self._global.take(now):
                return self._refuse(Refusal.BUDGET_GLOBAL)
        opened = open_tail(data)
        if opened is None:  # has_tail held: unreachable, but the types need it
            return self._refuse(Refusal.MISSING)
        freshness, signature, signed = opened
        self.counters["auth_verified"] += 1
        if not self._keyring.verify(prefix, signed, signature):
            return self._refuse(Refusal.BAD_SIGNATURE)
        if window is None:
            window = self._windows[prefix] = ReplayWindow()
        window.accept(freshness)
        return freshness

    def note_address(self, prefix: bytes, source: tuple[str, int]) -> None:
        """A datagram from ``prefix`` that ``check`` verified came from ``source`` and was
        used: its later datagrams from there spend the sender's own budget."""
        self._known[prefix] = source

    def high(self, prefix: bytes) -> Freshness | None:
        """The highest freshness verified from ``prefix`` (its epoch is its current life)."""
        window = self._windows.get(prefix)
        return None if window is None else window.high

    def _refuse(self, reason: Refusal) -> Refusal:
        self.counters[reason.value] += 1
        return reason


class SpdpAuth:
    """What the discovery engine needs to authenticate SPDP: seal on send, check on receive.

    ``epoch`` is this node's boot epoch, already durable (``swarmd.auth.epoch``)."""

    def __init__(self, keyring: KeyRing, epoch: int, now: float) -> None:
        self.keyring = keyring
        self.counter = SendCounter(epoch)
        self.verifier = SpdpVerifier(keyring, now)

    @property
    def epoch(self) -> int:
        return self.counter.epoch

    @property
    def own_prefix(self) -> GuidPrefix:
        """The prefix this node signs as (the engine checks it is its own)."""
        return self.keyring.own_prefix

    def seal(self, template: bytes) -> bytes:
        return seal(template, self.counter.next(), self.keyring)

    def check(
        self, prefix: bytes, data: bytes, source: tuple[str, int], now: float
    ) -> Freshness | Refusal:
        return self.verifier.check(prefix, data, source, now)

    def note_address(self, prefix: bytes, source: tuple[str, int]) -> None:
        self.verifier.note_address(prefix, source)
