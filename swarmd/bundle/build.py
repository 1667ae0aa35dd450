"""Mission -> bundle: derive every identity SEDP would have announced, then seal.

Everything is derived, nothing drawn (paper section 4.2: endpoint data decided before
flight): GUID prefixes from (swarm, domain, index) via ``derive_guid_prefix``, entity ids
from the topic's position via ``endpoint_entity_id``, ports from the participant index via
the standard RTPS port mapping. The only inputs beyond the mission are the per-node public
keys, the signing key and the serial, so the same mission, keys and serial give
byte-identical bundles.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.encoding import body_value, canonical_json, seal
from swarmd.bundle.errors import KeyFileError
from swarmd.bundle.keys import (
    dev_node_keys,
    dev_signing_key,
    load_node_public_keys,
    load_private_key,
    node_public_path,
    raw_public,
)
from swarmd.bundle.mission import Mission
from swarmd.bundle.model import (
    SERIAL_MAX,
    Bundle,
    Endpoint,
    EndpointKind,
    Participant,
    Topic,
    derive_guid_prefix,
    endpoint_entity_id,
    is_serial,
)
from swarmd.rtps.ports import metatraffic_unicast_port, user_unicast_port


@dataclass(frozen=True, slots=True)
class Built:
    """A sealed bundle: its file bytes and the model the daemon will load from them."""

    data: bytes
    bundle: Bundle
    dev: bool


def build_bundle(
    mission: Mission,
    signing_key: Ed25519PrivateKey,
    node_public_keys: Mapping[str, tuple[bytes, bytes]],
    *,
    dev: bool = False,
    serial: int = 1,
) -> Built:
    """Seal ``mission`` with ``signing_key``; ``node_public_keys`` maps every name to its
    raw (Ed25519, X25519) public keys. ``serial`` (1..``SERIAL_MAX``) must be above that of
    every bundle this one replaces: drones refuse a lower one (swarmd.bundle.floor)."""
    check_serial(serial)
    topics = tuple(Topic(t.name, t.type_name, t.qos, t.index) for t in mission.topics)
    # (topic index, writer before reader) keeps each participant's endpoint list canonical
    endpoints: dict[str, list[Endpoint]] = {p.name: [] for p in mission.participants}
    for t in mission.topics:
        for kind, names in ((EndpointKind.WRITER, t.writers), (EndpointKind.READER, t.readers)):
            entity_id = endpoint_entity_id(t.index, kind)
            for name in names:
                endpoints[name].append(Endpoint(t.name, kind, entity_id))
    participants = tuple(
        Participant(
            name=p.name,
            index=p.index,
            role=p.role,
            mavlink_sysid=p.mavlink_sysid,
            ipv4=p.ipv4,
            guid_prefix=derive_guid_prefix(mission.swarm, mission.domain_id, p.index),
            announce_public_key=node_public_keys[p.name][0],
            endpoints=tuple(endpoints[p.name]),
            x25519_public_key=node_public_keys[p.name][1],
        )
        for p in mission.participants
    )
    ports = {
        p.index: (
            metatraffic_unicast_port(mission.domain_id, p.index),
            user_unicast_port(mission.domain_id, p.index),
        )
        for p in mission.participants
    }
    body = canonical_json(
        body_value(
            mission.swarm,
            mission.domain_id,
            mission.discovery,
            topics,
            participants,
            ports,
            mission.ros2,
            serial,
        )
    )
    data = seal(body, signing_key, dev=dev)
    bundle = Bundle(
        swarm=mission.swarm,
        domain_id=mission.domain_id,
        discovery=mission.discovery,
        topics=topics,
        participants=participants,
        content_sha256=hashlib.sha256(body).digest(),
        signing_public_key=raw_public(signing_key),
        dev=dev,
        ros2=mission.ros2,
        serial=serial,
    )
    return Built(data, bundle, dev)


def check_serial(serial: int) -> None:
    """Raise ``ValueError`` (one line) for a serial outside 1..``SERIAL_MAX`` (0 is what a
    bundle without a serial counts as, so a built one starts at 1)."""
    if not is_serial(serial):
        raise ValueError(f"serial {serial!r} is not in 1..{SERIAL_MAX}")


def build_dev_bundle(mission: Mission, *, serial: int = 1) -> Built:
    """A bundle signed with the publicly derivable dev keys (``--unsigned-dev``)."""
    node_keys = {p.name: dev_node_keys(mission.swarm, p.name).public for p in mission.participants}
    return build_bundle(mission, dev_signing_key(mission.swarm), node_keys, dev=True, serial=serial)


def read_node_public_keys(mission: Mission, keys_dir: str | Path) -> dict[str, tuple[bytes, bytes]]:
    """Every participant's (Ed25519, X25519) public keys from ``keys_dir/nodes/<name>.pub``."""
    out: dict[str, tuple[bytes, bytes]] = {}
    for p in mission.participants:
        path = node_public_path(keys_dir, p.name)
        if not path.exists():
            raise KeyFileError(
                str(path),
                f"no announcement key for participant {p.name!r}",
                f"run 'swarmctl bundle keygen --out {keys_dir} --mission {mission.source}' "
                "(existing keys are kept)",
            )
        out[p.name] = load_node_public_keys(path)
    return out


def build_from_files(
    mission: Mission,
    sign_key: str | Path | None,
    keys_dir: str | Path | None,
    *,
    dev: bool = False,
    serial: int = 1,
) -> Built:
    """The CLI's build: keys from files, or the dev keys when ``dev``."""
    if dev:
        return build_dev_bundle(mission, serial=serial)
    if sign_key is None:
        raise KeyFileError(
            "-", "no signing key", "pass --sign-key KEY, or --unsigned-dev for a lab bundle"
        )
    key = load_private_key(sign_key)
    directory = Path(keys_dir) if keys_dir is not None else Path(sign_key).parent
    return build_bundle(mission, key, read_node_public_keys(mission, directory), serial=serial)
