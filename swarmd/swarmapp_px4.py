"""The PX4 link of ``SwarmApp`` (``swarmd/swarmapp.py``): the bridge built from the config
(its MAVLink signing key, an XRCE agent's vehicle key, the warning about a port any user
may bind; docs/px4.md) and the vehicle's answers into the swarm core (readiness changes,
ended tasks). Split out of ``swarmapp.py`` by concern at 773 lines (style.md rule 19).
"""

from __future__ import annotations

import os
import socket
from pathlib import Path

from swarmd.auth.keys import NodeSecrets
from swarmd.bundle.statedir import DaemonUser
from swarmd.dataplane.convert import ReadinessVerdict
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_OSERR, StartupError
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.provision import SigningKeyError, ed25519_seed, signing_key_for
from swarmd.px4.readiness import Readiness, ReadinessConfig
from swarmd.px4.transport import (
    PX4_SOCKET,
    XRCE_SOCKET,
    parse_connection,
    unprivileged_port_start,
)
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished
from swarmd.px4.xrce_key import XrceKey, XrceKeyError
from swarmd.px4.xrce_key import check as check_xrce_key
from swarmd.px4.xrce_key import load_or_create as load_or_create_xrce_key
from swarmd.swarm.member import NO_VEHICLE
from swarmd.swarmapp_status import SwarmAppStatus


