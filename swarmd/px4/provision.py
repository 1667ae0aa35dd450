"""Where the PX4 link's signing key comes from, on the drone and on the ground (file I/O).

On the drone (``swarmd run``) the key is derived from the node secrets the daemon loaded
(``node.key``, ``swarmd.auth.keys.NodeSecrets``), or read from ``px4.signing_key``. On the
ground, ``swarmctl px4 key`` derives the same key from ``keys/nodes/<name>.key`` and writes
PX4's key file (or the hex) for provisioning (docs/px4.md, "Message signing").
"""

from __future__ import annotations

from pathlib import Path

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.keys import load_node_keys
from swarmd.px4.signing import derive_key, parse_key_file


class SigningKeyError(ValueError):
    """No usable signing key; ``str()`` is one line with the fix."""


def ed25519_seed(key: Ed25519PrivateKey) -> bytes:
    """The 32-byte seed of a node's Ed25519 key: the secret the PX4 key is derived from."""
    return key.private_bytes(
        serialization.Encoding.Raw, serialization.PrivateFormat.Raw, serialization.NoEncryption()
    )


def node_secret(node_key: str | Path) -> bytes:
    """The seed in a node key file (``KeyFileError``, one line, if unreadable)."""
    return ed25519_seed(load_node_keys(node_key).ed25519)


def signing_key_for(*, swarm: str, node: str, key_file: str | None, seed: bytes) -> bytes:
    """The PX4 link key: ``key_file`` if set, else derived from the node's secret ``seed``."""
    if key_file is None:
        return derive_key(seed, swarm, node)
    try:
        data = Path(key_file).read_bytes()
    except OSError as exc:
        raise SigningKeyError(
            f"px4.signing_key {key_file}: cannot read ({exc.strerror}); fix: give the file "
            "'swarmctl px4 key' wrote, or drop the field to derive it from node.key"
        ) from None
    try:
        return parse_key_file(data, f"px4.signing_key {key_file}")
    except ValueError as exc:
        raise SigningKeyError(str(exc)) from None
