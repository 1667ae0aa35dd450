"""The daemon-side loader: bytes on the drone -> a verified ``Bundle``, or one line and exit 78.

Order of checks (each failure is a ``BundleError`` whose ``str()`` is one line):

1. framing: magic, format version, known flags, body length against file length
   (a truncated or padded file fails here);
2. content hash: SHA-256(body) equals the header's hash (a flipped body byte fails here);
3. signer: the header's public key equals the trusted swarm key, when one is configured;
4. signature: Ed25519 over header + body under the header's key (a flipped header or
   signature byte fails here; the hash and signer are header bytes, so they are covered);
5. policy: a DEV bundle only when explicitly allowed; the pinned hash, when configured;
6. body: schema, then consistency with the derivations (GUID prefixes, entity ids, ports),
   so a bundle from a buggy or foreign builder cannot smuggle in identities the discovery
   engine would compute differently.

Trust (docs/bundle-format.md): a bundle is accepted only against a trust anchor, either the
swarm signing public key (``trusted_key``) or a pinned content hash (``expected_sha256``).
The key embedded in the header is never trusted on its own.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any, Final, NoReturn

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from swarmd.bundle.encoding import (
    HEADER_SIZE,
    LEGACY_FORMAT_VERSIONS,
    MAX_BODY_BYTES,
    SIGNATURE_SIZE,
    Envelope,
    EnvelopeError,
    split,
)
from swarmd.bundle.errors import BundleError, KeyFileError
from swarmd.bundle.keys import PUBLIC_KEY_BYTES, fingerprint, load_public_key, parse_public_key
from swarmd.bundle.model import (
    SERIAL_MAX,
    Bundle,
    DiscoveryParams,
    Durability,
    Endpoint,
    EndpointKind,
    Liveliness,
    Participant,
    Qos,
    Reliability,
    Role,
    Topic,
    derive_guid_prefix,
    endpoint_entity_id,
    is_serial,
)
from swarmd.bundle.ros2 import graph_from_value
from swarmd.bundle.safeopen import (
    TRUSTED_FIX,
    SharedFolder,
    TooLarge,
    read_trusted,
    unreadable_why,
)
from swarmd.exitcodes import EX_CONFIG
from swarmd.rtps.ports import metatraffic_unicast_port, user_unicast_port
from swarmd.rtps.types import GuidPrefix

# the largest file a bundle's framing allows (split() refuses anything else anyway)
MAX_FILE_BYTES: Final = HEADER_SIZE + MAX_BODY_BYTES + SIGNATURE_SIZE

REBUILD = "rebuild it with 'swarmctl bundle build' and flash it again"
REBUILD_V2 = (
    "rebuild it with 'swarmctl bundle build' (after 'swarmctl bundle keygen --out DIR --mission "
    "MISSION', which adds the X25519 keys) and re-flash every drone with 'swarmctl bundle flash'"
)
REFLASH = (
    "flash the bundle again with 'swarmctl bundle flash' (the previous one is bundle.swb.prev)"
)


def verify_envelope(
    data: bytes,
    *,
    source: str = "<bundle>",
    trusted_key: bytes | None = None,
    expected_sha256: bytes | None = None,
    allow_dev: bool = False,
    require_anchor: bool = True,
) -> Envelope:
    """Steps 1-5 above; returns the verified envelope.

    ``require_anchor=False`` accepts a signature under the embedded key alone; only the
    ground tools use it (``swarmctl bundle show``), to inspect a bundle before trusting it.
    """
    if require_anchor and trusted_key is None and expected_sha256 is None:
        raise BundleError(
            source,
            "no trust anchor: neither a trusted swarm key nor a pinned bundle hash is configured",
            "set bundle.trusted_key to the swarm-signing.pub path (or bundle.expected_sha256)",
        )
    try:
        env = split(data)
    except EnvelopeError as exc:
        raise BundleError(source, str(exc), REFLASH) from None
    if env.version in LEGACY_FORMAT_VERSIONS:
        # refused before anything else: its nodes carry no X25519 key, so they could not
        # authenticate a single datagram (docs/security.md)
        raise BundleError(
            source,
            f"bundle format {env.version} has no field participants[].x25519_public_key "
            "(built before authenticated discovery)",
            REBUILD_V2,
        )
    if hashlib.sha256(env.body).digest() != env.content_sha256:
        raise BundleError(source, "content hash mismatch: the body was altered", REFLASH)
    if trusted_key is not None and env.signer != trusted_key:
        raise BundleError(
            source,
            f"signed by {fingerprint(env.signer)}, but this node trusts {fingerprint(trusted_key)}",
            "flash a bundle signed with the swarm signing key, or fix bundle.trusted_key",
        )
    try:
        Ed25519PublicKey.from_public_bytes(env.signer).verify(env.signature, env.signed)
    except (InvalidSignature, ValueError):
        raise BundleError(
            source, "bad signature: the header, body or signature was altered", REFLASH
        ) from None
    if env.dev and not allow_dev:
        raise BundleError(
            source,
            "this is an --unsigned-dev bundle, whose key anyone can derive",
            "build with --sign-key for flight, or set bundle.allow_dev for a lab bench",
        )
    if expected_sha256 is not None and env.content_sha256 != expected_sha256:
        raise BundleError(
            source,
            f"content hash {env.content_sha256.hex()} is not the pinned {expected_sha256.hex()}",
            "flash the bundle the mission was approved with, or update bundle.expected_sha256",
        )
    return env


def read_bundle(
    data: bytes,
    *,
    source: str = "<bundle>",
    trusted_key: bytes | None = None,
    expected_sha256: bytes | None = None,
    allow_dev: bool = False,
    require_anchor: bool = True,
) -> Bundle:
    """Verify ``data`` (see module docstring) and decode it into a ``Bundle``."""
    env = verify_envelope(
        data,
        source=source,
        trusted_key=trusted_key,
        expected_sha256=expected_sha256,
        allow_dev=allow_dev,
        require_anchor=require_anchor,
    )
    return decode_body(env, source)


def load_bundle(
    path: str | Path,
    trusted_key: bytes | str | Path | None = None,
    *,
    expected_sha256: bytes | None = None,
    allow_dev: bool = False,
    trusted_owners: frozenset[int] | None = None,
) -> Bundle:
    """Load and verify the bundle at ``path`` for the daemon.

    ``trusted_key`` is the swarm signing public key: raw 32 bytes, or the path of a PEM or
    hex key file. ``trusted_owners``: not None for the daemon (``swarmd run`` and
    ``check-config``: the daemon's uid beside root and swarmd): both files are then read
    through their folder's descriptor, the folder judged on it (``safeopen.read_trusted``:
    a folder swapped in since ``check_trusted_files`` is refused, a FIFO or a symlink at
    the name too). Raises ``BundleError`` (one line) on any failure, never anything else
    for bad file content.
    """
    source = str(path)
    anchor: bytes | None
    if trusted_key is None or isinstance(trusted_key, bytes):
        anchor = trusted_key
    elif trusted_owners is not None:
        raw = _read_judged(Path(trusted_key), trusted_owners, "trusted key: ")
        try:
            anchor = parse_public_key(raw, str(trusted_key))
        except KeyFileError as exc:
            raise BundleError(exc.file, f"trusted key: {exc.problem}", exc.fix) from None
    else:
        try:
            anchor = load_public_key(trusted_key)
        except KeyFileError as exc:
            raise BundleError(exc.file, f"trusted key: {exc.problem}", exc.fix) from None
    if anchor is not None and len(anchor) != PUBLIC_KEY_BYTES:
        raise BundleError(source, "trusted key is not 32 bytes", "give an Ed25519 public key")
    try:
        if trusted_owners is not None:
            data = _read_judged(Path(path), trusted_owners, "")
        else:
            with open(path, "rb") as f:
                # bounded: a wrong path (/dev/zero, a disk image) must not fill the memory
                data = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise BundleError(
            source, "bundle file not found", "flash one with 'swarmctl bundle flash'"
        ) from None
    except OSError as exc:
        raise BundleError(
            source, f"cannot read: {exc.strerror}", "check path and permissions"
        ) from None
    if len(data) > MAX_FILE_BYTES:
        raise BundleError(
            source,
            f"larger than a bundle can be ({MAX_FILE_BYTES} bytes)",
            "flash one with 'swarmctl bundle flash'",
        )
    return read_bundle(
        data,
        source=source,
        trusted_key=anchor,
        expected_sha256=expected_sha256,
        allow_dev=allow_dev,
    )


def _read_judged(path: Path, owners: frozenset[int], what: str) -> bytes:
    """``path`` through its judged folder (``safeopen.read_trusted``), at most
    ``MAX_FILE_BYTES``; a missing bundle is ``FileNotFoundError`` (the caller's line),
    anything else a ``BundleError`` naming ``what`` ("trusted key: ", or "" the bundle)."""
    try:
        return read_trusted(path, MAX_FILE_BYTES, also=owners)
    except FileNotFoundError:
        if not what:
            raise
        problem, fix = f"{what}key file not found", "give the swarm's swarm-signing.pub"
    except SharedFolder as exc:
        problem, fix = f"{what}{exc.strerror}", TRUSTED_FIX
    except TooLarge:
        problem = f"{what}larger than a bundle can be ({MAX_FILE_BYTES} bytes)"
        fix = "flash one with 'swarmctl bundle flash'"
    except OSError as exc:
        problem, fix = f"{what}cannot read: {unreadable_why(exc)}", "check path and permissions"
    raise BundleError(str(path), problem, fix)


def load_bundle_or_exit(
    path: str | Path,
    trusted_key: bytes | str | Path | None = None,
    *,
    expected_sha256: bytes | None = None,
    allow_dev: bool = False,
    prog: str = "swarmd",
) -> Bundle:
    """``load_bundle`` for a process entry point: on failure print one line, exit 78."""
    try:
        return load_bundle(path, trusted_key, expected_sha256=expected_sha256, allow_dev=allow_dev)
    except BundleError as exc:
        _exit_config(prog, exc)


def _exit_config(prog: str, exc: BundleError) -> NoReturn:
    print(f"{prog}: bundle rejected: {exc}", file=sys.stderr)
    raise SystemExit(EX_CONFIG)


# -- body ------------------------------------------------------------------------------------


class _BodyError(ValueError):
    pass


def _field(obj: Any, key: str, kind: type[Any] | tuple[type[Any], ...], where: str) -> Any:
    if not isinstance(obj, dict) or key not in obj:
        raise _BodyError(f"{where}: missing {key!r}")
    value = obj[key]
    if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
        raise _BodyError(f"{where}.{key}: unexpected {type(value).__name__}")
    return value


def decode_body(env: Envelope, source: str) -> Bundle:
    """The bundle model from a verified envelope; ``BundleError`` when the body is bad."""
    try:
        value = json.loads(env.body)
        return _bundle_from_value(value, env)
    except (_BodyError, ValueError, KeyError, TypeError) as exc:
        # the signature was valid, so a bad body comes from a bug in whatever built it
        raise BundleError(source, f"invalid bundle body: {exc}", REBUILD) from None


def _bundle_from_value(value: Any, env: Envelope) -> Bundle:
    swarm = _field(value, "swarm", str, "body")
    domain_id = _field(value, "domain_id", int, "body")
    d = _field(value, "discovery", dict, "body")
    discovery = DiscoveryParams(
        t_min_s=_field(d, "t_min_ms", int, "discovery") / 1000,
        t_max_s=_field(d, "t_max_ms", int, "discovery") / 1000,
        lease_s=_field(d, "lease_ms", int, "discovery") / 1000,
    )
    topics: list[Topic] = []
    topic_by_name: dict[str, Topic] = {}
    for i, t in enumerate(_field(value, "topics", list, "body")):
        where = f"topics[{i}]"
        lease_ms = _field(t, "liveliness_lease_ms", (int, type(None)), where)
        topic = Topic(
            name=_field(t, "name", str, where),
            type_name=_field(t, "type_name", str, where),
            qos=Qos(
                reliability=Reliability(_field(t, "reliability", str, where)),
                durability=Durability(_field(t, "durability", str, where)),
                history_depth=_field(t, "history_depth", int, where),
                liveliness=Liveliness(_field(t, "liveliness", str, where)),
                liveliness_lease_s=None if lease_ms is None else lease_ms / 1000,
            ),
            index=_field(t, "index", int, where),
        )
        if topic.index != i or topic.name in topic_by_name:
            raise _BodyError(f"{where}: index {topic.index} or name {topic.name!r} out of order")
        topics.append(topic)
        topic_by_name[topic.name] = topic

    # one EntityId object per (topic, kind): 500 drones x 5 topics share 10 of them
    entity_ids = {
        (t.name, kind): endpoint_entity_id(t.index, kind) for t in topics for kind in EndpointKind
    }
    swarm_prefix = derive_guid_prefix(swarm, domain_id, 0).value[:8]
    participants: list[Participant] = []
    names: set[str] = set()
    last_index = -1
    for i, p in enumerate(_field(value, "participants", list, "body")):
        where = f"participants[{i}]"
        index = _field(p, "index", int, where)
        name = _field(p, "name", str, where)
        if index <= last_index or name in names:
            raise _BodyError(f"{where}: participants not sorted by unique index/name")
        last_index = index
        names.add(name)
        prefix = bytes.fromhex(_field(p, "guid_prefix", str, where))
        if prefix != swarm_prefix + index.to_bytes(4, "big"):
            raise _BodyError(f"{where}: GUID prefix {prefix.hex()} is not the derived one")
        if _field(p, "metatraffic_unicast_port", int, where) != metatraffic_unicast_port(
            domain_id, index
        ) or _field(p, "user_unicast_port", int, where) != user_unicast_port(domain_id, index):
            raise _BodyError(f"{where}: ports differ from the RTPS port mapping")
        key = bytes.fromhex(_field(p, "announce_public_key", str, where))
        if len(key) != PUBLIC_KEY_BYTES:
            raise _BodyError(f"{where}: announce_public_key is not 32 bytes")
        x_key = bytes.fromhex(_field(p, "x25519_public_key", str, where))
        if len(x_key) != PUBLIC_KEY_BYTES:
            raise _BodyError(f"{where}: x25519_public_key is not 32 bytes")
        endpoints: list[Endpoint] = []
        for e in _field(p, "endpoints", list, where):
            topic_name = _field(e, "topic", str, where)
            kind = EndpointKind(_field(e, "kind", str, where))
            eid = entity_ids.get((topic_name, kind))
            if eid is None:
                raise _BodyError(f"{where}: endpoint on unknown topic {topic_name!r}")
            if _field(e, "entity_id", str, where) != eid.value.hex():
                raise _BodyError(f"{where}: entity id for {topic_name!r} is not the derived one")
            endpoints.append(Endpoint(topic_name, kind, eid))
        ipv4 = _field(p, "ipv4", (str, type(None)), where)
        participants.append(
            Participant(
                name=name,
                index=index,
                role=Role(_field(p, "role", str, where)),
                mavlink_sysid=_field(p, "mavlink_sysid", int, where),
                ipv4=ipv4,
                guid_prefix=GuidPrefix(prefix),
                announce_public_key=key,
                endpoints=tuple(endpoints),
                x25519_public_key=x_key,
            )
        )
    ros2 = None
    if isinstance(value, dict) and "ros2" in value:
        ros2 = graph_from_value(value["ros2"], swarm, {p.name: p.index for p in participants})
    serial = None
    if "serial" in value:  # absent: built before serials (the floor treats it as 0)
        serial = _field(value, "serial", int, "body")
        if not is_serial(serial):
            raise _BodyError(f"body.serial: {serial} is not in 1..{SERIAL_MAX}")
    return Bundle(
        swarm=swarm,
        domain_id=domain_id,
        discovery=discovery,
        topics=tuple(topics),
        participants=tuple(participants),
        content_sha256=env.content_sha256,
        signing_public_key=env.signer,
        dev=env.dev,
        ros2=ros2,
        serial=serial,
    )
