"""MAVLink 2 message signing for the PX4 link: the per-drone key, signing, verifying.

MAVLink spec, "Message Signing" (mavlink.io/en/guide/message_signing.html): a signed frame
sets incompatibility flag 0x01 and carries 13 more bytes, ``link_id`` (1), ``timestamp``
(6, little-endian, 10 µs units since 2015-01-01 UTC) and ``signature`` (6) = the first 48
bits of SHA-256(secret_key + header + payload + CRC + link_id + timestamp). A receiver
refuses a timestamp not newer than the last one accepted on the same stream
``(link_id, system, component)``, and a new stream more than one minute behind its own clock.
We add one rule: a frame must be newer than everything its sender (system, component)
signed so far, on any link id. PX4 signs all its links with one key and one clock, so
without it a frame recorded on another of its links (a telemetry radio) and written onto
ours up to a minute late would start a stream and arrive fresh, and that stream would go
on taking the recording (docs/px4.md, "Fresh state"; docs/security.md, the PX4 link's
residuals). swarmd hears PX4 on one link, so its frames come in their signing order.

Why our own verifier and not pymavlink's ``check_signature``: pymavlink records a stream's
timestamp *before* it compares the signature, so one forged frame with a wrong signature
and timestamp 2^48-1 makes it refuse every later genuine frame of that stream (the
"jump the sequence number" attack of issue 10, on the PX4 link). Here a stream's timestamp
moves only on a frame whose signature checked. pymavlink still signs what we send
(``MAVLink.signing``, ``sign_packet``), which is the spec's construction.

The key: 32 bytes per drone, HKDF-SHA256 from the node's secret (the Ed25519 seed in the
``node.key`` that ``swarmctl bundle flash`` installs) with a label that names its one use.
The ground station derives the same key from ``keys/nodes/<name>.key`` to provision PX4
(``SETUP_SIGNING`` or the SD-card key file, docs/px4.md); nothing crosses the air.

Pure: no clock, no socket. Callers pass the current MAVLink timestamp.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

KEY_BYTES: Final = 32
SIGNATURE_BLOCK: Final = 13  # link_id (1) + timestamp (6) + signature (6)
IFLAG_SIGNED: Final = 0x01
EPOCH_2015_UNIX: Final = 1_420_070_400  # 2015-01-01T00:00:00Z, the signing epoch
TICKS_PER_S: Final = 100_000  # 10 µs units
NEW_STREAM_WINDOW: Final = 60 * TICKS_PER_S  # spec: a new stream may lag us by one minute
TIMESTAMP_MAX: Final = (1 << 48) - 1
PX4_KEY_FILE_BYTES: Final = 40  # PX4 /mavlink/mavlink-signing-key.bin: key + u64 LE timestamp
_LABEL: Final = b"swarmd px4 mavlink-signing key v1"


def derive_key(node_secret: bytes, swarm: str, node: str) -> bytes:
    """The drone's 32-byte MAVLink signing key from its node secret (HKDF-SHA256, RFC 5869).

    ``info`` binds the swarm and node names, so one node secret reused across swarms (or a
    renamed node) yields unrelated keys; the salt is a fixed label naming this one use, so
    the key says nothing about the node's Ed25519 signing key it comes from.
    """
    if len(node_secret) < KEY_BYTES:
        raise ValueError("node secret shorter than 32 bytes")
    info = b"swarm=" + swarm.encode() + b"\0node=" + node.encode()
    hkdf = HKDF(algorithm=hashes.SHA256(), length=KEY_BYTES, salt=_LABEL, info=info)
    return hkdf.derive(node_secret)


def timestamp_from_unix(unix_s: float) -> int:
    """The MAVLink signing timestamp (10 µs since 2015-01-01) for a Unix time."""
    return max(0, min(TIMESTAMP_MAX, int((unix_s - EPOCH_2015_UNIX) * TICKS_PER_S)))


def px4_key_file(key: bytes, timestamp: int) -> bytes:
    """PX4's ``/mavlink/mavlink-signing-key.bin``: the 32-byte key, then a u64 LE timestamp."""
    if len(key) != KEY_BYTES:
        raise ValueError("a MAVLink signing key is 32 bytes")
    return key + struct.pack("<Q", timestamp)


