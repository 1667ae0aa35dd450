"""What the daemon works out before it starts: the node's secrets, the local IPv4, the
engine's settings, the link sources, the SPDP sockets and which systemd socket the PX4 link
takes. Split out of ``daemon.py`` (issue 20: a module past ~800 lines is split by concern);
``daemon.py`` keeps the running daemon's wiring.
"""

from __future__ import annotations

import fcntl
import os
import pathlib
import socket
import stat
import struct
from collections.abc import Callable, MutableMapping
from dataclasses import fields
from typing import Any, Final

from swarmd.auth.epoch import epoch_path
from swarmd.auth.keys import KeyRing, NodeKeyMismatch, NodeSecrets
from swarmd.bundle.errors import BundleError, KeyFileError
from swarmd.bundle.floor import FloorError, FloorResult, FloorWriteError, serial_of
from swarmd.bundle.floor import enforce as enforce_floor
from swarmd.bundle.keys import parse_node_keys
from swarmd.bundle.model import Bundle
from swarmd.bundle.safeopen import (
    NODE_KEY_CAP,
    TRUSTED_FIX,
    SharedFolder,
    TooLarge,
    read_trusted,
    unreadable_why,
)
from swarmd.bundle.statedir import DaemonUser
from swarmd.config import DaemonConfig, Px4Section
from swarmd.discovery.config import EngineConfig
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, StartupError
from swarmd.link import SourceName
from swarmd.link.file import FileSource
from swarmd.link.nl80211 import Nl80211Source
from swarmd.link.source import LinkSource
from swarmd.link.static import StaticSource
from swarmd.link.wext import WextSource
from swarmd.px4.transport import PX4_SOCKET, XRCE_SOCKET, parse_connection
from swarmd.sdlisten import ListenFdsError, listen_fds
from swarmd.udp import RECV_BUFFER_BYTES

SIOCGIFADDR: Final = 0x8915  # linux/sockios.h: get an interface's IPv4 address
IFNAMSIZ: Final = 16
IP_MULTICAST_ALL: Final = getattr(socket, "IP_MULTICAST_ALL", 49)  # linux/in.h
# Linux's default IP_MULTICAST_ALL=1 delivers every group any socket joined to every socket
# bound to the port; off, the SPDP socket hears only 239.255.0.1 joined on our interface.


class NodeSecretsError(ValueError):
    """node.key is missing, of the old format, or not this node's; ``str()`` is one line."""


def load_node_secrets(
    config: DaemonConfig, bundle: Bundle, also: frozenset[int] = frozenset()
) -> NodeSecrets:
    """This node's private keys: ``bundle.node_key`` (default node.key beside the bundle).

    A dev bundle without a node key uses the publicly derivable dev keys, so
    ``--unsigned-dev`` labs need no key files; a signed bundle always needs the file. The
    keys must be the ones the bundle lists for ``config.node``. ``also``: the daemon's uid
    when ``check-config`` judges for the unit's user. Raises ``NodeSecretsError``.
    """
    path = config.bundle.node_key_path
    if bundle.dev and config.bundle.node_key is None and not os.path.exists(path):
        secrets = NodeSecrets.dev(bundle.swarm, config.node)
    else:
        try:
            keys = parse_node_keys(read_node_key(path, also), path)
        except KeyFileError as exc:
            raise NodeSecretsError(str(exc)) from None
        secrets = NodeSecrets(keys.ed25519, keys.x25519)
    try:
        KeyRing.from_bundle(bundle, config.node, secrets)
    except NodeKeyMismatch as exc:
        raise NodeSecretsError(f"{path}: {exc}") from None
    except KeyError:
        pass  # a node outside the bundle is reported by the node check, naming its line
    return secrets


def read_node_key(path: str, also: frozenset[int] = frozenset()) -> bytes:
    """node.key's bytes, read through its folder's descriptor (``safeopen``): the folder
    judged on it (``check_trusted_files``' rule, so a folder swapped since that check is
    refused), the file a regular one of a trusted owner, private (``refuse_shared_secret``
    on its ``fstat``), at most ``NODE_KEY_CAP`` bytes. Raises ``NodeSecretsError``."""
    flash = (
        "flash this node with 'swarmctl bundle flash BUNDLE --node NAME --keys DIR' "
        "(or set bundle.node_key)"
    )
    try:
        return read_trusted(
            pathlib.Path(os.path.abspath(path)),
            NODE_KEY_CAP,
            also=also,
            judge=lambda info: refuse_shared_secret(path, info),
        )
    except FileNotFoundError:
        raise NodeSecretsError(f"{path}: node key not found; fix: {flash}") from None
    except SharedFolder as exc:
        raise NodeSecretsError(f"{path}: {exc.strerror}; fix: {TRUSTED_FIX}") from None
    except TooLarge:
        raise NodeSecretsError(
            f"{path}: over {NODE_KEY_CAP} bytes, not a node key (238 bytes); fix: {flash}"
        ) from None
    except OSError as exc:
        raise NodeSecretsError(
            f"{path}: cannot read the node key ({unreadable_why(exc)}); fix: {flash}"
        ) from None


