"""swarmd's SPDP against a live stock Cyclone DDS participant (PyPI cyclonedds 11.0.1).

Each test builds its own two-namespace LAN (Cyclone in host 0, swarmd's sockets in host 1),
so multicast is isolated from the machine and from parallel runs. Cyclone's acceptance is
read from its discovery trace; its packets are decoded with swarmd's codec. See
docs/interop.md for what Cyclone logs and how it answers.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from contextlib import closing
from typing import Final

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from swarmd_lab.netns import Lan

from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import PLACEHOLDER, seal
from swarmd.rtps import (
    BES_SPDP_ONLY,
    VENDORID_SWARMD,
    DecodeError,
    Duration,
    GuidPrefix,
    Header,
    Locator,
    SpdpAlive,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.ports import SPDP_MULTICAST_GROUP, spdp_multicast_port
from swarmd.rtps.spdp import (
    BES_PARTICIPANT_ANNOUNCER,
    BES_PARTICIPANT_DETECTOR,
    BES_PUBLICATION_ANNOUNCER,
    BES_PUBLICATION_DETECTOR,
    BES_SUBSCRIPTION_ANNOUNCER,
    BES_SUBSCRIPTION_DETECTOR,
)
from swarmd.rtps.types import VENDORID_CYCLONE
from tests.conftest import CycloneFactory
from tests.peers.cyclone import (
    own_participant_pattern,
    spdp_deleted_pattern,
    spdp_new_pattern,
)
from tests.peers.udp import group_listener, receive_until, unicast_socket

pytestmark = [pytest.mark.netns, pytest.mark.interop]

OUR_PREFIX: Final = GuidPrefix(bytes.fromhex("5357a11ce0000000000000a1"))
META_PORT: Final = 7410
DATA_PORT: Final = 7411
LEASE: Final = Duration(20)
ENTITY_NAME: Final = "uav_1/swarmd"
DIGEST: Final = bytes(range(32))
HEARD: Final = b"\x05\x01"
LINK_QUALITY: Final = 870
# Cyclone answers within milliseconds and repeats at 1 s; a generous bound, never asserted on
WAIT_S: Final = 5.0
SEDP_BITS: Final = (
    BES_PUBLICATION_ANNOUNCER
    | BES_PUBLICATION_DETECTOR
    | BES_SUBSCRIPTION_ANNOUNCER
    | BES_SUBSCRIPTION_DETECTOR
)


def swarmd_participant(address: str) -> SpdpParticipant:
    return SpdpParticipant(
        OUR_PREFIX,
        vendor_id=VENDORID_SWARMD,
        domain_id=0,
        metatraffic_unicast_locators=(Locator.udpv4(address, META_PORT),),
        default_unicast_locators=(Locator.udpv4(address, DATA_PORT),),
        lease_duration=LEASE,
        builtin_endpoints=BES_SPDP_ONLY,
        entity_name=ENTITY_NAME,
        bundle_digest=DIGEST,
        heard=HEARD,
        link_quality_permille=LINK_QUALITY,
        authenticator=PLACEHOLDER,
    )


# swarmd signs every SPDP datagram (PID 0x8a04 last, swarmd.auth.spdp): Cyclone must still
# take it for an ordinary participant, and act on the signed dispose
SIGNER: Final = Ed25519PrivateKey.from_private_bytes(b"\x05" * 32)


def sealed(template: bytes, seq: int) -> bytes:
    return seal(template, Freshness(int(time.time()), seq), SIGNER)


def wall_time() -> Duration:
    return Duration.from_seconds(time.time())


Accept = Callable[[bytes, tuple[str, int]], tuple[Header, SpdpAlive] | None]


def first_alive_from(prefix: GuidPrefix, *, directed_to: GuidPrefix | None = None) -> Accept:
    """An ``accept`` for ``receive_until``: (header, SpdpAlive) from ``prefix``, else None."""

    def accept(data: bytes, source: tuple[str, int]) -> tuple[Header, SpdpAlive] | None:
        try:
            header, samples = decode_spdp(data)
        except DecodeError as exc:
            raise AssertionError(
                f"swarmd cannot decode Cyclone's datagram from {source}: {exc}"
            ) from exc
        if header.guid_prefix != prefix:
            return None
        for sample in samples:
            if isinstance(sample, SpdpAlive) and sample.destination == directed_to:
                return header, sample
        return None

    return accept


def cyclone_meta_unicast(announced: SpdpAlive) -> tuple[str, int]:
    locators = announced.participant.metatraffic_unicast_locators
    assert locators, "Cyclone's DATA(p) lists no metatraffic unicast locator"
    return locators[0].sockaddr()


@pytest.mark.parametrize("delivery", ["multicast", "unicast"])
def test_cyclone_accepts_swarmd_participant_then_its_dispose(
    lan2: Lan, cyclone_factory: CycloneFactory, delivery: str
) -> None:
    cyclone_ns, our_ns = lan2[0], lan2[1]
    with (
        closing(group_listener(our_ns)) as listener,
        closing(unicast_socket(our_ns, META_PORT)) as sock,
    ):
        cyclone = cyclone_factory(cyclone_ns)
        if delivery == "multicast":
            destination = (SPDP_MULTICAST_GROUP, spdp_multicast_port(0))
        else:
            # Cyclone 11 picks an ephemeral unicast port (ParticipantIndex "none"): learn it
            # from its own DATA(p), as any peer would.
            announced = receive_until(listener, first_alive_from(cyclone.prefix), WAIT_S)
            assert announced is not None, "no DATA(p) from Cyclone on 239.255.0.1:7400"
            destination = cyclone_meta_unicast(announced[1])

        ours = swarmd_participant(our_ns.address)
        sock.sendto(
            sealed(encode_spdp(ours, sequence_number=1, timestamp=wall_time()), 1), destination
        )

        accepted = cyclone.trace.wait_for(
            spdp_new_pattern(OUR_PREFIX), WAIT_S, f"SPDP ST0 {OUR_PREFIX}:1c1 ... NEW"
        )
        assert accepted["bes"] == f"{BES_SPDP_ONLY:x}"
        assert f"meta udp/{our_ns.address}:{META_PORT}" in accepted["locators"]
        assert f"data udp/{our_ns.address}:{DATA_PORT}" in accepted["locators"]
        assert f"liveliness=0:{LEASE.seconds * 1_000_000_000}" in accepted["qos"]
        assert f'entity_name="{ENTITY_NAME}"' in accepted["qos"]
        # a stock peer never starts SEDP with a participant that has no SEDP endpoints
        assert not any(
            re.search(rf"{re.escape(str(OUR_PREFIX))}:[34]c[27]", line) and "SEDP" in line
            for line in cyclone.trace.lines()
        )

        # Cyclone answers a non-directed DATA(p) with its own, directed to us (INFO_DST)
        reply = receive_until(
            sock,
            first_alive_from(cyclone.prefix, directed_to=OUR_PREFIX),
            WAIT_S,
        )
        assert reply is not None, (
            f"no directed DATA(p) from Cyclone to {our_ns.address}:{META_PORT}"
        )
        header, alive = reply
        assert header.vendor_id == VENDORID_CYCLONE
        assert alive.destination == OUR_PREFIX
        assert alive.participant.guid_prefix == cyclone.prefix
        assert alive.participant.metatraffic_unicast_locators[0].host == cyclone_ns.address

        dispose = encode_spdp_dispose(
            OUR_PREFIX, sequence_number=2, timestamp=wall_time(), authenticator=PLACEHOLDER
        )
        sock.sendto(sealed(dispose, 2), destination)
        cyclone.trace.wait_for(
            spdp_deleted_pattern(OUR_PREFIX), WAIT_S, f"SPDP ST3 {OUR_PREFIX}:1c1 ... deleting"
        )


def test_swarmd_decodes_live_cyclone_spdp(lan2: Lan, cyclone_factory: CycloneFactory) -> None:
    cyclone_ns, our_ns = lan2[0], lan2[1]
    with closing(group_listener(our_ns)) as listener:
        cyclone = cyclone_factory(cyclone_ns)
        got = receive_until(listener, first_alive_from(cyclone.prefix), WAIT_S)
    assert got is not None, "no DATA(p) from Cyclone on 239.255.0.1:7400"
    header, alive = got
    p = alive.participant

    # identity: the prefix Cyclone's trace gives its own participant
    own = cyclone.trace.wait_for(
        own_participant_pattern(cyclone.prefix), WAIT_S, f"PARTICIPANT {cyclone.prefix}:1c1"
    )
    assert any(
        f"ddsi_new_participant({cyclone.prefix}:1c1" in line for line in cyclone.trace.lines()
    )
    assert header.guid_prefix == p.guid_prefix == cyclone.prefix
    assert header.vendor_id == p.vendor_id == VENDORID_CYCLONE
    assert str(p.vendor_id) == "01.10"
    # Cyclone 11 says 2.5; the spec and Cyclone's own receiver accept 2.1 and later
    assert (p.protocol_version.major, p.protocol_version.minor) >= (2, 1)
    assert p.protocol_version.major == 2
    assert not p.is_swarmd and p.bundle_digest is None

    # Cyclone's defaults: lease 10 s, in the trace as liveliness in ns
    assert p.lease_duration == Duration(10)
    assert "liveliness=0:10000000000" in own["qos"]
    assert p.domain_id == 0
    spdp_and_sedp = BES_PARTICIPANT_ANNOUNCER | BES_PARTICIPANT_DETECTOR | SEDP_BITS
    assert p.builtin_endpoints & spdp_and_sedp == spdp_and_sedp

    # locators: unicast on namespace A's address, multicast the standard group and ports
    unicast = p.metatraffic_unicast_locators + p.default_unicast_locators
    assert unicast and all(loc.host == cyclone_ns.address for loc in unicast)
    assert [str(loc) for loc in p.metatraffic_multicast_locators] == ["udp/239.255.0.1:7400"]
    assert [str(loc) for loc in p.default_multicast_locators] == ["udp/239.255.0.1:7401"]

    # the process properties Cyclone adds, matching what its trace says about itself
    props = dict(p.properties)
    assert f'"__Pid":"{props["__Pid"]}"' in own["qos"]
    assert props["__ProcessName"] == "python"
    assert alive.destination is None and alive.sequence_number >= 1
    assert alive.timestamp is not None