def parse_key_file(data: bytes, source: str) -> bytes:
    """A key file: PX4's 40-byte format, 32 raw bytes, or 64 hex digits (one line)."""
    if len(data) in (KEY_BYTES, PX4_KEY_FILE_BYTES):
        key = data[:KEY_BYTES]
    else:
        try:
            key = bytes.fromhex(data.decode("ascii").strip())
        except (UnicodeDecodeError, ValueError):
            key = b""
    if len(key) != KEY_BYTES:
        raise ValueError(
            f"{source}: not a MAVLink signing key (PX4's 40-byte key file, 32 raw bytes or "
            "64 hex digits); fix: 'swarmctl px4-key' writes one"
        )
    if key == bytes(KEY_BYTES):
        raise ValueError(f"{source}: the all-zero key means 'signing off' to PX4; fix: a real key")
    return key


def frame_signature(key: bytes, signed_part: bytes) -> bytes:
    """The 6-byte signature over a frame minus its last 6 bytes (spec: "Signature")."""
    return hashlib.sha256(key + signed_part).digest()[:6]


class Verdict(StrEnum):
    OK = "ok"
    UNSIGNED = "unsigned"
    BAD_SIGNATURE = "bad_signature"
    REPLAYED = "replayed"  # not newer than the stream's last, or a new stream too far behind


@dataclass(slots=True)
class Verifier:
    """Checks signed frames against one key; per-stream timestamps move only on a good one.

    ``timestamp`` is our clock: the caller raises it to the wall clock (``advance``), and a
    good frame raises it to that frame's timestamp (spec: "Timestamp handling").
    """

    key: bytes
    timestamp: int = 0
    streams: dict[tuple[int, int, int], int] = field(default_factory=dict)
    # (system, component) -> the newest timestamp it signed on any link (module docstring)
    newest: dict[tuple[int, int], int] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=lambda: {v.value: 0 for v in Verdict})

    def advance(self, timestamp: int) -> None:
        self.timestamp = max(self.timestamp, timestamp)

    def check(self, frame: bytes, src_system: int, src_component: int) -> Verdict:
        """The verdict on one whole MAVLink 2 frame (header .. signature), counted."""
        verdict = self._check(frame, src_system, src_component)
        self.counts[verdict.value] += 1
        return verdict

    def _check(self, frame: bytes, src_system: int, src_component: int) -> Verdict:
        if len(frame) < 10 + 2 + SIGNATURE_BLOCK or frame[0] != 0xFD:
            return Verdict.UNSIGNED  # MAVLink 1 has no signature
        if not frame[2] & IFLAG_SIGNED:
            return Verdict.UNSIGNED
        link_id = frame[-13]
        stamp = int.from_bytes(frame[-12:-6], "little")
        if not hmac.compare_digest(frame_signature(self.key, frame[:-6]), frame[-6:]):
            return Verdict.BAD_SIGNATURE  # checked first: a forgery moves no stream
        stream = (link_id, src_system, src_component)
        last = self.streams.get(stream)
        if last is not None and stamp <= last:
            return Verdict.REPLAYED
        if last is None and stamp + NEW_STREAM_WINDOW < self.timestamp:
            return Verdict.REPLAYED
        sender = (src_system, src_component)
        if stamp <= self.newest.get(sender, -1):
            return Verdict.REPLAYED  # another link's frame, older than what we heard
        self.streams[stream] = stamp
        self.newest[sender] = stamp
        self.timestamp = max(self.timestamp, stamp)
        return Verdict.OK
