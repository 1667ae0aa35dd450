"""``swarmd.auth.keys``: signatures and pairwise keys from the bundle alone (docs/security.md)."""

from __future__ import annotations

import dataclasses

import pytest
from swarmd_lab.testing import make_bundle, node_name

from swarmd.auth.keys import KeyRing, NodeKeyMismatch, NodeSecrets
from swarmd.bundle.model import Bundle
from swarmd.rtps.types import GuidPrefix

BUNDLE = make_bundle(4)


def ring(bundle: Bundle, index: int) -> KeyRing:
    name = node_name(index)
    return KeyRing.from_bundle(bundle, name, NodeSecrets.dev(bundle.swarm, name))


def prefix(index: int) -> GuidPrefix:
    return BUNDLE.participants[index].guid_prefix


def test_signature_verifies_under_the_senders_bundle_key_only() -> None:
    a, b = ring(BUNDLE, 1), ring(BUNDLE, 2)
    data = b"spdp datagram"
    sig = a.sign(data)
    assert len(sig) == 64
    assert b.verify(prefix(1), data, sig)
    # a captured member (2) cannot speak as member 1 or as the commander (0)
    forged = b.sign(data)
    assert not a.verify(prefix(1), data, forged)
    assert not a.verify(prefix(0), data, forged)
    # one flipped bit of data or signature, a short signature, a stranger's prefix
    assert not b.verify(prefix(1), data + b"x", sig)
    assert not b.verify(prefix(1), data, bytes([sig[0] ^ 1]) + sig[1:])
    assert not b.verify(prefix(1), data, sig[:63])
    assert not b.verify(GuidPrefix(b"\x01" * 12), data, sig)


def test_membership_and_roles() -> None:
    r = ring(BUNDLE, 1)
    assert r.own_prefix == prefix(1)
    assert r.is_member(prefix(0)) and r.is_member(prefix(3))
    assert r.is_commander(prefix(0)) and not r.is_commander(prefix(1))
    stranger = GuidPrefix(b"\x53\x57" + b"\x00" * 10)
    assert not r.is_member(stranger) and not r.is_commander(stranger)


def test_pair_keys_agree_on_both_ends_and_differ_per_pair() -> None:
    rings = [ring(BUNDLE, i) for i in range(4)]
    keys = {}
    for i in range(4):
        for j in range(4):
            k = rings[i].pair_key(prefix(j))
            if i == j:
                assert k is None
                continue
            assert k is not None and len(k) == 32
            assert k == rings[j].pair_key(prefix(i))
            keys[frozenset((i, j))] = k
    assert len(set(keys.values())) == 6  # one distinct key per unordered pair
    assert rings[0].pair_key(GuidPrefix(b"\x02" * 12)) is None


def test_pair_key_is_bound_to_the_bundle_hash() -> None:
    other = dataclasses.replace(BUNDLE, content_sha256=b"\x01" * 32)
    assert ring(BUNDLE, 1).pair_key(prefix(2)) != ring(other, 1).pair_key(prefix(2))


def test_secrets_must_be_this_nodes_keys() -> None:
    with pytest.raises(NodeKeyMismatch, match="does not match 'uav1'"):
        KeyRing.from_bundle(BUNDLE, "uav1", NodeSecrets.dev(BUNDLE.swarm, "uav2"))
