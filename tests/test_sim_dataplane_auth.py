"""The simulator's ``swarmd-auth`` protocol authenticates the 1 Hz user data too: the same
samples on the air, each datagram 12 octets longer (the data plane's authenticator less the
INFO_DST it replaces, docs/wire.md "User data")."""

from __future__ import annotations

from swarmd_lab.sim.runner import Scenario, run

from swarmd.dataplane.seal import NET_OVERHEAD_BYTES, TRAILER_BYTES
from swarmd.rtps.message import InfoDst, encode_submessage
from swarmd.rtps.types import GuidPrefix


def test_net_overhead_is_the_trailer_less_an_info_dst() -> None:
    info_dst = encode_submessage(InfoDst(GuidPrefix(bytes(12))))
    assert NET_OVERHEAD_BYTES == TRAILER_BYTES - len(info_dst) == 12


def test_authenticated_readiness_stream_has_the_same_samples_and_12_more_bytes_each() -> None:
    plain = run(Scenario("swarmd", 6, seed=3, window_s=25.0))
    auth = run(Scenario("swarmd-auth", 6, seed=3, window_s=25.0))
    p, a = plain["counters"], auth["counters"]
    assert isinstance(p, dict) and isinstance(a, dict)
    assert a["tx_data"] == p["tx_data"] > 0
    assert a["tx_data_bytes"] - p["tx_data_bytes"] == NET_OVERHEAD_BYTES * a["tx_data"]
