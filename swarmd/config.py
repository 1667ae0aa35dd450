"""The daemon's configuration file (``swarmd run --config FILE``), checked field by field.

The documented default is ``config/swarmd.yaml``. Checking walks PyYAML's composed node tree
(the plain loaded dict has no line numbers), so every rejection is one line of the form
``FILE:LINE: field PATH: problem; fix: ...`` and the daemon stops with exit 78 (EX_CONFIG)
before it opens a socket. Relative paths are taken relative to the config file's folder.
"""

from __future__ import annotations

import ipaddress
import math
import os
import pwd
import stat
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, NoReturn

import yaml

from swarmd.bundle.keys import others_can_write
from swarmd.bundle.model import Bundle, NotAParticipant, Participant
from swarmd.dataplane.validity import MIN_REPORT_PERIOD_MS
from swarmd.discovery.config import MODES
from swarmd.link import SourceName
from swarmd.yamldoc import FieldError, composed, read_text

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

    def error(self, path: str, problem: str, fix: str) -> ConfigError:
        """A ``ConfigError`` pointing at ``path``'s line (for checks made after loading)."""
        return ConfigError(self.file, self.lines.get(path), path, problem, fix)

    def check_trusted_files(self) -> None:
        """Raise ``ConfigError`` (one line) when another local user could rewrite the config,
        the bundle or its trust key, or swap one in its folder: whoever replaces the swarm
        key and the bundle flies their own mission on this node (docs/security-history.md,
        "Local boundaries (session 10 review)"). Checked before any of them is trusted."""
        problem = trust_problem(self.file)
        if problem is not None:
            raise ConfigError(
                self.file,
                None,
                "<file>",
                f"{problem}, so another user could rewrite this config",
                "chown root:swarmd and chmod 640 it, in a folder only root writes "
                "(/etc/swarmd, 0750)",
            )
        for key, path in (
            ("bundle.trusted_key", self.bundle.trusted_key),
            ("bundle.path", self.bundle.path),
        ):
            problem = trust_problem(path) if path is not None else None
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


_FIELDS: Final[dict[str, tuple[str, ...]]] = {
    "<top>": (
        "node",
        "bundle",
        "network",
        "control",
        "link",
        "discovery",
        "px4",
        "dataplane",
        "ros2",
        "logging",
    ),
    "bundle": ("path", "trusted_key", "expected_sha256", "allow_dev", "node_key"),
    "network": ("interface", "ipv4"),
    "control": ("socket", "mode"),
    "link": (
        "sources",
        "poll_interval_s",
        "file",
        "file_max_age_s",
        "wext_path",
        "wext_max_quality",
        "static_q",
        "snr_floor_db",
    ),
    "discovery": ("mode", "overrides"),
    "px4": (
        "enabled",
        "connection",
        "sysid",
        "allow_network",
        "autopilot",
        "signing",
        "signing_key",
        "heartbeat_timeout_s",
        "min_battery_pct",
        "allow_unknown_battery",
        "require_home",
        "takeoff_alt_m",
        "backend",
        "xrce_key",
        "namespace",
        "xrce_domain_id",
        "loopback_user",
    ),
    "dataplane": ("enabled", "readiness_period_s", "stale_after_s", "state_dir"),
    "ros2": ("relay", "relay_port", "lease_s", "node_users"),
    "logging": ("level", "format"),
}

Nodes = dict[str, yaml.Node]


def trust_problem(path: str | Path) -> str | None:
    """Why another local user could rewrite ``path`` or swap it in its folder, or None.

    A missing file is None here: reading it fails with its own one line."""
    file = Path(path)
    for kind, where in (("file", file), ("folder", file.parent)):
        why = others_can_write(where)
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


def load_config(path: str | Path, *, engine_fields: frozenset[str] | None = None) -> DaemonConfig:
    """Read and check ``path``; raises ``ConfigError`` (one line) on any problem.

    ``engine_fields``: the names ``discovery.overrides`` may set (the engine config's
    fields); None skips that check.
    """
    file = str(path)
    text = read_text(
        path, ConfigError, missing_fix="give the path of swarmd.yaml", what="config file"
    )
    return parse_config(text, file, base=Path(path).parent, engine_fields=engine_fields)


