"""The whole config, section by section: the required ``node``, ``bundle`` and ``network``,
then ``control``, ``link``, ``discovery`` (with its engine overrides), ``px4``
(``swarmd.config.px4``), ``dataplane`` and ``ros2`` (``swarmd.config.services``) and
``logging``. The first problem stops the check with one line.
"""

from __future__ import annotations

import ipaddress

import yaml

from swarmd.config.model import (
    DEFAULT_BUNDLE,
    LOG_FORMATS,
    LOG_LEVELS,
    MAX_POLL_S,
    MIN_POLL_S,
    BundleConfig,
    DaemonConfig,
    LinkConfig,
)
from swarmd.config.px4 import Px4Fields
from swarmd.config.reader import Nodes
from swarmd.config.services import ServiceFields
from swarmd.discovery.config import MODES
from swarmd.link import SourceName


class Checker(Px4Fields, ServiceFields):
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
