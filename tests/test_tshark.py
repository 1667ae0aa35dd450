"""Wireshark (tshark 4.0.x) dissects swarmd's SPDP cleanly and reads the fields we wrote.

Wireshark's RTPS dissector is an implementation independent of swarmd: if it names every
submessage, raises no expert info and reads back each field, stock tools and captures in
the field will show swarmd as an ordinary RTPS participant.
"""

from __future__ import annotations

import dataclasses
import random
import string
from pathlib import Path
from typing import Final

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.auth.freshness import Freshness
from swarmd.auth.spdp import PLACEHOLDER, seal
from swarmd.rtps import (
    BES_SPDP_ONLY,
    VENDORID_SWARMD,
    Duration,
    GuidPrefix,
    Locator,
    SpdpParticipant,
    Time,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.ports import (
    SPDP_MULTICAST_GROUP,
    metatraffic_unicast_port,
    spdp_multicast_port,
    user_multicast_port,
    user_unicast_port,
)
from tests.peers.tshark import (
    Datagram,
    decoded_view,
    dissect_fields,
    dissect_tree,
    dissect_verbose,
    spdp_view,
    tshark_path,
    write_pcap,
)

pytestmark = [
    pytest.mark.interop,
    pytest.mark.skipif(tshark_path() is None, reason="tshark not installed (scripts/setup.sh)"),
]

PREFIX: Final = GuidPrefix(bytes.fromhex("5357a11ce0000000000000a1"))
PEER: Final = GuidPrefix(bytes.fromhex("011030df694f9d47a4a979c8"))
HOST: Final = "10.77.1.2"
PEER_HOST: Final = "10.77.1.1"
STAMP: Final = Time(1_795_250_000, 1 << 31)
FIELDS: Final = [
    "_ws.col.Info",
    "_ws.expert",
    "_ws.expert.severity",
    "_ws.malformed",
    "rtps.guidPrefix.src",
    "rtps.guidPrefix.dst",
    "rtps.vendorId",
    "rtps.param.entityName",
    "rtps.param.ntpTime.sec",
    "rtps.locator.ipv4",
    "rtps.locator.port",
    "rtps.param.builtin_endpoint_set",
    "rtps.sm.seqNumber",
    "rtps.param.status_info",
]


def participant() -> SpdpParticipant:
    return SpdpParticipant(
        PREFIX,
        vendor_id=VENDORID_SWARMD,
        domain_id=0,
        metatraffic_unicast_locators=(Locator.udpv4(HOST, metatraffic_unicast_port(0, 0)),),
        default_unicast_locators=(Locator.udpv4(HOST, user_unicast_port(0, 0)),),
        lease_duration=Duration(20),
        builtin_endpoints=BES_SPDP_ONLY,
        entity_name="uav_1/swarmd",
        bundle_digest=bytes(range(32)),
        heard=b"\x05\x01",
        link_quality_permille=870,
    )


SIGNER: Final = Ed25519PrivateKey.from_private_bytes(b"\x05" * 32)


def sealed(template: bytes, seq: int) -> bytes:
    """As swarmd sends it: the authenticator (PID 0x8a04) filled in (swarmd.auth.spdp)."""
    return seal(template, Freshness(1_795_250_000, seq), SIGNER)


def three_datagrams() -> list[Datagram]:
    ours = dataclasses.replace(participant(), authenticator=PLACEHOLDER)
    group = (SPDP_MULTICAST_GROUP, spdp_multicast_port(0))
    src = (HOST, metatraffic_unicast_port(0, 0))
    dispose = encode_spdp_dispose(
        PREFIX, sequence_number=2, timestamp=STAMP, authenticator=PLACEHOLDER
    )
    return [
        Datagram(sealed(encode_spdp(ours, sequence_number=1, timestamp=STAMP), 1), src, group),
        Datagram(
            sealed(encode_spdp(ours, sequence_number=1, timestamp=STAMP, destination=PEER), 2),
            src,
            (PEER_HOST, metatraffic_unicast_port(0, 0)),
        ),
        Datagram(sealed(dispose, 3), src, group),
    ]


@pytest.fixture(scope="module")
def dissected(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, list[str]]]]:
    pcap = tmp_path_factory.mktemp("tshark") / "swarmd-spdp.pcap"
    write_pcap(pcap, three_datagrams())
    return pcap, dissect_fields(pcap, FIELDS)


def test_info_column_names_each_spdp_form(
    dissected: tuple[Path, list[dict[str, list[str]]]],
) -> None:
    _, frames = dissected
    assert [f["_ws.col.Info"] for f in frames] == [
        ["INFO_TS, DATA(p)"],
        ["INFO_DST, INFO_TS, DATA(p)"],
        ["INFO_TS, DATA(p[UD])"],
    ]


def test_no_malformed_or_expert_info(dissected: tuple[Path, list[dict[str, list[str]]]]) -> None:
    pcap, frames = dissected
    for frame in frames:
        assert frame["_ws.malformed"] == []
        assert frame["_ws.expert"] == [] and frame["_ws.expert.severity"] == []
    for text in dissect_verbose(pcap):
        assert "Malformed" not in text and "Expert Info" not in text