def enforce_bundle_floor(
    config: DaemonConfig, bundle: Bundle, *, commit: bool, user: DaemonUser | None = None
) -> FloorResult:
    """This node's anti-rollback floor (``swarmd.bundle.floor.enforce``, docs/security.md
    "Bundle rollback") in the folder of node.key, its refusals as the one-line
    ``StartupError``: 78 for a rolled-back bundle or a corrupt floor, 73 for a folder that is
    unsafe or cannot be written. ``swarmd`` checks it before anything runs
    (``commit=False``; ``user``: check-config's daemon user, whose folder and files it
    trusts, as the epoch's check does), ``Daemon.start`` again before the first send,
    raising the floor (as this process)."""
    state_dir = config.bundle.node_state_dir
    try:
        return enforce_floor(
            bundle,
            source=config.bundle.path,
            state_dir=state_dir,
            node=config.node,
            commit=commit,
            also=user.trusted_owners(pathlib.Path(state_dir)) if user is not None else frozenset(),
        )
    except BundleError as exc:
        raise StartupError(f"bundle rejected: {exc}", EX_CONFIG) from None
    except FloorError as exc:
        raise StartupError(f"bundle floor rejected: {exc}", EX_CONFIG) from None
    except FloorWriteError as exc:
        raise StartupError(str(exc), EX_CANTCREAT) from None


def raise_bundle_floor(config: DaemonConfig, bundle: Bundle, log: Any) -> None:
    """Refuse a rolled-back bundle, else raise the floor to it, before the first send
    (swarmd.bundle.floor, docs/security.md "Bundle rollback"); ``Daemon.start`` runs it. Its
    file lives beside the boot epoch, so an epoch without a floor means the floor was deleted
    (or this is the first start of a swarmd that keeps one): logged, not refused."""
    result = enforce_bundle_floor(config, bundle, commit=True)
    if result.previous is None and epoch_path(config.bundle.node_state_dir, config.node).exists():
        log.warning(
            "bundle_floor_missing",
            path=str(result.path),
            serial=bundle.serial,
            why="this node booted before (its epoch file exists) but holds no bundle "
            "floor: deleted, or the first start of a swarmd that keeps one",
        )
    if result.raised:
        log.info(
            "bundle_floor_raised",
            path=str(result.path),
            serial=serial_of(bundle),
            previous=None if result.previous is None else result.previous.serial,
            sha256=bundle.content_sha256.hex(),
        )


def refuse_shared_secret(path: str, info: os.stat_result) -> None:
    """Like ssh with a private key: a node.key other users may read is refused.

    Whoever reads it can sign SPDP and user data as this drone and derive its MAVLink
    signing key (docs/security.md). ``info``: the file's ``fstat`` (``read_node_key``).
    Raises ``NodeSecretsError`` naming file, mode and fix."""
    if info.st_mode & 0o077:
        raise NodeSecretsError(
            f"{path}: mode {stat.S_IMODE(info.st_mode):04o} lets other users read this node's "
            f"private keys; fix: chmod 600 {path} (owner swarmd)"
        )


def interface_ipv4(ifname: str) -> str:
    """The interface's (first) IPv4 address; ``OSError`` when it has none or does not exist."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        req = struct.pack("256s", ifname.encode()[: IFNAMSIZ - 1])
        packed = fcntl.ioctl(s.fileno(), SIOCGIFADDR, req)
    return socket.inet_ntoa(packed[20:24])


def resolve_ipv4(config: DaemonConfig) -> str:
    """The local IPv4 the engine announces: configured, else the interface's own."""
    try:
        socket.if_nametoindex(config.interface)
    except OSError:
        raise config.error(
            "network.interface",
            f"no interface {config.interface!r} on this host",
            "name an existing interface ('ip -br link' lists them)",
        ) from None
    if config.ipv4 is not None:
        return config.ipv4
    try:
        return interface_ipv4(config.interface)
    except OSError:
        raise config.error(
            "network.interface",
            f"interface {config.interface!r} has no IPv4 address",
            "bring the link up with an address, or set network.ipv4",
        ) from None


def engine_config(config: DaemonConfig) -> EngineConfig:
    """``EngineConfig`` from ``discovery.mode`` and ``discovery.overrides``."""
    types = {f.name: f.type for f in fields(EngineConfig)}
    values: dict[str, Any] = {}
    for name, value in config.engine_overrides.items():
        path = f"discovery.overrides.{name}"
        if name not in types or name == "mode":
            raise config.error(path, f"unknown engine setting {name!r}", "see EngineConfig")
        if types[name] in ("bool", bool):  # a switch (vouch): 0 or 1
            if value not in (0, 1):
                raise config.error(path, f"{value} is not 0 or 1", "use 0 (off) or 1 (on)")
            value = bool(value)
        elif types[name] in ("int", int):
            if value != int(value):
                raise config.error(path, f"{value} is not a whole number", "use an integer")
            value = int(value)
        values[name] = value
    try:
        return EngineConfig(mode=config.engine_mode, **values)  # type: ignore[arg-type]
    except ValueError as exc:
        problem, _, fix = str(exc).partition("; fix: ")
        path = next((f"discovery.overrides.{n}" for n in values if n in problem), "discovery")
        raise config.error(path, problem, fix or "see docs/operations.md") from None


