"""The field readers every section's check is made of: one YAML node in, one checked value
out, or one ``ConfigError`` line (``FILE:LINE: field PATH: problem; fix: ...``) naming the
node's line. ``FIELDS`` lists each section's known fields (an unknown one is refused, with
the list as its fix).
"""

from __future__ import annotations

import math
import pwd
from collections.abc import Callable
from pathlib import Path
from typing import Final, NoReturn

import yaml

from swarmd.config.model import ConfigError
from swarmd.yamldoc import unknown_field

FIELDS: Final[dict[str, tuple[str, ...]]] = {
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


class FieldReader:
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
        allowed = FIELDS[section]
        if not isinstance(node, yaml.MappingNode):
            self.fail(node, section, "expected a mapping (key: value lines)", "indent its fields")
        out: Nodes = {}
        for key_node, value_node in node.value:
            key = self.loader.construct_object(key_node, deep=True)
            path = str(key) if section == "<top>" else f"{section}.{key}"
            if not isinstance(key, str) or key not in allowed:
                self.fail(key_node, path, *unknown_field(key, allowed))
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
