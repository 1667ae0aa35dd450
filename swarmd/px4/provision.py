"""Where the PX4 link's signing key comes from, on the drone and on the ground (file I/O).

On the drone (``swarmd run``) the key is derived from the node key that ``swarmctl bundle
flash`` installs beside the bundle (``node.key``), or read from ``px4.signing_key``. On the
ground, ``swarmctl px4 key`` derives the same key from ``keys/nodes/<name>.key`` and writes
PX4's key file (or the hex) for provisioning (docs/px4.md, "Message signing").
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from cryptography.hazmat.primitives import serialization

from swarmd.bundle.errors import KeyFileError
from swarmd.bundle.keys import load_private_key
from swarmd.px4.signing import derive_key, parse_key_file

NODE_KEY_FILE: Final = "node.key"  # swarmd.bundle.flash writes it beside the bundle


class SigningKeyError(ValueError):
    """No usable signing key; ``str()`` is one line with the fix."""


def node_secret(node_key: str | Path) -> bytes:
    """The 32-byte Ed25519 seed of a node key file (``KeyFileError`` if unreadable)."""
    key = load_private_key(node_key)
    return key.private_bytes(
        serialization.Encoding.Raw, serialization.PrivateFormat.Raw, serialization.NoEncryption()
    )


def signing_key_for(
    *, swarm: str, node: str, key_file: str | None, bundle_path: str | Path
) -> bytes:
    """The PX4 link key: ``key_file`` if set, else derived from ``node.key`` by the bundle."""
    if key_file is not None:
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
    path = Path(bundle_path).parent / NODE_KEY_FILE
    try:
        return derive_key(node_secret(path), swarm, node)
    except KeyFileError as exc:
        raise SigningKeyError(
            f"px4.signing: no node key to derive the MAVLink key from ({exc.file}: "
            f"{exc.problem}); fix: flash the "
            "node with 'swarmctl bundle flash', set px4.signing_key, or px4.signing: false"
        ) from None
