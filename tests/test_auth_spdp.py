"""``swarmd.auth.spdp``: the SPDP authenticator and the verifier's order of checks."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.testing import make_bundle, node_name

from swarmd.auth.budget import GLOBAL_NEW_ADDRESS_BURST, NEW_ADDRESS_BURST, SENDER_BURST
from swarmd.auth.freshness import Freshness
from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.auth.spdp import (
    AUTHENTICATOR_OVERHEAD,
    PLACEHOLDER,
    Refusal,
    SpdpAuth,
    SpdpVerifier,
    open_tail,
    seal,
)
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import (
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)

BUNDLE = make_bundle(4)
P = [p.guid_prefix for p in BUNDLE.participants]
SRC = ("10.0.0.2", 7412)  # uav1's bundle address: node_ipv4(1), metatraffic port of index 1


def ring(i: int) -> KeyRing:
    return KeyRing.from_bundle(BUNDLE, node_name(i), NodeSecrets.dev(BUNDLE.swarm, node_name(i)))


def template(i: int, *, authenticated: bool = True, destination: int | None = None) -> bytes:
    part = SpdpParticipant(
        P[i],
        metatraffic_unicast_locators=(Locator.udpv4("10.0.0.2", 7412),),
        entity_name=f"alpha/{node_name(i)}",
        bundle_digest=BUNDLE.content_sha256[:16],
        heard=b"\x0f",
        link_quality_permille=800,
        authenticator=PLACEHOLDER if authenticated else None,
    )
    return encode_spdp(
        part,
        sequence_number=3,
        timestamp=None,
        destination=None if destination is None else P[destination],
    )


def test_sealed_datagram_is_80_octets_longer_and_still_plain_spdp() -> None:
    # without receiver tags (swarmd.auth.tags adds 4 octets per tag: tests/test_auth_tags.py)
    plain, sealed = template(1, authenticated=False), seal(template(1), Freshness(9, 1), ring(1))
    assert len(sealed) - len(plain) == AUTHENTICATOR_OVERHEAD == 80
    _, samples = decode_spdp(sealed)
    (alive,) = samples
    assert isinstance(alive, SpdpAlive)
    assert alive.participant.authenticator == sealed[-80:-4]
    opened = open_tail(sealed)
    assert opened is not None and opened[0] == Freshness(9, 1)
    assert open_tail(plain) is None


def test_verifier_accepts_once_then_refuses_the_replay() -> None:
    v = SpdpVerifier(ring(0), 0.0)
    d = seal(template(1), Freshness(9, 1), ring(1))
    assert v.check(P[1].value, d, SRC, 0.0) == Freshness(9, 1)
    assert v.check(P[1].value, d, SRC, 0.1) == Refusal.REPLAYED
    assert v.high(P[1].value) == Freshness(9, 1)
    assert v.counters["auth_replayed"] == 1 and v.counters["auth_verified"] == 1


def test_another_members_key_or_a_missing_authenticator_is_refused() -> None:
    v = SpdpVerifier(ring(0), 0.0)
    # member 2 (captured) signs a datagram carrying member 1's prefix
    forged = seal(template(1), Freshness(9, 1), ring(2))
    assert v.check(P[1].value, forged, SRC, 0.0) == Refusal.BAD_SIGNATURE
    assert v.check(P[1].value, template(1, authenticated=False), SRC, 0.0) == Refusal.MISSING
    assert v.high(P[1].value) is None  # nothing moved


def test_dispose_is_sealed_the_same_way() -> None:
    auth = SpdpAuth(ring(1), 5, 0.0)
    d = auth.seal(
        encode_spdp_dispose(P[1], sequence_number=4, timestamp=None, authenticator=PLACEHOLDER)
    )
    _, samples = decode_spdp(d)
    assert isinstance(samples[0], SpdpDisposed)
    v = SpdpVerifier(ring(0), 0.0)
    assert v.check(P[1].value, d, SRC, 0.0) == Freshness(5, 1)


def test_flood_from_other_addresses_never_spends_the_known_senders_budget() -> None:
    v = SpdpVerifier(ring(0), 0.0)
    auth = SpdpAuth(ring(1), 7, 0.0)
    assert isinstance(v.check(P[1].value, auth.seal(template(1)), SRC, 0.0), Freshness)
    v.note_address(P[1].value, SRC)  # the engine used it: SRC is member 1's address now
    # a forger spoofing member 1's prefix from many addresses, all at t = 0, each datagram
    # distinct (a repeat of one that failed is refused without spending: test_auth_tags)
    forged = [seal(template(1), Freshness(8, 1 + i), ring(2)) for i in range(520)]
    refusals = [
        v.check(P[1].value, forged[i], (f"10.9.{i // 250}.{i % 250}", 7412), 0.0)
        for i in range(500)
    ]
    # SRC is member 1's bundle address (ipv4 + metatraffic port): its own budget from the
    # first datagram on, so the forger had the whole global budget to itself
    verified = GLOBAL_NEW_ADDRESS_BURST
    assert refusals.count(Refusal.BAD_SIGNATURE) == verified  # then no tokens left
    assert refusals.count(Refusal.BUDGET_GLOBAL) == 500 - verified
    # one address: its own budget runs out first
    one = [v.check(P[1].value, forged[500 + k], ("10.8.0.1", 1), 0.0) for k in range(20)]
    assert one.count(Refusal.BUDGET_SENDER) >= 20 - NEW_ADDRESS_BURST
    # the real member at its known address still gets every datagram verified (its first
    # datagram above took one of its own tokens)
    for _ in range(int(SENDER_BURST) - 1):
        assert isinstance(v.check(P[1].value, auth.seal(template(1)), SRC, 0.0), Freshness)
    assert v.check(P[1].value, auth.seal(template(1)), SRC, 0.0) == Refusal.BUDGET_SENDER
    assert isinstance(v.check(P[1].value, auth.seal(template(1)), SRC, 1.0), Freshness)


@settings(max_examples=300, deadline=None)
@given(
    st.booleans(),
    st.integers(min_value=0, max_value=10_000),
    st.integers(min_value=0, max_value=7),
)
def test_flipping_any_bit_of_an_authenticated_datagram_gets_it_refused(
    directed: bool, where: int, bit: int
) -> None:
    d = seal(template(1, destination=2 if directed else None), Freshness(9, 5), ring(1))
    i = where % len(d)
    flipped = bytearray(d)
    flipped[i] ^= 1 << bit
    v = SpdpVerifier(ring(2), 0.0)
    assert isinstance(v.check(P[1].value, bytes(flipped), SRC, 0.0), Refusal)
    assert v.high(P[1].value) is None  # nothing moved
    # the same verifier still takes the genuine datagram: the refusal was the bit's doing
    assert v.check(P[1].value, d, SRC, 0.0) == Freshness(9, 5)