def link_sources(config: DaemonConfig) -> list[LinkSource]:
    """The configured link sources, in order."""
    link = config.link
    make: dict[SourceName, Callable[[], LinkSource]] = {
        SourceName.NL80211: lambda: Nl80211Source(config.interface, snr_floor_db=link.snr_floor_db),
        SourceName.WEXT: lambda: WextSource(
            config.interface,
            path=link.wext_path,
            max_quality=link.wext_max_quality,
            snr_floor_db=link.snr_floor_db,
        ),
        SourceName.FILE: lambda: FileSource(
            link.file, max_age_s=link.file_max_age_s, snr_floor_db=link.snr_floor_db
        ),
        SourceName.STATIC: lambda: StaticSource(link.static_q),
    }
    return [make[SourceName(name)]() for name in link.sources]


def open_spdp_socket(group: str, port: int, ipv4: str) -> socket.socket:
    """The SPDP multicast socket: ``group:port`` joined on the interface owning ``ipv4``."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        # several participants on one host (tests, a ground station) share the SPDP port
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        s.bind(("", port))
        mreq = socket.inet_aton(group) + socket.inet_aton(ipv4)
        s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
        s.setsockopt(socket.IPPROTO_IP, IP_MULTICAST_ALL, 0)
        _multicast_send_options(s, ipv4)
        s.setblocking(False)
    except BaseException:
        s.close()
        raise
    return s


def open_unicast_socket(port: int, ipv4: str) -> socket.socket:
    """The metatraffic unicast socket; every datagram the engine queues leaves from it."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECV_BUFFER_BYTES)
        s.bind(("", port))  # not ipv4: a re-addressed interface must not deafen us
        _multicast_send_options(s, ipv4)
        s.setblocking(False)
    except BaseException:
        s.close()
        raise
    return s


def _multicast_send_options(s: socket.socket, ipv4: str) -> None:
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(ipv4))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)  # the swarm is one hop
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)  # co-hosted participants


# the FileDescriptorName= of systemd/swarmd-px4.socket and systemd/swarmd-xrce.socket
KNOWN_LISTEN_NAMES: Final = (PX4_SOCKET.fd_name, XRCE_SOCKET.fd_name)


def listen_socket_name(px4: Px4Section) -> str | None:
    """Which socket unit's descriptor the configured PX4 link takes (sd_listen_fds names):
    ``px4`` for a MAVLink ``udpin:``, ``xrce`` for the XRCE agent's ``udp:``; None for a UART,
    ``udpout:`` or ``xrce-client`` (swarmd binds no port there: docs/px4.md)."""
    if not px4.enabled:
        return None
    if px4.backend == "mavlink":
        return PX4_SOCKET.fd_name if parse_connection(px4.connection).kind == "udpin" else None
    if px4.backend == "xrce-agent" and px4.connection.startswith("udp:"):
        return XRCE_SOCKET.fd_name
    return None


def px4_listen_socket(
    px4: Px4Section, env: MutableMapping[str, str], log: Any
) -> socket.socket | None:
    """The socket systemd bound for the vehicle link: ``swarmd-px4.socket`` (named
    ``px4``) for a MAVLink ``udpin:``, ``swarmd-xrce.socket`` (``xrce``) for the XRCE
    agent's ``udp:``; ``env`` is where sd_listen_fds(3) reads (and unsets) its variables.

    systemd holds it from boot and across restarts, so no local user can take the port
    (issue 18, docs/px4.md). Descriptors we have no use for are closed (systemd keeps its
    own copy) and logged: at info for the other backend's unit (the service lists both),
    as a warning for any other name."""
    try:
        fds = listen_fds(env)
    except ListenFdsError as exc:
        raise StartupError(str(exc), EX_CONFIG) from None
    name = listen_socket_name(px4)
    wanted = fds.pop(name, []) if name is not None else []
    for other, numbers in fds.items():
        for fd in numbers:
            os.close(fd)
        emit = log.info if other in KNOWN_LISTEN_NAMES else log.warning
        emit(
            "listen_fd_unused",
            name=other,
            count=len(numbers),
            why=f"px4.connection takes {name or 'no socket'} "
            "(px4: a MAVLink udpin:, xrce: the XRCE agent's udp:)",
        )
    for extra in wanted[1:]:
        os.close(extra)
    return socket.socket(fileno=wanted[0]) if wanted else None
