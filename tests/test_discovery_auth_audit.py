"""Forged SPDP the issue implies but its first tests did not try (issue 10 audit).

- a datagram whose RTPS header prefix is one participant's and whose DATA(p) is another's:
  signed by the header's owner (a captured member), it must not move the other;
- a captured member announcing locators at the receiver's own address;
- the CPU a forged datagram can cost: a datagram of ~64 KB of parameters, or of hundreds of
  DATA(p) submessages, under a bundle prefix (refused before decoding) or an invented one
  (decoded at the foreign budget's rate only).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from swarmd_lab.testing import auth_for, engine_for, make_bundle, node_ipv4

from swarmd.auth.spdp import PLACEHOLDER, SpdpAuth
from swarmd.discovery import DiscoveryEngine
from swarmd.discovery import received as received_module
from swarmd.discovery.foreign import FOREIGN_DECODE_BURST
from swarmd.rtps.locator import Locator
from swarmd.rtps.ports import SPDP_MULTICAST_GROUP, spdp_multicast_port
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp
from swarmd.rtps.types import Duration, GuidPrefix

BUNDLE = make_bundle(3)
P = [p.guid_prefix for p in BUNDLE.participants]
ATTACKER = ("10.0.0.66", 7412)


def _participant(
    index: int,
    *,
    meta: tuple[str, int] | None = None,
    user: tuple[str, int] | None = None,
    prefix: GuidPrefix | None = None,
    properties: tuple[tuple[str, str], ...] = (),
    sealed: bool = True,
) -> SpdpParticipant:
    p = BUNDLE.participants[index]
    host = node_ipv4(index)
    meta = meta or (host, BUNDLE.metatraffic_port(p))
    user = user or (host, BUNDLE.user_port(p))
    group = (SPDP_MULTICAST_GROUP, spdp_multicast_port(BUNDLE.domain_id))
    return SpdpParticipant(
        prefix or p.guid_prefix,
        domain_id=BUNDLE.domain_id,
        metatraffic_unicast_locators=(Locator.udpv4(*meta),),
        metatraffic_multicast_locators=(Locator.udpv4(*group),),
        default_unicast_locators=(Locator.udpv4(*user),),
        lease_duration=Duration.from_seconds(BUNDLE.discovery.lease_s),
        entity_name=f"{BUNDLE.swarm}/{p.name}",
        bundle_digest=BUNDLE.content_sha256[:16],
        link_quality_permille=1000,
        properties=properties,
        authenticator=PLACEHOLDER if sealed else None,
    )


def _sealed(
    participant: SpdpParticipant, auth: SpdpAuth, header: GuidPrefix | None = None
) -> bytes:
    data = bytearray(encode_spdp(participant, sequence_number=1, timestamp=None))
    if header is not None:
        data[8:20] = header.value  # the RTPS header's prefix, before the signature covers it
    return auth.seal(bytes(data))


def _receiver(index: int = 0) -> DiscoveryEngine:
    return engine_for(BUNDLE, index, auth=auth_for(BUNDLE, index))


def _dropped(engine: DiscoveryEngine) -> dict[str, int]:
    return {k: v for k, v in engine.counters()["dropped"].items() if v}


def _known(engine: DiscoveryEngine) -> list[tuple[str, bool]]:
    return [(v.name, v.discovered) for v in engine.peers()]


# -- header prefix vs DATA(p) ----------------------------------------------------------------


def test_a_data_p_for_another_participant_under_a_signed_header_moves_nothing() -> None:
    """Captured uav2 signs a datagram whose header is its own (so the signature holds) and
    whose DATA(p) says it is uav1, with the attacker's locators: uav1 must not appear."""
    e = _receiver()
    uav1_at_attacker = _participant(1, meta=ATTACKER, user=(ATTACKER[0], 7413))
    forged = _sealed(uav1_at_attacker, auth_for(BUNDLE, 2), header=P[2])
    e.receive_datagram(forged, (node_ipv4(2), 7412), 0.1)
    assert _known(e) == [("uav1", False), ("uav2", False)]
    assert _dropped(e) == {"decode_error": 1}  # the decoder's rule: one prefix per datagram
    assert e.datagrams_to_send() == []


