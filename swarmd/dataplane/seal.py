"""The authenticator on every user-data datagram: a swarmd vendor submessage at the end.

Issue 10: no host without the bundle's keys may move a data plane (a forged TAKEOFF, a
HEARTBEAT jump, a GAP, an ACKNACK, a readiness row), and a captured datagram must never
count twice. Every datagram a ``DataPlane`` sends to a peer ends with one submessage::

    0      1      2             4                8                12                  28
    | 0x8a | flags| length = 24 | sender epoch   | sender seq     | tag (16 octets)    |
           flags = E (bit 0, always set: little-endian) | (receiver epoch mod 128) << 1

* ``0x8a`` is a vendor-specific submessage id (DDSI-RTPS 2.5 section 9.4.5.1.1: 0x80..0xff,
  meaning fixed by the header's vendor id, swarmd's 53.57); stock stacks skip it (section
  8.3.4.1) and Wireshark shows it as "Vendor-specific (0x8a)" without expert info.
* ``sender epoch, sender seq`` is the sender's ``Freshness`` (``swarmd.auth.freshness``):
  its persisted boot epoch and a counter per (sender, receiver) pair that starts at 1 in
  every epoch. The receiver keeps a ``ReplayWindow`` per sender.
* ``tag`` = HMAC-SHA256(K, receiver prefix ‖ receiver epoch (u32 BE) ‖ every octet of the
  datagram before the tag) truncated to 16 octets (RFC 2104, truncation per RFC 4868 / NIST
  SP 800-107: 128 bits), with K = HMAC-SHA256(pair key, ``LABEL``): the pairwise key from the
  bundle (static X25519 + HKDF, ``KeyRing.pair_key``), separated from any other use of it.

What the tag binds: the RTPS header (so the sender's GUID prefix), every submessage, the
freshness, and two values that are not on the wire: the receiver's GUID prefix (so no
INFO_DST is needed, see docs/wire.md) and the **receiver's current epoch** as the sender
learned it from the receiver's authenticated SPDP. A datagram captured before the receiver
restarted was made for its old epoch and can never verify again, even if the receiver lost
every replay window with its state. The low 7 bits of that epoch ride in the flags so the
receiver can tell "made for my previous life" from a forgery without computing a tag.

Why HMAC-SHA256 and not Poly1305 (docs/security.md): the standard library has it (no new
dependency on the drone), it needs no per-message key or nonce, and a repeated input
(a sender whose epoch did not grow) degrades it to a replay, never to a forgery, whereas a
Poly1305 one-time key used twice gives the key away.

Sans-IO: bytes in, bytes out; no clock, no randomness.
"""

from __future__ import annotations

import hmac
import struct
from dataclasses import dataclass
from typing import Final

from swarmd.auth.freshness import Freshness
from swarmd.rtps.message import FLAG_E, HEADER_SIZE
from swarmd.rtps.types import GuidPrefix

AUTH_SUBMESSAGE_ID: Final = 0x8A  # vendor-specific range (0x80..0xff), like the 0x8a0x PIDs
TAG_BYTES: Final = 16
FRESHNESS_BYTES: Final = 8
AUTH_BODY_BYTES: Final = FRESHNESS_BYTES + TAG_BYTES  # octetsToNextHeader of the trailer
TRAILER_BYTES: Final = 4 + AUTH_BODY_BYTES  # what authentication adds to a datagram: 28
# What authentication adds to each datagram: the trailer, less the INFO_DST it replaces
# (4-octet submessage header + 12-octet GUID prefix). The simulator models user data with it.
INFO_DST_BYTES: Final = 4 + 12
NET_OVERHEAD_BYTES: Final = TRAILER_BYTES - INFO_DST_BYTES
EPOCH_HINT_MASK: Final = 0x7F  # flags bits 1..7 carry the receiver epoch mod 128
LABEL: Final = b"swarmd user data v1"  # domain separation of the pair key (HMAC, RFC 2104)

_TRAILER_HEAD = struct.Struct("<BBHII")  # id, flags, octetsToNextHeader, epoch, seq
_EPOCH = struct.Struct(">I")


@dataclass(frozen=True, slots=True)
class Trailer:
    """The authenticator's fields, read without any cryptography (cheap checks first)."""

    freshness: Freshness
    epoch_hint: int  # receiver epoch mod 128, as the sender believed it


def user_data_key(pair_key: bytes) -> hmac.HMAC:
    """The MAC state for one peer: HMAC-SHA256 keyed with a label-separated sub-key.

    Returned as a prepared ``hmac.HMAC`` whose ``copy()`` skips re-hashing the key pads for
    every datagram (about 40 % of the cost of a one-shot HMAC of a readiness datagram)."""
    sub_key = hmac.digest(pair_key, LABEL, "sha256")
    return hmac.new(sub_key, digestmod="sha256")


def _tag(key: hmac.HMAC, receiver: GuidPrefix, receiver_epoch: int, body: bytes) -> bytes:
    mac = key.copy()
    mac.update(receiver.value)
    mac.update(_EPOCH.pack(receiver_epoch))
    mac.update(body)
    return mac.digest()[:TAG_BYTES]


def seal(
    key: hmac.HMAC,
    message: bytes,
    freshness: Freshness,
    receiver: GuidPrefix,
    receiver_epoch: int,
) -> bytes:
    """``message`` (an RTPS message for ``receiver``) with the authenticator appended."""
    flags = FLAG_E | ((receiver_epoch & EPOCH_HINT_MASK) << 1)
    body = message + _TRAILER_HEAD.pack(
        AUTH_SUBMESSAGE_ID, flags, AUTH_BODY_BYTES, freshness.epoch, freshness.seq
    )
    return body + _tag(key, receiver, receiver_epoch, body)


def peek_trailer(data: bytes) -> Trailer | None:
    """The trailer's fields if ``data`` ends with a well-formed one after an RTPS header;
    None otherwise. Reads 12 octets: no decoding, no cryptography."""
    if len(data) < HEADER_SIZE + TRAILER_BYTES:
        return None
    sm_id, flags, length, epoch, seq = _TRAILER_HEAD.unpack_from(data, len(data) - TRAILER_BYTES)
    if sm_id != AUTH_SUBMESSAGE_ID or not flags & FLAG_E or length != AUTH_BODY_BYTES:
        return None
    return Trailer(Freshness(epoch, seq), flags >> 1)


def verify(key: hmac.HMAC, data: bytes, receiver: GuidPrefix, receiver_epoch: int) -> bool:
    """Whether ``data``'s tag is the one ``key``'s holder made for ``receiver`` in
    ``receiver_epoch``. Constant-time comparison (``hmac.compare_digest``)."""
    if len(data) < HEADER_SIZE + TRAILER_BYTES:
        return False
    body, tag = data[:-TAG_BYTES], data[-TAG_BYTES:]
    return hmac.compare_digest(_tag(key, receiver, receiver_epoch, body), tag)


def protected_part(data: bytes) -> bytes:
    """The RTPS message the trailer protects (the datagram without the trailer)."""
    return data[:-TRAILER_BYTES]
