"""Where the PX4 link's signing key comes from, on the drone and on the ground (file I/O).

On the drone (``swarmd run``) the key is derived from the node secrets the daemon loaded
(``node.key``, ``swarmd.auth.keys.NodeSecrets``), or read from ``px4.signing_key``. On the
ground, ``swarmctl px4 key`` derives the same key from ``keys/nodes/<name>.key`` and writes
PX4's key file (or the hex), and ``swarmctl px4 setup-signing`` sends it to PX4 as
``SETUP_SIGNING`` on a bench link (docs/px4.md, "Message signing").
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from pathlib import Path
from typing import Final

from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.keys import load_node_keys
from swarmd.bundle.safeopen import (
    SIGNING_KEY_CAP,
    TRUSTED_FIX,
    SharedFolder,
    TooLarge,
    read_trusted,
    unreadable_why,
)
from swarmd.px4.constants import COMP_ID_AUTOPILOT1
from swarmd.px4.mavlink_codec import MavlinkCodec, SetupSigning
from swarmd.px4.messages import Heartbeat
from swarmd.px4.signing import derive_key, parse_key_file, timestamp_from_unix
from swarmd.px4.transport import Endpoint, open_link

GCS_SYSID: Final = 255  # a ground station's usual system id (QGroundControl, MAVProxy)
GCS_COMPID: Final = 190  # MAV_COMP_ID_MISSIONPLANNER
SETUP_RESEND_S: Final = 0.5  # resend until a signed heartbeat confirms (UDP may drop it)


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


def signing_key_for(
    *,
    swarm: str,
    node: str,
    key_file: str | None,
    seed: bytes,
    also: frozenset[int] = frozenset(),
) -> bytes:
    """The PX4 link key: ``key_file`` if set, else derived from the node's secret ``seed``.
    ``also``: the daemon's uid when ``check-config`` judges for the unit's user."""
    if key_file is None:
        return derive_key(seed, swarm, node)
    data = _read_signing_key(key_file, also)
    try:
        return parse_key_file(data, f"px4.signing_key {key_file}")
    except ValueError as exc:
        raise SigningKeyError(str(exc)) from None


def _read_signing_key(key_file: str, also: frozenset[int]) -> bytes:
    """The key file's bytes through its folder's descriptor (``swarmd.bundle.safeopen``):
    the folder judged on it (``check_trusted_files``' rule: one swapped in since is
    refused), the file a regular one of a trusted owner, never a symlink or a FIFO, private
    (0600), at most ``SIGNING_KEY_CAP`` bytes. Raises ``SigningKeyError`` (one line)."""
    where = f"px4.signing_key {key_file}"
    fix = "give the file 'swarmctl px4 key' wrote, or drop the field to derive it from node.key"
    path = Path(key_file)

    def private(info: os.stat_result) -> None:
        if info.st_mode & 0o077:  # whoever reads it speaks for swarmd to PX4 (like node.key)
            raise SigningKeyError(
                f"{where}: mode {info.st_mode & 0o777:o} lets other users read the key; "
                f"fix: chmod 600 {key_file}"
            )

    try:
        return read_trusted(path, SIGNING_KEY_CAP, also=also, judge=private)
    except SharedFolder as exc:
        raise SigningKeyError(f"{where}: {exc.strerror}; fix: {TRUSTED_FIX}") from None
    except TooLarge:
        raise SigningKeyError(
            f"{where}: over {SIGNING_KEY_CAP} bytes, not a key (40 bytes, 65 as hex); fix: {fix}"
        ) from None
    except OSError as exc:
        raise SigningKeyError(f"{where}: cannot read ({unreadable_why(exc)}); fix: {fix}") from None


async def setup_signing(
    endpoint: Endpoint,
    sysid: int,
    key: bytes,
    *,
    current_key: bytes | None = None,
    timeout_s: float = 5.0,
) -> bool:
    """Send ``SETUP_SIGNING`` with ``key`` to the autopilot (sysid, 1) until it answers with a
    HEARTBEAT signed with that key (True), or ``timeout_s`` passes (False).

    The message goes unsigned (an unprovisioned PX4 takes it so), or signed with
    ``current_key`` (a provisioned PX4 takes only that). We speak as a ground station
    (255, 190), over ``udpout:`` or ``serial:`` only: a bench link to one autopilot.
    """
    if endpoint.kind == "udpin":
        raise SigningKeyError(
            f"{endpoint}: setup-signing speaks first; fix: udpout:HOST:PORT (PX4 SITL: "
            "udpout:127.0.0.1:14580) or serial:/dev/ttyACM0:115200 (PX4's USB)"
        )
    loop = asyncio.get_running_loop()
    tx = MavlinkCodec(GCS_SYSID, GCS_COMPID, signing_key=current_key)
    rx = MavlinkCodec(GCS_SYSID, GCS_COMPID, signing_key=key)
    confirmed = loop.create_future()

    def on_bytes(data: bytes, _source: str | None) -> None:
        rx.advance_clock(timestamp_from_unix(time.time()))
        for frame in rx.feed(data, datagram=endpoint.kind != "serial"):
            ours = (frame.src_system, frame.src_component) == (sysid, COMP_ID_AUTOPILOT1)
            if ours and frame.signed and isinstance(frame.msg, Heartbeat):
                if not confirmed.done():
                    confirmed.set_result(True)

    link = await open_link(endpoint, on_bytes)
    try:
        deadline = loop.time() + timeout_s
        while loop.time() < deadline and not confirmed.done():
            now = timestamp_from_unix(time.time())
            tx.advance_clock(now)
            link.send(tx.encode(SetupSigning(sysid, COMP_ID_AUTOPILOT1, key, now)))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(confirmed), SETUP_RESEND_S)
        return confirmed.done()
    finally:
        link.close()
