"""Golden packets captured from a live stock Cyclone DDS (tests/fixtures/cyclone-live/).

Each ``NAME.bin`` is one UDP payload; ``NAME.json`` holds what tshark (an implementation
independent of swarmd) and Cyclone's own trace say about it. swarmd's decoder must agree
with both on every field, and no truncation may decode to a wrong participant.
Recapture with ``scripts/capture_cyclone_fixtures.py`` (docs/interop.md).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Final, Literal

import pytest

from swarmd.rtps import (
    DecodeError,
    SpdpAlive,
    decode_message,
    decode_spdp,
    encode_spdp,
)
from swarmd.rtps.message import HEADER_SIZE
from swarmd.rtps.types import VENDORID_CYCLONE
from tests.peers.tshark import (
    Datagram,
    decoded_view,
    dissect_fields,
    dissect_tree,
    spdp_view,
    tshark_path,
    write_pcap,
)

FIXTURES: Final = Path(__file__).parent / "fixtures" / "cyclone-live"
EXPECTED: Final = (
    "data-p-directed",
    "data-p-multicast",
    "data-p-ud-multicast",
    "data-p-ud-unicast",
)
NAMES: Final = sorted(p.stem for p in FIXTURES.glob("*.json"))


def load(name: str) -> tuple[bytes, dict[str, Any]]:
    sidecar: dict[str, Any] = json.loads((FIXTURES / f"{name}.json").read_text())
    return (FIXTURES / sidecar["file"]).read_bytes(), sidecar


def addr(text: str) -> tuple[str, int]:
    host, port = text.rsplit(":", 1)
    return host, int(port)


def test_every_expected_fixture_is_checked_in() -> None:
    assert set(EXPECTED) <= set(NAMES), f"missing fixtures in {FIXTURES}"
    for name in NAMES:
        assert (FIXTURES / f"{name}.bin").is_file()


@pytest.mark.parametrize("name", NAMES)
def test_decode_agrees_with_tshark_and_cyclone_trace(name: str) -> None:
    data, sidecar = load(name)
    assert len(data) == sidecar["length"]
    assert sidecar["cyclonedds_version"] == "11.0.1"

    header, samples = decode_spdp(data)
    assert header.guid_prefix.hex() == sidecar["header"]["guid_prefix"]
    assert str(header.vendor_id) == sidecar["header"]["vendor_id"] == "01.10"
    assert header.vendor_id == VENDORID_CYCLONE
    assert str(header.protocol_version) == sidecar["header"]["protocol_version"]
    # the prefix Cyclone's trace gives its own participant, in its a:b:c form
    assert f"{header.guid_prefix}:1c1" == sidecar["cyclone_trace"]["participant"]

    assert samples, f"{name}: no SPDP sample decoded"
    assert [decoded_view(s) for s in samples] == sidecar["samples"]
    for sample in samples:
        if isinstance(sample, SpdpAlive):
            lease = sample.participant.lease_duration
            assert str(round(lease.total_seconds() * 1e9)) == sidecar["cyclone_trace"]["lease_ns"]
            props = dict(sample.participant.properties)
            assert props["__Pid"] == sidecar["cyclone_trace"]["pid"]
            unicast = (
                sample.participant.metatraffic_unicast_locators
                + sample.participant.default_unicast_locators
            )
            assert {loc.host for loc in unicast} == {addr(sidecar["udp"]["source"])[0]}


@pytest.mark.parametrize("name", NAMES)
def test_directed_and_dispose_context(name: str) -> None:
    data, sidecar = load(name)
    _, samples = decode_spdp(data)
    if "directed" in name:
        assert all(s.destination is not None for s in samples)
        assert sidecar["tshark_info"] == "INFO_DST, INFO_TS, DATA(p)"
    if "-ud-" in name:
        assert [decoded_view(s)["kind"] for s in samples] == ["disposed"]
        assert sidecar["tshark_info"].endswith("DATA(p[UD])")


def submessage_boundaries(data: bytes) -> list[int]:
    """Offsets where a submessage starts, read straight off the wire (spec 9.4.1)."""
    offsets, pos = [], HEADER_SIZE
    while pos < len(data):
        offsets.append(pos)
        order: Literal["little", "big"] = "little" if data[pos + 1] & 1 else "big"
        pos += 4 + int.from_bytes(data[pos + 2 : pos + 4], order)
    assert pos == len(data), "fixture's last submessage does not end at the datagram's end"
    return offsets


@pytest.mark.parametrize("name", NAMES)
def test_every_truncation_raises_or_keeps_only_complete_submessages(name: str) -> None:
    data, _ = load(name)
    full = decode_message(data).submessages
    _, full_samples = decode_spdp(data)
    decodable = []
    for cut in range(len(data)):
        try:
            header, samples = decode_spdp(data[:cut])
        except DecodeError:
            continue
        decodable.append(cut)
        # a cut that decodes must sit on a submessage boundary and lose only what follows
        kept = decode_message(data[:cut]).submessages
        assert list(kept) == list(full[: len(kept)]), f"cut at {cut} changed a submessage"
        assert samples == full_samples[: len(samples)], f"cut at {cut} changed a sample"
        assert len(kept) < len(full), f"cut at {cut} decoded the whole message"
    # exactly the cuts on a submessage boundary decode; nothing in between does
    assert decodable == submessage_boundaries(data)


@pytest.mark.parametrize("name", NAMES)
def test_reencoded_participant_decodes_to_the_same(name: str) -> None:
    # swarmd re-emits a stock participant (e.g. when relaying) without losing a field:
    # unknown and vendor PIDs are kept opaque and written back in order.
    data, _ = load(name)
    _, samples = decode_spdp(data)
    for sample in samples:
        if not isinstance(sample, SpdpAlive):
            continue
        again = encode_spdp(
            sample.participant,
            sequence_number=sample.sequence_number,
            timestamp=sample.timestamp,
            destination=sample.destination,
        )
        _, (copy,) = decode_spdp(again)
        assert copy == sample


@pytest.mark.interop
@pytest.mark.skipif(tshark_path() is None, reason="tshark not installed (scripts/setup.sh)")
def test_tshark_still_dissects_fixtures_as_recorded(tmp_path: Path) -> None:
    loaded = [load(name) for name in NAMES]
    datagrams = [
        Datagram(data, addr(s["udp"]["source"]), addr(s["udp"]["destination"]))
        for data, s in loaded
    ]
    pcap = tmp_path / "cyclone-live.pcap"
    write_pcap(pcap, datagrams)
    infos = dissect_fields(pcap, ["_ws.col.Info", "_ws.expert", "_ws.malformed"])
    trees = dissect_tree(pcap)
    for (_, sidecar), info, tree in zip(loaded, infos, trees, strict=True):
        assert info["_ws.col.Info"] == [sidecar["tshark_info"]]
        assert info["_ws.expert"] == [] and info["_ws.malformed"] == []
        assert spdp_view(tree) == sidecar["samples"]
