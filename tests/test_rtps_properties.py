"""Property tests: encode/decode round trips, and "decode or DecodeError, nothing else"."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.rtps import (
    AckNack,
    Data,
    DecodeError,
    Duration,
    EntityId,
    Gap,
    GuidPrefix,
    Header,
    Heartbeat,
    InfoDst,
    InfoTs,
    Locator,
    Parameter,
    ProtocolVersion,
    SequenceNumberSet,
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    Submessage,
    VendorId,
    decode_message,
    decode_spdp,
    encode_message,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.spdp import _MODELLED, SWARMD_PIDS
from swarmd.rtps.types import VENDORID_CYCLONE, VENDORID_SWARMD
from tests import golden_swarmd

FIXTURES = Path(__file__).parent / "fixtures"
GOLDEN = sorted(FIXTURES.glob("**/*.bin"))

prefixes = st.binary(min_size=12, max_size=12).map(GuidPrefix)
entity_ids = st.binary(min_size=4, max_size=4).map(EntityId)
u32 = st.integers(0, 2**32 - 1)
sns = st.integers(1, 2**63 - 1)
durations = st.builds(Duration, st.integers(-(2**31), 2**31 - 1), u32)
text = st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\x00"), max_size=40)
ipv4_locators = st.builds(
    lambda a, port: Locator(1, port, bytes(12) + a), st.binary(min_size=4, max_size=4), u32
)
any_locators = ipv4_locators | st.builds(
    Locator, st.integers(-(2**31), 2**31 - 1), u32, st.binary(min_size=16, max_size=16)
)
locator_lists = st.lists(any_locators, max_size=3).map(tuple)
# extra parameters: PIDs the participant does not model, values padded to 4
extra_pids = st.integers(0x0002, 0xFFFF).filter(
    lambda p: p not in _MODELLED and p not in SWARMD_PIDS
)
extras = st.lists(
    st.builds(Parameter, extra_pids, st.binary(max_size=24).map(lambda b: b + bytes(-len(b) % 4))),
    max_size=3,
).map(tuple)
participants = st.builds(
    SpdpParticipant,
    guid_prefix=prefixes,
    protocol_version=st.builds(ProtocolVersion, st.just(2), st.integers(1, 5)),
    vendor_id=st.sampled_from([VENDORID_SWARMD, VENDORID_CYCLONE]),
    domain_id=st.none() | st.integers(0, 232),
    domain_tag=st.none() | text,
    metatraffic_unicast_locators=locator_lists,
    metatraffic_multicast_locators=locator_lists,
    default_unicast_locators=locator_lists,
    default_multicast_locators=locator_lists,
    lease_duration=durations,
    builtin_endpoints=u32,
    manual_liveliness_count=st.none() | st.integers(-(2**31), 2**31 - 1),
    entity_name=st.none() | text,
    user_data=st.none() | st.binary(max_size=32),
    properties=st.lists(st.tuples(text, text), max_size=3).map(tuple),
    extra_parameters=extras,
).map(
    # swarmd fields only travel under swarmd's vendor id
    lambda p: (
        replace(p, bundle_digest=bytes(16), heard=b"\x01", link_quality_permille=999)
        if p.is_swarmd
        else p
    )
)


@settings(max_examples=300)
@given(
    participants, sns, st.none() | prefixes, st.none() | durations.filter(lambda d: d.seconds >= 0)
)
def test_spdp_round_trip(
    p: SpdpParticipant, sn: int, dst: GuidPrefix | None, ts: Duration | None
) -> None:
    if dst is not None and dst.value == bytes(12):
        dst = None  # all-zero INFO_DST means "to everyone" and decodes as None
    header, samples = decode_spdp(encode_spdp(p, sequence_number=sn, timestamp=ts, destination=dst))
    assert header.guid_prefix == p.guid_prefix
    assert samples == [SpdpAlive(p, sn, dst, ts)]


@given(prefixes, sns)
def test_spdp_dispose_round_trip(prefix: GuidPrefix, sn: int) -> None:
    _, samples = decode_spdp(encode_spdp_dispose(prefix, sequence_number=sn, timestamp=None))
    assert samples == [SpdpDisposed(prefix, sn, None, None)]


sn_sets = st.builds(
    lambda base, bits: SequenceNumberSet.of(base, [base + b for b in bits], 256 if bits else 0),
    st.integers(1, 2**40),
    st.lists(st.integers(0, 255), max_size=8, unique=True),
)
submessages: st.SearchStrategy[Submessage] = st.one_of(
    st.builds(InfoTs, st.none() | st.builds(Duration, u32, u32)),
    st.builds(InfoDst, prefixes),
    st.builds(Heartbeat, entity_ids, entity_ids, sns, sns, u32, st.booleans(), st.booleans()),
    st.builds(AckNack, entity_ids, entity_ids, sn_sets, u32, st.booleans()),
    st.builds(Gap, entity_ids, entity_ids, sns, sn_sets),
    st.builds(
        Data,
        entity_ids,
        entity_ids,
        sns,
        st.none(),
        st.none() | st.binary(min_size=4, max_size=64).map(lambda b: b + bytes(-len(b) % 4)),
    ),
)


@given(st.lists(submessages, max_size=6), prefixes)
def test_message_round_trip(subs: list[Submessage], prefix: GuidPrefix) -> None:
    header = Header(ProtocolVersion(2, 3), VendorId(b"SW"), prefix)
    decoded = decode_message(encode_message(header, subs))
    assert decoded.header == header
    assert list(decoded.submessages) == subs


def _decode_or_drop(data: bytes) -> None:
    for decoder in (decode_message, decode_spdp):
        try:
            decoder(data)
        except DecodeError:
            pass


@settings(max_examples=500)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_decode_or_raise_decode_error(data: bytes) -> None:
    _decode_or_drop(data)
    _decode_or_drop(b"RTPS\x02\x03SW" + bytes(12) + data)


@settings(max_examples=500)
@given(
    st.sampled_from(GOLDEN),
    st.lists(st.tuples(st.integers(0, 2000), st.integers(0, 255)), min_size=1, max_size=8),
)
def test_mutated_golden_packets_decode_or_raise_decode_error(
    path: Path, mutations: list[tuple[int, int]]
) -> None:
    data = bytearray(path.read_bytes())
    for offset, value in mutations:
        data[offset % len(data)] = value
    _decode_or_drop(bytes(data))


def test_golden_corpus_is_present() -> None:
    # the mutation test above is only as good as its corpus
    names = {p.name for p in GOLDEN}
    assert {"spdp-alive.bin", "spdp-dispose.bin"} <= names
    assert len(GOLDEN) >= len(golden_swarmd.PACKETS) + 2
