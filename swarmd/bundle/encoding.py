"""The canonical byte encoding of a firmware bundle (documented in docs/bundle-format.md).

::

    offset  size  field
    0       4     magic "SWB1"
    4       2     format version (u16 big-endian) = 2 (1: before X25519 node keys, refused)
    6       2     flags (u16 BE): bit 0 = DEV (signed with the public dev key)
    8       4     body length L (u32 BE)
    12      32    content SHA-256 = SHA-256(body)
    44      32    signer: raw Ed25519 public key of the swarm signing key
    76      L     body: canonical JSON (UTF-8, sorted keys, no whitespace, ASCII only)
    76+L    64    Ed25519 signature over bytes [0, 76+L) (header and body)

The body is a pure function of the bundle model, so the same mission always gives the same
bytes (Ed25519 signatures are deterministic, RFC 8032 5.1.6). Durations are integer
milliseconds so no float formatting enters the canonical form. The content hash covers the
body only: it names *what* the swarm agreed on and is what drones compare over the air
(SPDP ``bundle_digest``); the signature additionally binds the header, hence the signer.
"""

from __future__ import annotations

import hashlib
import json
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.keys import raw_public
from swarmd.bundle.model import (
    Bundle,
    DiscoveryParams,
    Endpoint,
    Participant,
    Topic,
)
from swarmd.bundle.ros2 import Ros2Graph, graph_value, ros2_participants

MAGIC: Final = b"SWB1"
FORMAT_VERSION: Final = 2
# format 1 had no per-node X25519 key; it still splits, so the loader can say what to do
LEGACY_FORMAT_VERSIONS: Final = frozenset({1})
FLAG_DEV: Final = 0x0001
KNOWN_FLAGS: Final = FLAG_DEV
_HEADER: Final = struct.Struct(">4sHHI32s32s")
HEADER_SIZE: Final = _HEADER.size  # 76
SIGNATURE_SIZE: Final = 64
MIN_SIZE: Final = HEADER_SIZE + SIGNATURE_SIZE
# a 500-drone bundle is ~0.4 MB; this cap keeps a corrupt length field from asking for gigabytes
MAX_BODY_BYTES: Final = 64 * 1024 * 1024

OFFSET_MAGIC: Final = 0
OFFSET_VERSION: Final = 4
OFFSET_FLAGS: Final = 6
OFFSET_LENGTH: Final = 8
OFFSET_SHA256: Final = 12
OFFSET_SIGNER: Final = 44


def canonical_json(value: Any) -> bytes:
    """Sorted keys, no whitespace, ASCII escapes, no NaN: one byte string per value."""
    return json.dumps(
        value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False
    ).encode("ascii")


def seconds_to_ms(seconds: float) -> int:
    return round(seconds * 1000)


def body_value(
    swarm: str,
    domain_id: int,
    discovery: DiscoveryParams,
    topics: tuple[Topic, ...],
    participants: tuple[Participant, ...],
    ports: Mapping[int, tuple[int, int]],
    ros2: Ros2Graph | None = None,
    serial: int | None = None,
) -> dict[str, Any]:
    """The JSON value of a bundle body; ``ports`` maps index -> (metatraffic, user) port.
    A mission without a ROS 2 graph has no ``ros2`` key, so its bytes (and content hash)
    are what they were before ROS 2 graphs existed. ``serial`` (docs/bundle-format.md,
    "Serial") is in the body, so the content hash and the signature cover it; None (only
    for re-encoding a bundle built before serials) leaves the key out."""
    value = {
        "swarm": swarm,
        "domain_id": domain_id,
        "discovery": {
            "t_min_ms": seconds_to_ms(discovery.t_min_s),
            "t_max_ms": seconds_to_ms(discovery.t_max_s),
            "lease_ms": seconds_to_ms(discovery.lease_s),
        },
        "topics": [
            {
                "index": t.index,
                "name": t.name,
                "type_name": t.type_name,
                "reliability": t.qos.reliability.value,
                "durability": t.qos.durability.value,
                "history_depth": t.qos.history_depth,
                "liveliness": t.qos.liveliness.value,
                "liveliness_lease_ms": (
                    None
                    if t.qos.liveliness_lease_s is None
                    else seconds_to_ms(t.qos.liveliness_lease_s)
                ),
            }
            for t in topics
        ],
        "participants": [
            {
                "name": p.name,
                "index": p.index,
                "role": p.role.value,
                "mavlink_sysid": p.mavlink_sysid,
                "ipv4": p.ipv4,
                "guid_prefix": p.guid_prefix.value.hex(),
                "metatraffic_unicast_port": ports[p.index][0],
                "user_unicast_port": ports[p.index][1],
                "announce_public_key": p.announce_public_key.hex(),
                "x25519_public_key": p.x25519_public_key.hex(),
                "endpoints": [_endpoint_value(e) for e in p.endpoints],
            }
            for p in participants
        ],
    }
    if ros2 is not None:
        indices = {p.name: p.index for p in participants}
        value["ros2"] = graph_value(ros2, ros2_participants(swarm, indices, ros2))
    if serial is not None:
        value["serial"] = serial
    return value


