"""Wireshark dissects the data plane's traffic cleanly: user DATA with a padded CDR payload,
HEARTBEAT, ACKNACK with a missing-set bitmap, and GAP, each datagram ending with swarmd's
authenticator (vendor submessage 0x8a), with no expert info.

The traffic is what a commander and two members sent each other through the lossy network
of ``test_dataplane_swarm`` (so repairs happen), plus one GAP from a writer whose keep-last
history lost what a reader asked for.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from swarmd.auth.freshness import Freshness
from swarmd.dataplane import CommandKind
from swarmd.dataplane.seal import AUTH_SUBMESSAGE_ID, seal, user_data_key
from swarmd.dataplane.writer import ReliableWriter
from swarmd.rtps import AckNack, Header, SequenceNumberSet, encode_message
from swarmd.rtps.types import PROTOCOLVERSION_SWARMD, VENDORID_SWARMD
from tests.peers.tshark import Datagram, dissect_fields, tshark_path, write_pcap
from tests.test_dataplane_swarm import (
    address_of,
    keyring,
    make_swarm,
    readiness_ticks,
    send_at,
)

pytestmark = [
    pytest.mark.interop,
    pytest.mark.skipif(tshark_path() is None, reason="tshark not installed (scripts/setup.sh)"),
]

FIELDS = [
    "_ws.col.Info",
    "_ws.expert",
    "_ws.malformed",
    "rtps.guidPrefix.src",
    "rtps.guidPrefix.dst",
    "rtps.sm.wrEntityId",
    "rtps.sm.rdEntityId",
    "rtps.param.serialize.encap_kind",
    "rtps.padding_bytes",
    "rtps.sm.seqNumber",
    "rtps.sm.id",
]


def test_user_traffic_dissects_without_expert_info(tmp_path: Path) -> None:
    swarm = make_swarm(2, seed=4, drop=0.3)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    commands = [lead.make_command(CommandKind.TAKEOFF, altitude_m=10.0) for _ in range(3)]
    ticks = readiness_ticks(swarm, 0.5, 3)
    ticks += [send_at(swarm, 1.0 + 0.01 * i, c) for i, c in enumerate(commands)]
    swarm.run_until(20.0, ticks)
    datagrams = [Datagram(p, s, d) for p, s, d in swarm.net.payloads()]

    # one GAP: a depth-1 writer asked for a sample its history no longer holds
    lead_p, m01 = swarm.bundle.participant("lead"), swarm.bundle.participant("m01")
    match = next(m for m in swarm.bundle.matches(lead_p, m01) if m.topic == "swarm/command")
    writer = ReliableWriter(match.local, depth=1)
    writer.add_reader(match.remote, 0.0)
    writer.write(b"\x00\x01\x00\x00", 0.0)
    writer.write(b"\x00\x01\x00\x00", 0.0)
    ask = AckNack(match.remote.entity_id, match.local.entity_id, SequenceNumberSet.of(1, [1]), 1)
    reply = [o.submessage for o in writer.on_acknack(match.remote, ask, 0.1)]
    header = Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, lead_p.guid_prefix)
    key = keyring(swarm.bundle, "lead").pair_key(m01.guid_prefix)
    assert key is not None
    gap = seal(
        user_data_key(key),
        encode_message(header, reply),
        Freshness(1, 1 << 20),
        m01.guid_prefix,
        1,
    )
    datagrams.append(
        Datagram(gap, address_of(swarm.bundle, "lead"), address_of(swarm.bundle, "m01"))
    )

    pcap = tmp_path / "dataplane.pcap"
    write_pcap(pcap, datagrams)
    frames = dissect_fields(pcap, FIELDS)
    assert len(frames) == len(datagrams)
    kinds: set[str] = set()
    for i, frame in enumerate(frames):
        assert frame["_ws.expert"] == [] and frame["_ws.malformed"] == [], f"datagram {i}"
        info = frame["_ws.col.Info"][0]
        kinds |= {k.strip() for k in info.split(",")}
        assert frame["rtps.guidPrefix.dst"] == [], "no INFO_DST: the tag names the receiver"
        assert int(frame["rtps.sm.id"][-1], 16) == AUTH_SUBMESSAGE_ID, f"datagram {i}"
    assert {"DATA", "HEARTBEAT", "ACKNACK", "GAP", f"Unknown[{AUTH_SUBMESSAGE_ID:x}]"} <= kinds
    # CDR_LE payloads; Wireshark reads the RTPS 2.3 padding count from the options of the
    # padded ones (outcomes: "" pads 3 octets, "ok" pads 1)
    encodings = {k for f in frames for k in f["rtps.param.serialize.encap_kind"]}
    paddings = {int(n) for f in frames for n in f["rtps.padding_bytes"]}
    assert encodings == {"0x0001"}
    assert {1, 3} <= paddings
    # only bundle endpoints: user entity ids of kind 0x03 (writer) / 0x04 (reader)
    for f in frames:
        for eid in f["rtps.sm.wrEntityId"]:
            assert int(eid, 16) & 0xFF == 0x03
        for eid in f["rtps.sm.rdEntityId"]:
            assert int(eid, 16) & 0xFF == 0x04
