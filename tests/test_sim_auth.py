"""The simulator's ``swarmd-auth`` protocol: the SPDP authenticator's bytes on every frame,
the same schedule (issue 10: +0 packets), freshness still checked (``modelled_auth``)."""

from __future__ import annotations

from swarmd_lab.sim.modelled_auth import ModelledSpdpAuth
from swarmd_lab.sim.runner import Scenario, run
from swarmd_lab.testing import make_bundle, peer_datagram

from swarmd.auth.spdp import AUTHENTICATOR_OVERHEAD, Refusal, open_tail, tail_window


def test_authenticated_run_has_the_same_frames_and_the_authenticators_bytes() -> None:
    plain = run(Scenario("swarmd", 8, seed=5, window_s=30.0))
    auth = run(Scenario("swarmd-auth", 8, seed=5, window_s=30.0))
    assert plain["all_discovered"] and auth["all_discovered"]
    p, a = plain["counters"], auth["counters"]
    assert isinstance(p, dict) and isinstance(a, dict)
    assert a["tx_discovery"] == p["tx_discovery"] > 0
    added = a["tx_discovery_bytes"] - p["tx_discovery_bytes"]
    # 80 octets each, plus a 2-octet receiver tag per peer padded to 4: 7 at N = 8 in a
    # multicast datagram (16 octets), one in a directed one (4)
    per_frame = added / a["tx_discovery"]
    assert AUTHENTICATOR_OVERHEAD + 4 <= per_frame <= AUTHENTICATOR_OVERHEAD + 16


def test_modelled_auth_seals_the_real_layout_and_refuses_replays() -> None:
    bundle = make_bundle(3)
    sender = ModelledSpdpAuth(bundle.participants[1].guid_prefix, 4, 3)
    d = peer_datagram(bundle, 1, auth=sender)
    assert tail_window(d) == (0, 2)  # zero tags for both peers: the daemon's size
    opened = open_tail(d)
    assert opened is not None and (opened[0].epoch, opened[0].seq) == (4, 1)
    receiver = ModelledSpdpAuth(bundle.participants[0].guid_prefix, 1)
    prefix = bundle.participants[1].guid_prefix.value
    assert receiver.check(prefix, d, ("10.0.0.2", 7412), 0.0) == opened[0]
    assert receiver.check(prefix, d, ("10.0.0.2", 7412), 0.1) == Refusal.REPLAYED
    assert receiver.check(prefix, peer_datagram(bundle, 1), ("x", 1), 0.2) == Refusal.MISSING