def _endpoint_value(e: Endpoint) -> dict[str, Any]:
    return {"topic": e.topic, "kind": e.kind.value, "entity_id": e.entity_id.value.hex()}


def encode_body(bundle: Bundle) -> bytes:
    """The canonical body of an existing bundle model (round-trip: equals the loaded body)."""
    ports = {
        p.index: (bundle.metatraffic_port(p), bundle.user_port(p)) for p in bundle.participants
    }
    return canonical_json(
        body_value(
            bundle.swarm,
            bundle.domain_id,
            bundle.discovery,
            bundle.topics,
            bundle.participants,
            ports,
            bundle.ros2,
            bundle.serial,
        )
    )


def seal(body: bytes, signing_key: Ed25519PrivateKey, *, dev: bool = False) -> bytes:
    """Header + body + signature: the complete bundle file."""
    if len(body) > MAX_BODY_BYTES:
        raise ValueError(f"bundle body of {len(body)} bytes exceeds {MAX_BODY_BYTES}")
    header = _HEADER.pack(
        MAGIC,
        FORMAT_VERSION,
        FLAG_DEV if dev else 0,
        len(body),
        hashlib.sha256(body).digest(),
        raw_public(signing_key),
    )
    signed = header + body
    return signed + signing_key.sign(signed)


@dataclass(frozen=True, slots=True)
class Envelope:
    """The fields of a bundle file, split but not yet trusted."""

    version: int
    flags: int
    content_sha256: bytes
    signer: bytes
    body: bytes
    signature: bytes
    signed: bytes  # header + body: what the signature covers

    @property
    def dev(self) -> bool:
        return bool(self.flags & FLAG_DEV)


class EnvelopeError(ValueError):
    """The bytes are not a well-formed bundle; the message says what is wrong."""


def split(data: bytes) -> Envelope:
    """Check the framing (magic, version, flags, lengths) and cut the file into its parts."""
    if len(data) < MIN_SIZE:
        raise EnvelopeError(f"truncated: {len(data)} bytes, a bundle has at least {MIN_SIZE}")
    magic, version, flags, length, digest, signer = _HEADER.unpack_from(data, 0)
    if magic != MAGIC:
        raise EnvelopeError(f"not a swarmd bundle (magic {magic!r}, expected {MAGIC!r})")
    if version != FORMAT_VERSION and version not in LEGACY_FORMAT_VERSIONS:
        raise EnvelopeError(
            f"unsupported bundle format version {version} (this is {FORMAT_VERSION})"
        )
    if flags & ~KNOWN_FLAGS:
        raise EnvelopeError(f"unknown header flags 0x{flags:04x}")
    if length > MAX_BODY_BYTES:
        raise EnvelopeError(f"body length {length} exceeds {MAX_BODY_BYTES}")
    expected = HEADER_SIZE + length + SIGNATURE_SIZE
    if len(data) < expected:
        raise EnvelopeError(f"truncated: {len(data)} bytes, the header announces {expected}")
    if len(data) > expected:
        raise EnvelopeError(f"{len(data) - expected} trailing bytes after the signature")
    end = HEADER_SIZE + length
    return Envelope(
        version=version,
        flags=flags,
        content_sha256=digest,
        signer=signer,
        body=data[HEADER_SIZE:end],
        signature=data[end:],
        signed=data[:end],
    )
