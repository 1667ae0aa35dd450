"""The checked daemon config as values: its sections' dataclasses, ``DaemonConfig`` and the
checks made on the files it names (who may rewrite them). Read by ``swarmd.config.checker``
from the YAML; callers import these names from ``swarmd.config``.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from swarmd.bundle.keys import others_can_write
from swarmd.bundle.model import Bundle, NotAParticipant, Participant
from swarmd.bundle.safeopen import writers_problem
from swarmd.link import SourceName
from swarmd.yamldoc import FieldError

LOG_LEVELS: Final = ("debug", "info", "warning", "error")
LOG_FORMATS: Final = ("auto", "json", "console")
DEFAULT_SOCKET: Final = "/run/swarmd/swarmd.sock"
DEFAULT_BUNDLE: Final = "/var/lib/swarmd/bundle.swb"
DEFAULT_STATE_DIR: Final = "/var/lib/swarmd"  # systemd StateDirectory=swarmd
# PX4 SITL / mavlink-router onboard link, loopback only: a wildcard would hear the swarm's
# Wi-Fi (issue 10, attack 6); px4.allow_network opts in for an FMU on Ethernet
DEFAULT_PX4_CONNECTION: Final = "udpin:127.0.0.1:14540"
MIN_POLL_S: Final = 0.05  # faster polling would only burn CPU: drivers average over ~1 s
MAX_POLL_S: Final = 60.0


class ConfigError(FieldError):
    """A config file the daemon refuses; ``str()`` is one line naming file, line, field, fix."""


@dataclass(frozen=True, slots=True)
class BundleConfig:
    path: str = DEFAULT_BUNDLE
    trusted_key: str | None = None  # swarm-signing.pub (PEM or hex)
    expected_sha256: bytes | None = None  # a pinned content hash, the other trust anchor
    allow_dev: bool = False  # accept --unsigned-dev bundles (lab benches only)
    # this node's private keys (Ed25519 + X25519); None: node.key next to the bundle, where
    # 'swarmctl bundle flash' writes it. Its folder also keeps the boot epoch (auth-epoch-*).
    node_key: str | None = None

    @property
    def node_key_path(self) -> str:
        return self.node_key or str(Path(self.path).parent / "node.key")

    @property
    def node_state_dir(self) -> str:
        """node.key's folder (/var/lib/swarmd on a drone): the boot epoch, the SPDP replay
        windows and the bundle floor live beside it."""
        return os.path.dirname(os.path.abspath(self.node_key_path))


@dataclass(frozen=True, slots=True)
class LinkConfig:
    sources: tuple[str, ...] = (SourceName.NL80211, SourceName.WEXT, SourceName.STATIC)
    poll_interval_s: float = 1.0
    file: str = "/run/swarmd/link.json"
    file_max_age_s: float | None = None
    wext_path: str = "/proc/net/wireless"
    wext_max_quality: float = 70.0
    static_q: float = 0.5
    snr_floor_db: float = 25.0  # paper eq. 2: Q = clamp((SNR - 25) / 15); 0 = garbled print


@dataclass(frozen=True, slots=True)
class Px4Section:
    """``px4:``: the vehicle this daemon flies (docs/px4.md). Absent or ``enabled: false``:
    a node without PX4 (a ground station, a benchmark node); it reports ``px4_disabled``."""

    enabled: bool = False
    connection: str = DEFAULT_PX4_CONNECTION
    sysid: int | None = None  # None: the bundle participant's mavlink_sysid
    allow_network: bool = False  # a UDP endpoint beyond loopback (FMU on Ethernet): opt-in
    autopilot: str | None = None  # "IP:PORT" pinned; None: the first heartbeat's source
    signing: bool = False  # MAVLink 2 message signing with the per-drone key (docs/px4.md)
    signing_key: str | None = None  # a key file; None: derived from the node key
    heartbeat_timeout_s: float = 2.5  # PX4 HEARTBEAT_TIMEOUT_US; keeps link loss within 3 s
    min_battery_pct: float = 30.0
    allow_unknown_battery: bool = False
    require_home: bool = True
    takeoff_alt_m: float = 10.0  # metres above home when swarmctl takeoff has no --alt
    backend: str = "mavlink"  # | "xrce-agent" | "xrce-client" (docs/px4.md, uXRCE-DDS)
    # xrce-agent: the vehicle's UXRCE_DDS_KEY, binding the agent to it; None: generated once
    # into px4-xrce-key beside node.key (swarmd.px4.xrce_key, docs/px4.md)
    xrce_key: int | None = None
    namespace: str | None = None  # PX4's UXRCE_DDS_NS (topics rt/<ns>/fmu/...)
    # xrce-client: the DDS domain of swarmd's participant in the agent = UXRCE_DDS_DOM_ID
    xrce_domain_id: int = 0
    # xrce-agent with PX4 SITL on this computer's loopback: the uid PX4 runs as; every other
    # local user's loopback datagram is dropped (swarmd.senderuid). None: not told apart
    loopback_user: int | None = None


@dataclass(frozen=True, slots=True)
class DataplaneSection:
    """``dataplane:``: RTPS user data (docs/dataplane.md). Absent: off (discovery only)."""

    enabled: bool = False
    readiness_period_s: float = 1.0  # swarm/ready: the paper's 1 Hz workload
    # the commander counts a member whose last report is older than this as not ready
    stale_after_s: float = 3.0
    state_dir: str = DEFAULT_STATE_DIR  # boot counter + executed command ids survive restarts


@dataclass(frozen=True, slots=True)
class Ros2Section:
    """``ros2:``: serve SPDP to this drone's stock ROS 2 nodes on loopback (docs/ros2.md,
    swarmd.ros2.relay). Absent: off. The nodes' profiles come from ``swarmctl ros2 profile
    --via-swarmd`` with the same ``relay_port``."""

    relay: bool = False
    relay_port: int = 7399  # swarmd.ros2.relay.DEFAULT_RELAY_PORT, on [::1] only
    # the lease the relay announces for other drones' ROS 2 participants; renewed 4 times in it
    lease_s: float = 20.0
    # the uids allowed to be this drone's ROS 2 nodes: another local user's datagram to the
    # relay is dropped (swarmd.senderuid). None: every local process is taken as a node
    node_users: frozenset[int] | None = None


@dataclass(frozen=True, slots=True)
class DaemonConfig:
    """A checked daemon config. ``lines`` maps a field path to its line, for later errors."""

    file: str
    node: str
    interface: str
    bundle: BundleConfig = BundleConfig()
    ipv4: str | None = None  # None: the interface's first IPv4 address
    control_socket: str = DEFAULT_SOCKET
    control_socket_mode: int = 0o660
    link: LinkConfig = LinkConfig()
    engine_mode: str = "adaptive"
    engine_overrides: dict[str, float] = field(default_factory=dict)
    px4: Px4Section = Px4Section()
    dataplane: DataplaneSection = DataplaneSection()
    ros2: Ros2Section = Ros2Section()
    log_level: str = "info"
    log_format: str = "auto"
    lines: dict[str, int] = field(default_factory=dict, compare=False, repr=False)
    # the fstat of the config file as load_config read it: check_trusted_files judges that
    # very file, whatever its path names by then (a swap between read and check)
    read_stat: os.stat_result | None = field(default=None, compare=False, repr=False)

    def error(self, path: str, problem: str, fix: str) -> ConfigError:
        """A ``ConfigError`` pointing at ``path``'s line (for checks made after loading)."""
        return ConfigError(self.file, self.lines.get(path), path, problem, fix)

    def check_trusted_files(self, also: frozenset[int] = frozenset()) -> None:
        """Raise ``ConfigError`` (one line) when another local user could rewrite the config,
        the bundle or its trust key, node.key or the PX4 signing key file, or swap one in its
        folder: whoever replaces the swarm key and the bundle flies their own mission on
        this node (docs/security-history.md, "Local boundaries (session 10 review)"). Checked
        before any of them is trusted, or opened. ``also``: the daemon's uid when
        ``check-config`` judges for the unit's user."""
        problem = trust_problem(self.file, also)
        if problem is None and self.read_stat is not None:
            why = writers_problem(self.read_stat, also)
            problem = None if why is None else f"file {self.file} (as read) is {why}"
        if problem is not None:
            raise ConfigError(
                self.file,
                None,
                "<file>",
                f"{problem}, so another user could rewrite this config",
                "chown root:swarmd and chmod 640 it, in a folder only root writes "
                "(/etc/swarmd, 0750)",
            )
        # node.key and the PX4 link's key file are credentials too: whoever plants one the
        # daemon reads (a FIFO it waits on, a key they know) or reads one they own speaks for
        # this drone, or for its autopilot (docs/security-history.md, session 15 review);
        # judged here, before any of them is opened
        signing_key = self.px4.signing_key if self.px4.enabled and self.px4.signing else None
        for key, path in (
            ("bundle.trusted_key", self.bundle.trusted_key),
            ("bundle.path", self.bundle.path),
            ("bundle.node_key", self.bundle.node_key_path),
            ("px4.signing_key", signing_key),
        ):
            problem = trust_problem(path, also) if path is not None else None
            if problem is not None:
                raise self.error(
                    key,
                    f"{problem}, so another user could swap it",
                    "make it and its folder writable by root or swarmd alone (chmod go-w; "
                    "/etc/swarmd/keys, /var/lib/swarmd)",
                )

    def member_of(self, bundle: Bundle) -> Participant:
        """This node's participant in ``bundle``; a ``ConfigError`` at ``node`` if none."""
        try:
            return bundle.member(self.node)
        except NotAParticipant as exc:
            raise self.error("node", exc.problem, exc.fix) from None


def trust_problem(path: str | Path, also: frozenset[int] = frozenset()) -> str | None:
    """Why another local user could rewrite ``path`` or swap it in its folder, or None.

    A missing file is None here: reading it fails with its own one line."""
    file = Path(path)
    for kind, where in (("file", file), ("folder", file.parent)):
        why = others_can_write(where, also)
        if why is not None:
            return f"{kind} {where} is {why}"
    return None


def config_mode_problem(path: str | Path) -> str | None:
    """What is wrong with the config file's mode for a production drone, or None.

    Readable by every user: it names the key files and the PX4 link (docs/deploy.md:
    0640 root:swarmd). swarmd warns (``config_mode``) and starts: the node's secrets are
    elsewhere, each refused when others may read it."""
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        return None
    if mode & 0o004:
        return f"mode {mode:04o} lets every user read it; fix: chmod 640 {path} (root:swarmd)"
    return None
