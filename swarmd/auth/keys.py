"""This node's secrets and every participant's public keys, from the bundle alone.

No key is ever exchanged on the air (paper Appendix B: a runtime Diffie-Hellman exchange cost
+110 % packets; preloading the keys costs none):

- **Signatures** (SPDP, multicast and directed): Ed25519 (RFC 8032) with the sender's
  ``announce_public_key`` from the bundle. Anyone can verify, only the holder of the node
  key can sign, so a captured member cannot speak for the commander or another member.
- **Pairwise keys** (unicast user data, secData's MACs): static-static X25519 (RFC 7748)
  between my private key and the peer's bundle public key, both ends compute the same
  secret. It is expanded with HKDF-SHA256 (RFC 5869) bound to the bundle's content hash (a
  re-flashed swarm gets new keys even if the node keys stay) and to both GUID prefixes in a
  fixed order (the key names the pair, not a direction).

Sans-IO: no file is read here. ``NodeSecrets.load`` is the one exception and is called by the
daemon at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Final

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey
from cryptography.hazmat.primitives.kdf.hkdf import HKDF

from swarmd.bundle.keys import NodeKeys, dev_node_keys, load_node_keys
from swarmd.bundle.model import Bundle, Participant, Role
from swarmd.rtps.types import GuidPrefix

SIGNATURE_BYTES: Final = 64  # Ed25519 (RFC 8032 5.1.6)
PAIR_KEY_BYTES: Final = 32
# HKDF "info" prefix: a key derived for another purpose from the same secret never collides
PAIR_KEY_INFO: Final = b"swarmd pair key v1|"


class NodeKeyMismatch(ValueError):
    """node.key does not hold the keys the bundle lists for this node; one line, with the fix."""


@dataclass(frozen=True, slots=True)
class NodeSecrets:
    """This node's private keys: Ed25519 (signs its SPDP) and X25519 (pairwise keys)."""

    ed25519: Ed25519PrivateKey
    x25519: X25519PrivateKey

    @classmethod
    def load(cls, path: str | Path) -> NodeSecrets:
        """Read node.key (bundle format 2: both keys). Raises ``KeyFileError`` (one line);
        a format-1 file (Ed25519 only) is refused with the rebuild/re-flash fix."""
        keys = load_node_keys(path)
        return cls(keys.ed25519, keys.x25519)

    @classmethod
    def dev(cls, swarm: str, name: str) -> NodeSecrets:
        """The publicly derivable keys of a node in an ``--unsigned-dev`` bundle (labs only)."""
        keys = dev_node_keys(swarm, name)
        return cls(keys.ed25519, keys.x25519)

    @property
    def public(self) -> tuple[bytes, bytes]:
        """(Ed25519, X25519) raw public keys, as the bundle lists them."""
        return NodeKeys(self.ed25519, self.x25519).public


class KeyRing:
    """Every bundle participant's public keys plus this node's secrets.

    Built once at start-up from a verified bundle; lookups are by GUID prefix octets (the
    engine has them from the RTPS header without decoding anything). Public-key objects and
    pairwise keys are made on first use, so a 1000-node ring costs nothing until a peer speaks.
    """

    def __init__(self, bundle: Bundle, me: Participant, secrets: NodeSecrets) -> None:
        if secrets.public != (me.announce_public_key, me.x25519_public_key):
            raise NodeKeyMismatch(
                f"node key does not match {me.name!r}'s keys in bundle {bundle.swarm!r}; "
                "fix: flash this node with the keys directory the bundle was built from"
            )
        self.bundle = bundle
        self._bundle_hash = bundle.content_sha256
        self._me = me
        self._secrets = secrets
        self._by_prefix: dict[bytes, Participant] = {
            p.guid_prefix.value: p for p in bundle.participants
        }
        self._verifiers: dict[bytes, Ed25519PublicKey] = {}
        self._pair_keys: dict[bytes, bytes | None] = {}

    @classmethod
    def from_bundle(cls, bundle: Bundle, own_name: str, secrets: NodeSecrets) -> KeyRing:
        """Raises ``KeyError`` for a name not in the bundle, ``NodeKeyMismatch`` when
        ``secrets`` are not that participant's keys."""
        return cls(bundle, bundle.participant(own_name), secrets)

    @property
    def size(self) -> int:
        """Participants in the bundle (this node included)."""
        return len(self._by_prefix)

    @property
    def own_prefix(self) -> GuidPrefix:
        return self._me.guid_prefix

    @property
    def own(self) -> Participant:
        return self._me

    def participant(self, prefix: GuidPrefix | bytes) -> Participant | None:
        return self._by_prefix.get(prefix.value if isinstance(prefix, GuidPrefix) else prefix)

    def is_member(self, prefix: GuidPrefix | bytes) -> bool:
        """A participant of the bundle (commander included)."""
        return self.participant(prefix) is not None

    def is_commander(self, prefix: GuidPrefix | bytes) -> bool:
        p = self.participant(prefix)
        return p is not None and p.role == Role.COMMANDER

    def sign(self, data: bytes) -> bytes:
        """This node's Ed25519 signature of ``data`` (64 bytes)."""
        return self._secrets.ed25519.sign(data)

    def verify(self, sender: GuidPrefix | bytes, data: bytes, signature: bytes) -> bool:
        """Whether ``signature`` is ``sender``'s (by its bundle key) over ``data``.

        False for a prefix outside the bundle, whatever the signature: the prefix names the
        key, so a member's key never verifies as another member or the commander."""
        raw = sender.value if isinstance(sender, GuidPrefix) else sender
        key = self._verifiers.get(raw)
        if key is None:
            p = self._by_prefix.get(raw)
            if p is None:
                return False
            try:
                key = Ed25519PublicKey.from_public_bytes(p.announce_public_key)
            except ValueError:  # not a valid curve point: nobody can sign for it
                return False
            self._verifiers[raw] = key
        if len(signature) != SIGNATURE_BYTES:
            return False
        try:
            key.verify(signature, data)
        except InvalidSignature:
            return False
        return True

    def pair_key(self, peer: GuidPrefix | bytes) -> bytes | None:
        """The 32-byte key this node shares with ``peer``, equal on both ends; None for a
        prefix outside the bundle (or myself, or a key that yields no shared secret).

        HKDF-SHA256(ikm = X25519(mine, peer's), salt = bundle content hash,
        info = "swarmd pair key v1|" + lower prefix + higher prefix)."""
        raw = peer.value if isinstance(peer, GuidPrefix) else peer
        if raw in self._pair_keys:
            return self._pair_keys[raw]
        p = self._by_prefix.get(raw)
        key: bytes | None = None
        if p is not None and raw != self._me.guid_prefix.value:
            try:
                shared = self._secrets.x25519.exchange(
                    X25519PublicKey.from_public_bytes(p.x25519_public_key)
                )
            except ValueError:  # a malformed or low-order public key: all-zero secret
                shared = None
            if shared is not None:
                low, high = sorted((raw, self._me.guid_prefix.value))
                key = HKDF(
                    algorithm=hashes.SHA256(),
                    length=PAIR_KEY_BYTES,
                    salt=self._bundle_hash,
                    info=PAIR_KEY_INFO + low + high,
                ).derive(shared)
        if p is not None:  # cache only bundle prefixes: a stranger cannot grow this table
            self._pair_keys[raw] = key
        return key