def test_tshark_reads_back_our_fields(dissected: tuple[Path, list[dict[str, list[str]]]]) -> None:
    pcap, (alive, directed, dispose) = dissected
    for frame in (alive, directed, dispose):
        assert frame["rtps.guidPrefix.src"] == [PREFIX.hex()]
        assert frame["rtps.vendorId"][0] == "0x5357"
    for frame in (alive, directed):
        assert frame["rtps.param.entityName"] == ["uav_1/swarmd"]
        assert frame["rtps.param.ntpTime.sec"] == ["20"]
        assert frame["rtps.locator.ipv4"] == [HOST, HOST]
        assert frame["rtps.locator.port"] == ["7410", "7411"]
        assert frame["rtps.param.builtin_endpoint_set"] == ["0x00000003"]
    assert directed["rtps.guidPrefix.dst"] == [PEER.hex()]
    assert dispose["rtps.param.status_info"] == ["0x00000003"]
    assert dispose["rtps.sm.seqNumber"] == ["2"]
    verbose = dissect_verbose(pcap)
    assert "PID_ENTITY_NAME" in verbose[0] and "entityName: uav_1/swarmd" in verbose[0]
    assert "lease_duration: 20.000000 sec" in verbose[0]


def test_tshark_and_swarmd_decode_identically(
    dissected: tuple[Path, list[dict[str, list[str]]]],
) -> None:
    pcap, _ = dissected
    for dgram, tree in zip(three_datagrams(), dissect_tree(pcap), strict=True):
        _, samples = decode_spdp(dgram.payload)
        assert spdp_view(tree) == [decoded_view(s) for s in samples]


def random_participant(rng: random.Random, index: int) -> SpdpParticipant:
    """A participant exercising the optional fields, locator counts and odd lengths."""
    name_chars = string.ascii_letters + string.digits + "_/.-"

    def locators(port: int, multicast: bool) -> tuple[Locator, ...]:
        count = rng.randrange(0, 3)
        host = SPDP_MULTICAST_GROUP if multicast else f"10.77.{rng.randrange(256)}.{index + 1}"
        return tuple(Locator.udpv4(host, port + i) for i in range(count))

    domain = rng.randrange(0, 5)
    return SpdpParticipant(
        GuidPrefix(b"SW" + rng.randbytes(10)),
        domain_id=domain,
        metatraffic_unicast_locators=locators(metatraffic_unicast_port(domain, index), False),
        metatraffic_multicast_locators=locators(spdp_multicast_port(domain), True),
        default_unicast_locators=locators(user_unicast_port(domain, index), False),
        default_multicast_locators=locators(user_multicast_port(domain), True),
        lease_duration=Duration(rng.randrange(1, 300), rng.randrange(1 << 32)),
        builtin_endpoints=rng.choice([BES_SPDP_ONLY, 0x3F, 0xC3F, 0xFC3F]),
        entity_name=(
            None
            if rng.random() < 0.3
            else "".join(rng.choice(name_chars) for _ in range(rng.randrange(0, 40)))
        ),
        properties=tuple(
            (f"swarmd.key{i}", "".join(rng.choice(name_chars) for _ in range(rng.randrange(9))))
            for i in range(rng.randrange(0, 3))
        ),
        bundle_digest=rng.randbytes(rng.choice([0, 1, 31, 32])) if rng.random() < 0.7 else None,
        heard=rng.randbytes(rng.randrange(0, 9)) if rng.random() < 0.7 else None,
        link_quality_permille=rng.randrange(0, 1001) if rng.random() < 0.7 else None,
    )


def test_tshark_agrees_on_many_varied_participants(tmp_path: Path) -> None:
    rng = random.Random(20250564)
    datagrams = []
    for i in range(40):
        p = random_participant(rng, i)
        destination = PEER if i % 3 == 0 else None
        payload = encode_spdp(p, sequence_number=i + 1, timestamp=STAMP, destination=destination)
        datagrams.append(Datagram(payload, (HOST, 7410), (SPDP_MULTICAST_GROUP, 7400)))
    pcap = tmp_path / "varied.pcap"
    write_pcap(pcap, datagrams)
    frames = dissect_fields(pcap, ["_ws.col.Info", "_ws.expert", "_ws.malformed"])
    for i, (dgram, frame, tree) in enumerate(
        zip(datagrams, frames, dissect_tree(pcap), strict=True)
    ):
        prefix = "INFO_DST, " if i % 3 == 0 else ""
        assert frame["_ws.col.Info"] == [f"{prefix}INFO_TS, DATA(p)"], f"datagram {i}"
        assert frame["_ws.expert"] == [] and frame["_ws.malformed"] == [], f"datagram {i}"
        _, samples = decode_spdp(dgram.payload)
        assert spdp_view(tree) == [decoded_view(s) for s in samples], f"datagram {i}"