class VehicleLink(SwarmAppStatus):
    """The PX4 bridge built (``start``, ``check``) and its callbacks into the core; the
    bridge itself is shared state (``SwarmAppStatus``: status, the write-ahead, stop)."""

    node_secrets: NodeSecrets | None  # the PX4 link's signing key derives from them
    # the link's port as systemd bound it: swarmd-px4.socket (MAVLink udpin:) or
    # swarmd-xrce.socket (the XRCE agent's udp:), docs/px4.md
    px4_socket: socket.socket | None

    def _px4_bridge(self, *, write: bool, user: DaemonUser | None = None) -> Px4Bridge:
        """The PX4 bridge of the config, built and not started; ``write``: an XRCE agent's
        key file is generated (or its mode fixed) when it must be, else only read."""
        px4 = self.config.px4
        sysid = px4.sysid if px4.sysid is not None else self.me.mavlink_sysid
        signing_key: bytes | None = None
        # the per-drone MAVLink key (docs/px4.md, "Message signing"); MAVLink only: PX4's
        # uXRCE-DDS client has no message authentication to key
        if px4.signing and px4.backend == "mavlink":
            secrets = self.node_secrets
            if secrets is None and px4.signing_key is None:
                raise StartupError(
                    "px4.signing: no node secrets to derive the MAVLink key from; fix: "
                    "flash node.key, set px4.signing_key, or px4.signing: false",
                    EX_CONFIG,
                )
            seed = b"" if secrets is None else ed25519_seed(secrets.ed25519)
            try:
                signing_key = signing_key_for(
                    swarm=self.bundle.swarm,
                    node=self.me.name,
                    key_file=px4.signing_key,
                    seed=seed,
                    also=user.own_uid if user else frozenset(),
                )
            except SigningKeyError as exc:
                raise StartupError(str(exc), EX_CONFIG) from None
        xrce = px4.backend == "xrce-agent"
        xrce_key = self._xrce_key(write=write, user=user) if xrce else px4.xrce_key
        try:
            return Px4Bridge.from_config(
                Px4Config(
                    connection=px4.connection,
                    sysid=sysid,
                    autopilot=px4.autopilot,
                    signing_key=signing_key,
                    backend=px4.backend,
                    xrce_key=xrce_key,
                    namespace=px4.namespace,
                    xrce_domain_id=px4.xrce_domain_id,
                    loopback_user=px4.loopback_user,
                    listen_socket=self.px4_socket,
                    readiness=ReadinessConfig(
                        heartbeat_timeout_s=px4.heartbeat_timeout_s,
                        min_battery_pct=px4.min_battery_pct,
                        require_home=px4.require_home,
                        allow_unknown_battery=px4.allow_unknown_battery,
                    ),
                ),
                log=self.log,
            )
        except ValueError as exc:
            raise StartupError(f"px4.connection {px4.connection}: {exc}", EX_OSERR) from None

    def _xrce_key(self, *, write: bool, user: DaemonUser | None = None) -> int | None:
        """The vehicle key the XRCE agent is bound to: ``px4.xrce_key``, else the one kept
        with the node's secrets, generated at the first start (docs/px4.md, "One agent, one
        vehicle"). ``write=False``: the file read only, None when there is none yet."""
        configured = self.config.px4.xrce_key
        if configured is not None:
            if write:
                self.log.info("xrce_key", source="px4.xrce_key")
            return configured
        folder = os.path.dirname(os.path.abspath(self.config.bundle.node_key_path))
        key: XrceKey | None
        try:
            if write:
                key = load_or_create_xrce_key(folder)
            else:  # check-config: the folder's owners as the daemon's user sees them
                owners = user.trusted_owners(Path(folder)) if user else frozenset()
                key = check_xrce_key(folder, owners)
        except XrceKeyError as exc:
            raise StartupError(f"px4.xrce_key: {exc}", EX_CANTCREAT) from None
        if key is None or not write:
            return None if key is None else key.value
        if key.created:
            # the operator's one step: PX4 must send this key or its sessions are refused
            self.log.warning(
                "xrce_key_generated",
                path=str(key.path),
                xrce_key=key.value,
                fix=f"on PX4: param set UXRCE_DDS_KEY {key.value} (or set px4.xrce_key)",
            )
        else:
            self.log.info("xrce_key", source=str(key.path))
        if key.mode_fixed:
            self.log.warning("xrce_key_mode_fixed", path=str(key.path), mode="0600")
        return key.value

    def _warn_unprivileged_port(self) -> None:
        """A UDP port any user may bind can be taken while swarmd (or its agent) is down
        (issue 18): the MAVLink ``udpin:`` port, the XRCE agent's port swarmd listens on, or,
        as ``xrce-client``, the MicroXRCEAgent's port swarmd reaches (docs/px4.md)."""
        px4 = self.config.px4
        if px4.backend == "mavlink":
            endpoint = parse_connection(px4.connection)
            fix = f"a port below 1024 held by {PX4_SOCKET.unit} (docs/px4.md)"
        else:
            from swarmd.px4.xrce_backend import parse_xrce_connection  # XRCE configs only

            endpoint = parse_xrce_connection(px4.connection)
            fix = (
                f"a port below 1024 held by {XRCE_SOCKET.unit} (docs/px4.md)"
                if px4.backend == "xrce-agent"
                else "run MicroXRCEAgent on a port below 1024 (docs/px4.md, xrce-client)"
            )
        lowest = unprivileged_port_start()
        if endpoint.kind == "udpin" and endpoint.port >= lowest:
            self.log.warning(
                "px4_port_unprivileged",
                backend=px4.backend,
                port=endpoint.port,
                unprivileged_port_start=lowest,
                socket_activated=self.px4_socket is not None,
                fix=fix,
            )

    # ---- the vehicle ----------------------------------------------------------------------

    def verdict(self) -> ReadinessVerdict:
        if self.bridge is None:
            return NO_VEHICLE
        return self.bridge.readiness()

    def _on_px4_change(self, verdict: Readiness) -> None:
        reason = None if verdict.reason is None else str(verdict.reason)
        swarm, driver = self._core(), self._driver()
        driver.call(lambda now: swarm.vehicle_changed(verdict.ready, reason, now))

    def _on_task_finished(self, done: TaskFinished | DisarmUnconfirmed) -> None:
        swarm, driver = self._core(), self._driver()
        driver.call(lambda now: swarm.task_finished(done, now))
