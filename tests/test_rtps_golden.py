"""Golden packets: stock Cyclone DDS 0.10.2 SPDP from the reference capture, and swarmd's own.

Every field is asserted; what swarmd owns is re-encoded and compared byte for byte; every
truncation either raises DecodeError or decodes to the complete submessages before the cut.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from swarmd.auth.spdp import authenticator_overhead, open_tail, tail_window
from swarmd.rtps import (
    Data,
    DecodeError,
    Duration,
    GuidPrefix,
    InfoDst,
    InfoTs,
    Locator,
    ProtocolVersion,
    SpdpAlive,
    SpdpDisposed,
    VendorId,
    decode_message,
    decode_spdp,
    encode_message,
)
from swarmd.rtps.message import HEADER_SIZE
from swarmd.rtps.spdp import BES_SPDP_ONLY
from swarmd.rtps.types import ENTITYID_SPDP_READER, ENTITYID_SPDP_WRITER, ENTITYID_UNKNOWN
from tests import golden_swarmd

CYCLONE = Path(__file__).parent / "fixtures" / "cyclone-0.10.2"
CYCLONE_PREFIX = GuidPrefix(bytes.fromhex("0110f12eb78897fa21779fa5"))


def _load(path: Path) -> bytes:
    return path.read_bytes()


def test_cyclone_alive_every_field() -> None:
    data = _load(CYCLONE / "spdp-alive.bin")
    header, samples = decode_spdp(data)
    assert header.protocol_version == ProtocolVersion(2, 1)
    assert header.vendor_id == VendorId(b"\x01\x10")
    assert header.vendor_id.name == "Eclipse Cyclone DDS"
    assert header.guid_prefix == CYCLONE_PREFIX
    assert str(header.guid_prefix) == "110f12e:b78897fa:21779fa5"

    message = decode_message(data)
    assert [type(sm) for sm in message.submessages] == [InfoTs, Data]
    info_ts, sm = message.submessages
    assert isinstance(info_ts, InfoTs) and info_ts.timestamp is not None
    assert isinstance(sm, Data)
    assert sm.reader_id == ENTITYID_UNKNOWN  # Cyclone 0.10.2 addresses SPDP to "unknown"
    assert sm.writer_id == ENTITYID_SPDP_WRITER
    assert sm.writer_sn == 1
    assert sm.inline_qos is None and not sm.key

    assert len(samples) == 1
    sample = samples[0]
    assert isinstance(sample, SpdpAlive)
    assert sample.sequence_number == 1
    assert sample.destination is None
    assert sample.timestamp == info_ts.timestamp
    p = sample.participant
    assert p.guid_prefix == CYCLONE_PREFIX
    assert p.protocol_version == ProtocolVersion(2, 1)
    assert p.vendor_id == VendorId(b"\x01\x10")
    assert p.domain_id == 0
    assert p.domain_tag is None
    assert p.metatraffic_unicast_locators == (Locator.udpv4("127.0.0.1", 7410),)
    assert p.default_unicast_locators == (Locator.udpv4("127.0.0.1", 7411),)
    assert p.metatraffic_multicast_locators == ()
    assert p.default_multicast_locators == ()
    assert p.lease_duration == Duration(10, 0)
    assert p.builtin_endpoints == 0x0000FC3F
    assert p.entity_name is None
    assert p.user_data == b"DDSPerf:1:16898:vm"
    assert p.properties == (("__ProcessName", "ddsperf"), ("__Pid", "16898"), ("__Hostname", "vm"))
    # Cyclone's own vendor PIDs stay opaque: ADLINK_PARTICIPANT_VERSION_INFO, RECEIVE_BUFFER_SIZE
    assert [x.pid for x in p.extra_parameters] == [0x8007, 0x8019]
    assert b"vm/0.10.2/Linux/Linux" in p.extra_parameters[0].value
    # swarmd's vendor fields are never read from another vendor's packet
    assert p.bundle_digest is None and p.heard is None and p.link_quality_permille is None
    assert not p.is_swarmd


def test_cyclone_dispose_every_field() -> None:
    data = _load(CYCLONE / "spdp-dispose.bin")
    header, samples = decode_spdp(data)
    assert header.guid_prefix == CYCLONE_PREFIX
    message = decode_message(data)
    sm = message.submessages[1]
    assert isinstance(sm, Data)
    assert sm.key  # Cyclone style: flags E|Q|K, key payload, STATUS_INFO only inline
    assert sm.inline_qos is not None
    assert [x.pid for x in sm.inline_qos.params] == [0x0071]
    assert samples == [
        SpdpDisposed(
            CYCLONE_PREFIX,
            sequence_number=2,
            destination=None,
            timestamp=samples[0].timestamp,
        )
    ]


@pytest.mark.parametrize("name", ["spdp-alive.bin", "spdp-dispose.bin"])
def test_cyclone_message_reencodes_byte_exact(name: str) -> None:
    data = _load(CYCLONE / name)
    message = decode_message(data)
    assert encode_message(message.header, message.submessages) == data


@pytest.mark.parametrize("name", sorted(golden_swarmd.PACKETS))
def test_swarmd_golden_bytes_unchanged(name: str) -> None:
    checked_in = _load(golden_swarmd.FIXTURES / name)
    assert golden_swarmd.PACKETS[name] == checked_in


def test_swarmd_golden_alive_decodes_to_participant() -> None:
    _, samples = decode_spdp(_load(golden_swarmd.FIXTURES / "spdp-alive.bin"))
    assert samples == [SpdpAlive(golden_swarmd.PARTICIPANT, 1, None, golden_swarmd.TIMESTAMP)]
    p = golden_swarmd.PARTICIPANT
    assert p.is_swarmd and p.builtin_endpoints == BES_SPDP_ONLY


def test_swarmd_golden_directed_carries_info_dst() -> None:
    data = _load(golden_swarmd.FIXTURES / "spdp-directed.bin")
    message = decode_message(data)
    assert [type(sm) for sm in message.submessages] == [InfoDst, InfoTs, Data]
    sm = message.submessages[2]
    assert isinstance(sm, Data) and sm.reader_id == ENTITYID_SPDP_READER
    _, samples = decode_spdp(data)
    assert samples == [
        SpdpAlive(golden_swarmd.PARTICIPANT, 2, golden_swarmd.PEER, golden_swarmd.TIMESTAMP)
    ]


def test_swarmd_golden_dispose() -> None:
    data = _load(golden_swarmd.FIXTURES / "spdp-dispose.bin")
    sm = decode_message(data).submessages[1]
    assert isinstance(sm, Data) and sm.key and sm.inline_qos is not None
    # both KEY_HASH (Fast DDS reads it) and STATUS_INFO (everyone) inline, reference 1.11
    assert [x.pid for x in sm.inline_qos.params] == [0x0070, 0x0071]
    _, samples = decode_spdp(data)
    assert samples == [SpdpDisposed(golden_swarmd.PREFIX, 3, None, golden_swarmd.TIMESTAMP)]


ALL_GOLDEN = [CYCLONE / "spdp-alive.bin", CYCLONE / "spdp-dispose.bin"] + [
    golden_swarmd.FIXTURES / n for n in sorted(golden_swarmd.PACKETS)
]


def _boundaries(data: bytes) -> list[int]:
    """Offsets at which a submessage ends (where a cut leaves only complete submessages)."""
    out = [HEADER_SIZE]
    pos = HEADER_SIZE
    while pos < len(data):
        length = int.from_bytes(data[pos + 2 : pos + 4], "little" if data[pos + 1] & 1 else "big")
        pos += 4 + length
        out.append(pos)
    return out


@pytest.mark.parametrize("path", ALL_GOLDEN, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_truncation_raises_or_keeps_complete_submessages(path: Path) -> None:
    data = _load(path)
    full = decode_message(data)
    boundaries = _boundaries(data)
    for cut in range(len(data)):
        prefix = data[:cut]
        if cut in boundaries:
            message = decode_message(prefix)
            kept = boundaries.index(cut)
            assert message.submessages == full.submessages[:kept]
            # a cut before the DATA never yields a participant, so no wrong field values
            _, samples = decode_spdp(prefix)
            assert samples == []
        else:
            with pytest.raises(DecodeError):
                decode_message(prefix)
            with pytest.raises(DecodeError):
                decode_spdp(prefix)


@pytest.mark.parametrize("kind", ["alive", "directed", "dispose"])
def test_signed_goldens_are_the_unsigned_ones_plus_a_verifying_authenticator(kind: str) -> None:
    plain = _load(golden_swarmd.FIXTURES / f"spdp-{kind}.bin")
    signed = _load(golden_swarmd.FIXTURES / f"spdp-{kind}-signed.bin")
    opened = open_tail(signed)
    assert opened is not None
    freshness, signature, covered = opened
    assert freshness == golden_swarmd.FRESHNESS
    golden_swarmd.SIGNING_KEY.public_key().verify(signature, covered)  # raises if not
    _, plain_samples = decode_spdp(plain)
    _, signed_samples = decode_spdp(signed)
    # the receiver tags of a 3-node swarm: both peers when multicast, the destination alone
    tags = 1 if kind == "directed" else 2
    assert tail_window(signed) == (0, tags)
    assert len(signed) == len(plain) + authenticator_overhead(tags)
    if kind == "dispose":
        assert signed_samples == plain_samples
    else:
        (a,), (b,) = plain_samples, signed_samples
        assert isinstance(a, SpdpAlive) and isinstance(b, SpdpAlive)
        assert b.participant.authenticator == signed[-authenticator_overhead(tags) : -4]
        assert dataclasses.replace(b.participant, authenticator=None) == a.participant
