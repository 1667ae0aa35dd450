"""The ``px4:`` section (docs/px4.md): the backend, its connection (loopback unless
``allow_network``), the pinned autopilot, signing, the XRCE settings and the loopback user.
"""

from __future__ import annotations

from typing import NoReturn

import yaml

from swarmd.config.model import Px4Section
from swarmd.config.reader import FieldReader, Nodes


class Px4Fields(FieldReader):
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
            try:
                if xrce:
                    # only XRCE configs pay for the backend's import (asyncio, the XRCE
                    # agent): a MAVLink drone's start-up does not (docs/benchmarks.md,
                    # "Daemon start-up")
                    from swarmd.px4.xrce_backend import parse_xrce_connection

                    endpoint = parse_xrce_connection(connection, "px4.connection")
                else:
                    endpoint = parse_connection(connection, "px4.connection")
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