def test_a_data_p_for_a_member_under_an_invented_header_moves_nothing() -> None:
    """The outsider's variant: an invented (foreign) header prefix skips authentication and
    is decoded; its DATA(p) naming uav1 must neither discover nor refresh uav1."""
    e = _receiver()
    invented = GuidPrefix(bytes(range(12)))
    data = bytearray(encode_spdp(_participant(1, sealed=False), sequence_number=1, timestamp=None))
    data[8:20] = invented.value
    e.receive_datagram(bytes(data), ATTACKER, 0.1)
    assert _known(e) == [("uav1", False), ("uav2", False)]
    assert _dropped(e) == {"decode_error": 1}
    assert e.foreign(0.1) == ()


# -- locators --------------------------------------------------------------------------------


def test_a_captured_member_announcing_the_receivers_own_address_is_refused() -> None:
    e = _receiver()
    me = BUNDLE.participants[0]
    own_meta = (node_ipv4(0), BUNDLE.metatraffic_port(me))
    own_user = (node_ipv4(0), BUNDLE.user_port(me))
    forged = _sealed(_participant(1, meta=own_meta, user=own_user), auth_for(BUNDLE, 1))
    e.receive_datagram(forged, (node_ipv4(1), 7412), 0.1)
    assert _dropped(e) == {"bad_locator": 1}


# -- CPU per forged datagram -----------------------------------------------------------------


def _huge(index: int, prefix: GuidPrefix | None = None) -> SpdpParticipant:
    # ~60 KB of parameters: 600 properties of ~100 octets each
    props = tuple((f"k{i:04d}", "v" * 90) for i in range(600))
    return _participant(index, prefix=prefix, properties=props)


def _count_decodes(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls = [0]
    real: Callable[..., Any] = received_module.decode

    def counting(raw: bytes) -> Any:
        calls[0] += 1
        return real(raw)

    monkeypatch.setattr(received_module, "decode", counting)
    return calls


def test_huge_forged_datagrams_under_a_member_prefix_are_never_decoded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    forged = _sealed(_huge(1), auth_for(BUNDLE, 2, epoch=1000))  # the attacker's own key
    assert len(forged) > 50_000
    e = _receiver()
    decodes = _count_decodes(monkeypatch)
    for i in range(500):
        e.receive_datagram(forged, (f"10.3.{i // 250}.{i % 250}", 7412), 0.2)
    assert decodes[0] == 0  # refused on the authenticator, before the decoder
    # a captured member's key makes no tag under another member's prefix: refused on the
    # tag (one keyed BLAKE2b over the ~60 KB), never on Ed25519, no budget spent
    assert _dropped(e) == {"auth_bad_tag": 500}
    assert e.counters()["auth"]["verified"] == 0


def test_huge_and_many_submessage_datagrams_under_invented_prefixes_are_decoded_at_a_bounded_rate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    invented = GuidPrefix(b"\x01\x10" + bytes(10))
    huge = bytearray(encode_spdp(_huge(1, prefix=invented), sequence_number=1, timestamp=None))
    # and one of ~300 DATA(p) submessages: the same DATA(p) repeated after one header
    one = encode_spdp(
        _participant(1, prefix=invented, sealed=False), sequence_number=1, timestamp=None
    )
    many = one + one[20:] * 300
    assert len(huge) > 50_000 and len(many) > 50_000
    e = _receiver()
    decodes = _count_decodes(monkeypatch)
    for _ in range(500):
        e.receive_datagram(bytes(huge), ATTACKER, 0.2)
        e.receive_datagram(many, ATTACKER, 0.2)
    assert decodes[0] <= FOREIGN_DECODE_BURST  # one instant: only the burst is decoded
    assert _dropped(e)["foreign_budget"] >= 1000 - FOREIGN_DECODE_BURST
    assert len(e.foreign(0.2)) <= 1  # one invented participant, listed once
