"""swarmd's own golden SPDP packets: the participant they encode and how to regenerate them.

The ``.bin`` files under ``tests/fixtures/swarmd/`` were produced by
``python -m tests.golden_swarmd`` and checked by tshark (see tests/test_tshark.py); the
golden tests assert that today's encoder still produces exactly these bytes, so any wire
change is deliberate. The ``*-signed.bin`` ones are what a daemon sends: the same datagrams
with the authenticator (PID 0x8a04, ``swarmd.auth.spdp``) sealed by ``SIGNING_KEY`` at
``FRESHNESS`` (Ed25519 is deterministic, RFC 8032, so the bytes are fixed too), with the
receiver tags of a 3-node swarm (``TAGS``: two in a multicast datagram, the destination's
in a directed one; fixed tag keys, so the bytes are fixed).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import PLACEHOLDER, seal
from swarmd.auth.tags import compute_tag, tag_block_bytes
from swarmd.rtps import Duration, GuidPrefix, Locator, SpdpParticipant, Time, encode_spdp
from swarmd.rtps.spdp import encode_spdp_dispose

FIXTURES = Path(__file__).parent / "fixtures" / "swarmd"
PREFIX = GuidPrefix(bytes.fromhex("5357968cdf45098f00000003"))
PEER = GuidPrefix(bytes.fromhex("5357968cdf45098f00000001"))
TIMESTAMP = Time(1795247086, 0x80000000)

PARTICIPANT = SpdpParticipant(
    guid_prefix=PREFIX,
    domain_id=0,
    metatraffic_unicast_locators=(Locator.udpv4("10.77.0.3", 7416),),
    metatraffic_multicast_locators=(Locator.udpv4("239.255.0.1", 7400),),
    default_unicast_locators=(Locator.udpv4("10.77.0.3", 7417),),
    lease_duration=Duration(20, 0),
    entity_name="alpha/uav3",
    bundle_digest=bytes(range(16)),
    heard=bytes([0b0000_0101]),
    link_quality_permille=830,
)

SIGNING_KEY = Ed25519PrivateKey.from_private_bytes(bytes(range(32)))
FRESHNESS = Freshness(1795247086, 41)
SIGNED = dataclasses.replace(PARTICIPANT, authenticator=PLACEHOLDER)


class _GoldenTags:
    """Receiver tags of a 3-node swarm under fixed keys (``swarmd.auth.tags.Tagger``)."""

    def slots(self, destination: bytes | None) -> tuple[int, int]:
        return (0, 1) if destination is not None else (0, 2)

    def make(self, start: int, count: int, head: bytes, meta_fresh: bytes) -> bytes:
        keys = [bytes([start + i + 1]) * 32 for i in range(count)]
        block = b"".join(compute_tag(k, head, meta_fresh) for k in keys)
        return block + bytes(tag_block_bytes(count) - len(block))


TAGS = _GoldenTags()

PACKETS: dict[str, bytes] = {
    "spdp-alive.bin": encode_spdp(PARTICIPANT, sequence_number=1, timestamp=TIMESTAMP),
    "spdp-directed.bin": encode_spdp(
        PARTICIPANT, sequence_number=2, timestamp=TIMESTAMP, destination=PEER
    ),
    "spdp-dispose.bin": encode_spdp_dispose(PREFIX, sequence_number=3, timestamp=TIMESTAMP),
    "spdp-alive-signed.bin": seal(
        encode_spdp(SIGNED, sequence_number=1, timestamp=TIMESTAMP), FRESHNESS, SIGNING_KEY, TAGS
    ),
    "spdp-directed-signed.bin": seal(
        encode_spdp(SIGNED, sequence_number=2, timestamp=TIMESTAMP, destination=PEER),
        FRESHNESS,
        SIGNING_KEY,
        TAGS,
    ),
    "spdp-dispose-signed.bin": seal(
        encode_spdp_dispose(
            PREFIX, sequence_number=3, timestamp=TIMESTAMP, authenticator=PLACEHOLDER
        ),
        FRESHNESS,
        SIGNING_KEY,
        TAGS,
    ),
}


def main() -> None:
    FIXTURES.mkdir(parents=True, exist_ok=True)
    for name, data in PACKETS.items():
        (FIXTURES / name).write_bytes(data)
        print(f"wrote {FIXTURES / name} ({len(data)} bytes)")


if __name__ == "__main__":
    main()