def parse_config(
    text: str,
    file: str = "<config>",
    *,
    base: Path | None = None,
    engine_fields: frozenset[str] | None = None,
) -> DaemonConfig:
    """Check a config given as YAML text; relative paths resolve against ``base``."""
    with composed(text, file, ConfigError, empty_fix="see config/swarmd.yaml") as (root, loader):
        return _Checker(file, loader, base, engine_fields).config(root)


class _Checker:
    def __init__(
        self,
        file: str,
        loader: yaml.SafeLoader,
        base: Path | None,
        engine_fields: frozenset[str] | None,
    ) -> None:
        self.file = file
        self.loader = loader
        self.base = base
        self.engine_fields = engine_fields
        self.lines: dict[str, int] = {}

    def fail(self, node: yaml.Node, path: str, problem: str, fix: str) -> NoReturn:
        raise ConfigError(self.file, node.start_mark.line + 1, path, problem, fix)

    def mapping(self, node: yaml.Node, section: str) -> Nodes:
        allowed = _FIELDS[section]
        if not isinstance(node, yaml.MappingNode):
            self.fail(node, section, "expected a mapping (key: value lines)", "indent its fields")
        out: Nodes = {}
        for key_node, value_node in node.value:
            key = self.loader.construct_object(key_node, deep=True)
            path = str(key) if section == "<top>" else f"{section}.{key}"
            if not isinstance(key, str) or key not in allowed:
                self.fail(
                    key_node,
                    path,
                    f"unknown field {key!r}",
                    f"remove it or correct the spelling; known fields: {', '.join(allowed)}",
                )
            if key in out:
                self.fail(key_node, path, "duplicate key", "keep one of them")
            out[key] = value_node
            self.lines[path] = value_node.start_mark.line + 1
        return out

    def value(self, node: yaml.Node, path: str) -> object:
        if not isinstance(node, yaml.ScalarNode):
            self.fail(node, path, "expected a single value", "write a plain value, not a list/map")
        return self.loader.construct_object(node, deep=True)

    def string(self, node: yaml.Node, path: str, what: str, *, nullable: bool = False) -> str:
        value = self.value(node, path)
        if value is None and nullable:
            return ""
        if not isinstance(value, str) or not value:
            self.fail(node, path, f"expected {what}, got {value!r}", f"write {what}")
        return value

    def path(self, node: yaml.Node, key: str, *, nullable: bool = False) -> str | None:
        text = self.string(node, key, "a file path", nullable=nullable)
        if not text:
            return None
        p = Path(text)
        return str(self.base / p) if self.base is not None and not p.is_absolute() else str(p)

    def number(self, node: yaml.Node, path: str, low: float, high: float, unit: str = "") -> float:
        value = self.value(node, path)
        if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
            self.fail(node, path, f"expected a number, got {value!r}", f"write e.g. {low}{unit}")
        if not low <= value <= high:
            self.fail(node, path, f"{value} is outside {low}..{high}", f"use {low}..{high}{unit}")
        return float(value)

    def boolean(self, node: yaml.Node, path: str) -> bool:
        value = self.value(node, path)
        if not isinstance(value, bool):
            self.fail(node, path, f"expected true or false, got {value!r}", "write true or false")
        return value

    def choice(self, node: yaml.Node, path: str, names: tuple[str, ...]) -> str:
        value = self.value(node, path)
        if not isinstance(value, str) or value not in names:
            self.fail(node, path, f"unknown value {value!r}", f"use one of: {', '.join(names)}")
        return value

    def user(self, node: yaml.Node, path: str) -> int:
        """A local user by name (resolved here, from the passwd database) or uid."""
        value = self.value(node, path)
        if isinstance(value, int) and not isinstance(value, bool):
            if not 0 <= value < 0xFFFF_FFFF:  # (uid_t) -1 is "no user"
                self.fail(node, path, f"{value} is no uid", "write a user name or a uid")
            return value
        if not isinstance(value, str) or not value:
            self.fail(node, path, f"expected a user, got {value!r}", "write a user name or uid")
        try:
            return pwd.getpwnam(value).pw_uid
        except KeyError:
            self.fail(node, path, f"no user {value!r} on this computer",
                      "create it, or write the user the process runs as (id -un)")  # fmt: skip

    def section(self, top: Nodes, name: str, parse: Callable[[Nodes], None]) -> None:
        if name in top:
            parse(self.mapping(top[name], name))

    # -- the config ----------------------------------------------------------------------

    def config(self, root: yaml.Node) -> DaemonConfig:
        top = self.mapping(root, "<top>")
        if "node" not in top:
            self.fail(root, "node", "missing required field", "add 'node: NAME' (this drone)")
        node = self.string(top["node"], "node", "this drone's participant name")
        values: dict[str, object] = {"node": node}
        bundle = BundleConfig()

        def bundle_section(f: Nodes) -> None:
            nonlocal bundle
            sha: bytes | None = None
            if "expected_sha256" in f:
                text = self.string(f["expected_sha256"], "bundle.expected_sha256", "64 hex digits")
                try:
                    sha = bytes.fromhex(text)
                except ValueError:
                    sha = b""
                if len(sha) != 32:
                    self.fail(
                        f["expected_sha256"],
                        "bundle.expected_sha256",
                        "not a SHA-256 in hex",
                        "paste the hash 'swarmctl bundle show' prints (64 hex digits)",
                    )
            bundle = BundleConfig(
                path=self.path(f["path"], "bundle.path") or DEFAULT_BUNDLE
                if "path" in f
                else DEFAULT_BUNDLE,
                trusted_key=self.path(f["trusted_key"], "bundle.trusted_key", nullable=True)
                if "trusted_key" in f
                else None,
                expected_sha256=sha,
                allow_dev=self.boolean(f["allow_dev"], "bundle.allow_dev")
                if "allow_dev" in f
                else False,
                node_key=self.path(f["node_key"], "bundle.node_key", nullable=True)
                if "node_key" in f
                else None,
            )
            if bundle.trusted_key is None and bundle.expected_sha256 is None:
                self.fail(
                    f.get("trusted_key", top["bundle"]),
                    "bundle.trusted_key",
                    "no trust anchor: a bundle would be accepted from anyone",
                    "set bundle.trusted_key to the swarm-signing.pub path "
                    "(or bundle.expected_sha256)",
                )

        if "bundle" not in top:
            self.fail(root, "bundle", "missing required section", "add 'bundle:' with trusted_key")
        self.section(top, "bundle", bundle_section)

        if "network" not in top:
            self.fail(
                root, "network", "missing required section", "add 'network: {interface: wlan0}'"
            )

        def network(f: Nodes) -> None:
            if "interface" not in f:
                self.fail(top["network"], "network.interface", "missing", "add 'interface: wlan0'")
            values["interface"] = self.string(f["interface"], "network.interface", "a name")
            if "ipv4" in f:
                raw = self.value(f["ipv4"], "network.ipv4")
                if raw is not None:
                    try:
                        values["ipv4"] = str(ipaddress.IPv4Address(str(raw)))
                    except ValueError:
                        self.fail(
                            f["ipv4"],
                            "network.ipv4",
                            f"{raw!r} is not an IPv4 address",
                            "write e.g. 10.0.0.2, or null to use the interface's address",
                        )

        self.section(top, "network", network)

        def control(f: Nodes) -> None:
            if "socket" in f:
                values["control_socket"] = self.path(f["socket"], "control.socket")
            if "mode" in f:
                raw = self.value(f["mode"], "control.mode")
                try:
                    mode = int(str(raw), 8)
                except ValueError:
                    mode = -1
                if not 0 <= mode <= 0o777:
                    self.fail(
                        f["mode"], "control.mode", f"{raw!r} is not a file mode", 'write "0660"'
                    )
                if mode & 0o007:  # connect(2) needs only the write bit: take-off for anyone
                    self.fail(
                        f["mode"],
                        "control.mode",
                        f"{raw!r} opens the control socket to every local user",
                        'write "0660" (root and group swarmd)',
                    )
                values["control_socket_mode"] = mode

        self.section(top, "control", control)
        values["link"] = LinkConfig()

        def link(f: Nodes) -> None:
            d = LinkConfig()
            sources = d.sources
            if "sources" in f:
                n = f["sources"]
                if not isinstance(n, yaml.SequenceNode) or not n.value:
                    self.fail(
                        n, "link.sources", "expected a non-empty list", "e.g. [nl80211, static]"
                    )
                sources = tuple(
                    self.choice(item, "link.sources", tuple(SourceName)) for item in n.value
                )
                if len(set(sources)) != len(sources):
                    self.fail(n, "link.sources", "a source is listed twice", "list each once")
            num = self.number
            values["link"] = LinkConfig(
                sources=sources,
                poll_interval_s=num(
                    f["poll_interval_s"], "link.poll_interval_s", MIN_POLL_S, MAX_POLL_S, " s"
                )
                if "poll_interval_s" in f
                else d.poll_interval_s,
                file=(self.path(f["file"], "link.file") or d.file) if "file" in f else d.file,
                file_max_age_s=num(f["file_max_age_s"], "link.file_max_age_s", 0.1, 86400, " s")
                if "file_max_age_s" in f and self.value(f["file_max_age_s"], "-") is not None
                else None,
                wext_path=(self.path(f["wext_path"], "link.wext_path") or d.wext_path)
                if "wext_path" in f
                else d.wext_path,
                wext_max_quality=num(f["wext_max_quality"], "link.wext_max_quality", 1, 255)
                if "wext_max_quality" in f
                else d.wext_max_quality,
                static_q=num(f["static_q"], "link.static_q", 0.0, 1.0)
                if "static_q" in f
                else d.static_q,
                snr_floor_db=num(f["snr_floor_db"], "link.snr_floor_db", -20.0, 39.0, " dB")
                if "snr_floor_db" in f
                else d.snr_floor_db,
            )

        self.section(top, "link", link)

        def discovery(f: Nodes) -> None:
            if "mode" in f:
                values["engine_mode"] = self.choice(f["mode"], "discovery.mode", MODES)
            if "overrides" in f:
                values["engine_overrides"] = self.overrides(f["overrides"])

        self.section(top, "discovery", discovery)
        self.section(top, "px4", lambda f: values.__setitem__("px4", self.px4(f)))
        self.section(top, "dataplane", lambda f: values.__setitem__("dataplane", self.dataplane(f)))
        self.section(top, "ros2", lambda f: values.__setitem__("ros2", self.ros2(f)))

        def logging(f: Nodes) -> None:
            if "level" in f:
                values["log_level"] = self.choice(f["level"], "logging.level", LOG_LEVELS)
            if "format" in f:
                values["log_format"] = self.choice(f["format"], "logging.format", LOG_FORMATS)

        self.section(top, "logging", logging)
        return DaemonConfig(file=self.file, bundle=bundle, lines=self.lines, **values)  # type: ignore[arg-type]

    def px4(self, f: Nodes) -> Px4Section:
        # only px4 configs pay for the transport import
        from swarmd.px4.transport import is_network_endpoint, parse_address, parse_connection

        def relay(node: yaml.Node, path: str, exc: ValueError) -> NoReturn:
            problem, _, fix = str(exc).removeprefix(f"{path}: ").partition("; fix: ")
            self.fail(node, path, problem, fix or "see docs/px4.md")

        d = Px4Section()
        backend = d.backend
        if "backend" in f:
            backend = self.string(f["backend"], "px4.backend", "mavlink, xrce-agent or xrce-client")
            if backend not in ("mavlink", "xrce-agent", "xrce-client"):
                self.fail(f["backend"], "px4.backend", f"{backend!r} is not a backend",
                          "mavlink, xrce-agent or xrce-client")  # fmt: skip
        xrce = backend != "mavlink"
        # PX4 SITL's agent port 8888 moved below 1024, where no local user can bind it (issue 18)
        connection = "udp:127.0.0.1:888" if xrce else d.connection
        where = f.get("connection")
        if where is not None:
            connection = self.string(where, "px4.connection", "a connection string")
            from swarmd.px4.xrce_backend import parse_xrce_connection

            try:
                endpoint = (parse_xrce_connection if xrce else parse_connection)(
                    connection, "px4.connection"
                )
            except ValueError as exc:
                relay(where, "px4.connection", exc)
            allow_network = (
                self.boolean(f["allow_network"], "px4.allow_network")
                if "allow_network" in f
                else False
            )
            if is_network_endpoint(endpoint) and not allow_network:
                # issue 10, attack 6: a wildcard listener hears the swarm's Wi-Fi
                self.fail(
                    where,
                    "px4.connection",
                    f"{connection} reaches beyond loopback: any host on the network could pose "
                    "as the autopilot",
                    "use udpin:127.0.0.1:14540 (PX4 SITL, mavlink-router) or "
                    "serial:/dev/ttyTHS1:921600; for an FMU on Ethernet set "
                    "px4.allow_network: true and px4.autopilot: IP:PORT",
                )
        autopilot: str | None = None
        if "autopilot" in f and self.value(f["autopilot"], "px4.autopilot") is not None:
            raw = self.string(f["autopilot"], "px4.autopilot", "IP:PORT")
            try:
                autopilot = parse_address(raw, "px4.autopilot")
            except ValueError as exc:
                relay(f["autopilot"], "px4.autopilot", exc)
            if xrce or parse_connection(connection).kind != "udpin":
                self.fail(
                    f["autopilot"],
                    "px4.autopilot",
                    "only a MAVLink udpin: connection learns its autopilot's address",
                    "remove px4.autopilot (udpout pins its target; a UART has one peer)",
                )
        signing_key = (
            self.path(f["signing_key"], "px4.signing_key", nullable=True)
            if "signing_key" in f
            else None
        )
        sysid: int | None = None
        if "sysid" in f and self.value(f["sysid"], "px4.sysid") is not None:
            number = self.number(f["sysid"], "px4.sysid", 1, 255)
            if number != int(number):
                self.fail(f["sysid"], "px4.sysid", f"{number} is not a whole number", "1..255")
            sysid = int(number)

        xrce_domain_id = d.xrce_domain_id
        if "xrce_domain_id" in f:
            node, path = f["xrce_domain_id"], "px4.xrce_domain_id"
            if backend != "xrce-client":
                self.fail(node, path,
                          f"only xrce-client creates a DDS participant ({backend} has no domain)",
                          "remove it, or use px4.backend: xrce-client")  # fmt: skip
            # 232: the highest domain whose RTPS ports (7400 + 250 * domain + offsets, DDSI-RTPS
            # 9.6.1.1) fit in 16 bits; Fast DDS refuses more
            number = self.number(node, path, 0, 232)
            if number != int(number):
                self.fail(node, path, f"{number:g} is not a whole number",
                          "write PX4's UXRCE_DDS_DOM_ID, a whole number 0..232")  # fmt: skip
            xrce_domain_id = int(number)

        def num(key: str, low: float, high: float, unit: str, default: float) -> float:
            return self.number(f[key], f"px4.{key}", low, high, unit) if key in f else default

        def flag(key: str, default: bool) -> bool:
            return self.boolean(f[key], f"px4.{key}") if key in f else default

        return Px4Section(
            enabled=flag("enabled", True),
            connection=connection,
            sysid=sysid,
            allow_network=flag("allow_network", d.allow_network),
            autopilot=autopilot,
            signing=flag("signing", d.signing),
            signing_key=signing_key,
            heartbeat_timeout_s=num("heartbeat_timeout_s", 0.5, 30.0, " s", d.heartbeat_timeout_s),
            min_battery_pct=num("min_battery_pct", 0.0, 100.0, " %", d.min_battery_pct),
            allow_unknown_battery=flag("allow_unknown_battery", d.allow_unknown_battery),
            require_home=flag("require_home", d.require_home),
            takeoff_alt_m=num("takeoff_alt_m", 0.5, 120.0, " m", d.takeoff_alt_m),
            backend=backend,
            xrce_key=(
                int(self.number(f["xrce_key"], "px4.xrce_key", 1, 0xFFFFFFFF))
                if "xrce_key" in f
                else None
            ),
            namespace=(
                self.string(f["namespace"], "px4.namespace", "PX4's UXRCE_DDS_NS")
                if "namespace" in f
                else None
            ),
            xrce_domain_id=xrce_domain_id,
            loopback_user=self.loopback_user(f, backend),
        )

    def loopback_user(self, f: Nodes, backend: str) -> int | None:
        if "loopback_user" not in f:
            return None
        node, path = f["loopback_user"], "px4.loopback_user"
        if backend != "xrce-agent":
            self.fail(
                node,
                path,
                f"only the xrce-agent backend tells loopback users apart ({backend} does not)",
                "remove it, or use px4.backend: xrce-agent",
            )
        return self.user(node, path)

    def dataplane(self, f: Nodes) -> DataplaneSection:
        d = DataplaneSection()
        period = (
            self.number(
                f["readiness_period_s"],
                "dataplane.readiness_period_s",
                MIN_REPORT_PERIOD_MS / 1000.0,  # the report log's cap assumes it
                60.0,
                " s",
            )
            if "readiness_period_s" in f
            else d.readiness_period_s
        )
        stale = (
            self.number(f["stale_after_s"], "dataplane.stale_after_s", 0.1, 600.0, " s")
            if "stale_after_s" in f
            else max(d.stale_after_s, 3 * period)
        )
        if stale <= period:
            where = f["stale_after_s"] if "stale_after_s" in f else f["readiness_period_s"]
            self.fail(
                where,
                "dataplane.stale_after_s",
                f"{stale:g} s does not exceed readiness_period_s {period:g} s: every member "
                "would look stale between two reports",
                "make stale_after_s at least 2-3 readiness periods",
            )
        return DataplaneSection(
            enabled=self.boolean(f["enabled"], "dataplane.enabled") if "enabled" in f else True,
            readiness_period_s=period,
            stale_after_s=stale,
            state_dir=(self.path(f["state_dir"], "dataplane.state_dir") or d.state_dir)
            if "state_dir" in f
            else d.state_dir,
        )

    def ros2(self, f: Nodes) -> Ros2Section:
        d = Ros2Section()
        port = (
            self.number(f["relay_port"], "ros2.relay_port", 1, 65535)
            if "relay_port" in f
            else d.relay_port
        )
        if port != int(port):
            self.fail(f["relay_port"], "ros2.relay_port", f"{port} is no port", "write e.g. 7399")
        return Ros2Section(
            relay=self.boolean(f["relay"], "ros2.relay") if "relay" in f else True,
            relay_port=int(port),
            lease_s=self.number(f["lease_s"], "ros2.lease_s", 2.0, 600.0, " s")
            if "lease_s" in f
            else d.lease_s,
            node_users=self.node_users(f["node_users"]) if "node_users" in f else None,
        )

    def node_users(self, node: yaml.Node) -> frozenset[int]:
        path = "ros2.node_users"
        if isinstance(node, yaml.ScalarNode):
            return frozenset({self.user(node, path)})
        if not isinstance(node, yaml.SequenceNode) or not node.value:
            self.fail(node, path, "expected a user or a list of users",
                      "write e.g. node_users: [ros]  (names or uids)")  # fmt: skip
        return frozenset(self.user(item, path) for item in node.value)

    def overrides(self, node: yaml.Node) -> dict[str, float]:
        if not isinstance(node, yaml.MappingNode):
            self.fail(
                node, "discovery.overrides", "expected a mapping", "write 'name: value' lines"
            )
        out: dict[str, float] = {}
        for key_node, value_node in node.value:
            key = self.loader.construct_object(key_node, deep=True)
            path = f"discovery.overrides.{key}"
            if not isinstance(key, str) or (
                self.engine_fields is not None and key not in self.engine_fields
            ):
                known = ", ".join(sorted(self.engine_fields or ()))
                self.fail(key_node, path, f"unknown engine setting {key!r}", f"use one of: {known}")
            out[key] = self.number(value_node, path, 0.0, 1e6)
            self.lines[path] = value_node.start_mark.line + 1
        return out
