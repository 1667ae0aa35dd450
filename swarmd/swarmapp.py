"""The swarm's wiring in one daemon: sockets, the state file and the PX4 bridge around the
sans-IO ``SwarmCore`` (``swarm/core.py``), run by the one asyncio ``Driver`` (``swarmd.driver``).

What the swarm is for: every member reports readiness to the commander, the commander
sends take-off, each drone's autopilot takes off. The decisions are the core's (roles,
readiness table, command tracker, request validation, a member's execution); this module
only does their I/O:

- discovery's ``PeerDiscovered``/``PeerRestarted``/``PeerLocatorsChanged``/``PeerLost`` ->
  the core's ``peer_up``/``peer_down`` (user unicast locator = the peer's address +
  ``Bundle.user_port``; the peer's boot epoch from its signed SPDP, to which the plane binds
  every datagram it sends it: docs/security.md);
- the user-data UDP socket feeds the driver; the driver sends what the core queued;
- ``PersistExecuted`` writes the state file on the writer's thread (``swarmd.filewriter``:
  the loop never waits for an fsync), ``VehicleRequest`` goes to the bridge once every
  write asked for before it has ended (the write-ahead), and the bridge's ``TaskFinished``
  and readiness changes come back into the core;
- the control socket's ``takeoff``/``command``/``outcomes`` requests call the core at
  ``loop.time()``; its ``RequestInvalid`` becomes the control socket's.

This module is the composition: ``SwarmApp``'s life (``start``, ``check``, ``stop``) and
discovery's input. Its concerns are its base classes, each in its own module with its
own state (split by concern at 773 lines, style.md rule 19): ``swarmapp_status.py`` (the
shared state, ``status``), ``swarmapp_px4.py`` (the PX4 bridge built, its callbacks),
``swarmapp_saves.py`` (the state file, the data plane built on it, the write-ahead),
``swarmapp_events.py`` (the core's datagrams and events), ``swarmapp_requests.py`` (the
control socket's requests).
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from swarmd.auth.keys import NodeSecrets
from swarmd.bundle.model import Bundle
from swarmd.bundle.statedir import DaemonUser
from swarmd.config import DaemonConfig
from swarmd.dataplane import PairKeys
from swarmd.driver import Driver
from swarmd.exitcodes import EX_OSERR, StartupError
from swarmd.filewriter import FileWriter
from swarmd.statefile import preview
from swarmd.swarm.core import SwarmCore, SwarmSettings
from swarmd.swarm.roles import Roles
from swarmd.swarmapp_events import CoreEvents
from swarmd.swarmapp_px4 import VehicleLink
from swarmd.swarmapp_requests import ControlRequests
from swarmd.swarmapp_saves import dropped_text, on_clock
from swarmd.userdata import UserDataSocket


class SwarmApp(ControlRequests, CoreEvents, VehicleLink):
    """Readiness, commands and the PX4 bridge of one daemon (see the module docstring)."""

    def __init__(
        self,
        config: DaemonConfig,
        bundle: Bundle,
        *,
        log: Any,
        link_q: Callable[[], float],
        keys: PairKeys,
        epoch: int,
        node_secrets: NodeSecrets | None = None,
        px4_socket: socket.socket | None = None,
        booted_before: bool = False,
        writer: FileWriter | None = None,
    ) -> None:
        """``keys`` (the daemon's ``KeyRing``) and ``epoch`` (this boot's, the one its SPDP
        announces) authenticate the data plane's datagrams (docs/security.md).
        ``booted_before``: this node's boot epoch file held an earlier epoch, so a missing
        state file was deleted, not never written (``state_file_missing``). ``writer``:
        the daemon's writer thread (None: one of this app's own)."""
        # each attribute is declared, with why it exists, in the class of its concern
        # (the bases above); the shared ones in SwarmAppStatus
        self.config = config
        self.bundle = bundle
        self.log = log
        self.link_q = link_q
        self.keys = keys
        self.epoch = epoch
        self.node_secrets = node_secrets
        self.px4_socket = px4_socket
        self.booted_before = booted_before
        self.me = config.member_of(bundle)
        self.roles = Roles.of(bundle, self.me)
        self.bridge = None
        self.state = None
        self.plane = None
        self.socket = None
        self.core = None
        self.driver = None
        # discovered peers -> (address, boot epoch), replayed on start
        self._up: dict[str, tuple[str | None, int]] = {}
        self.counters = {"state_save_errors": 0, "state_file_missing": 0}
        self.writer = writer if writer is not None else FileWriter()
        self._saves_asked = 0
        self._saves_answered = 0
        self._held = deque()
        self._stopping = False
        self.on_peer_traffic = None

    # ---- life -----------------------------------------------------------------------------

    async def start(self) -> None:
        """PX4 link, state directory, data plane socket; ``StartupError`` on failure."""
        px4 = self.config.px4
        if px4.enabled:
            built = self._px4_bridge(write=True)
            try:
                await built.start()
            except (OSError, ValueError) as exc:
                reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                raise StartupError(f"px4.connection {px4.connection}: {reason}", EX_OSERR) from None
            self.bridge = built
            self._warn_unprivileged_port()
        try:
            if self.config.dataplane.enabled:
                self._boot_dataplane()
            bridge = self.bridge
            earlier = () if self.state is None else self.state.decisions
            offset = time.time() - asyncio.get_running_loop().time()
            self.core = SwarmCore(
                self.roles,
                self.plane,
                verdict=None if bridge is None else bridge.core.readiness,
                link_q=self.link_q,
                settings=SwarmSettings(
                    readiness_period_s=self.config.dataplane.readiness_period_s,
                    stale_after_s=self.config.dataplane.stale_after_s,
                    takeoff_alt_m=self.config.px4.takeoff_alt_m,
                ),
                # the earlier lives' decisions, dated on this life's clock
                earlier_decisions=[on_clock(d, -offset) for d in earlier],
                told_unsaved=() if self.state is None else self.state.told_unsaved,
                disarm_unconfirmed=() if self.state is None else self.state.disarm_unconfirmed,
            )
            self.driver = Driver(
                self.core,
                transmit=self._transmit,
                on_event=self._on_event,
                name="swarm",
                log=self.log,
            )
            if self.plane is not None:
                await self._open_socket()
        except BaseException:
            await self.stop()
            raise
        for name, (address, epoch) in list(self._up.items()):
            self.peer_up(name, address, epoch)
        if bridge is not None:
            bridge.on_readiness_change(self._on_px4_change)
            bridge.on_task_finished(self._on_task_finished)
        self.driver.call(self.core.start)

    def check(self, user: DaemonUser) -> list[str]:
        """``start``'s checks that neither bind, send nor write (``swarmd check-config``):
        the PX4 link built (its signing key read, an XRCE agent's key file read) and never
        started; the state file read and the data plane built on it, as ``start`` builds
        them, with the same one-line ``StartupError``. ``user``: whose writes the state
        folder is judged for (``swarmd.bundle.statedir``). Writes nothing; returns what
        ``start`` would log as a warning and go on (a state file it would replace)."""
        notes: list[str] = []
        if self.config.px4.enabled:
            self._px4_bridge(write=False, user=user)
        if self.config.dataplane.enabled:
            state = self._state(lambda d, n: preview(d, n, user))
            if state.recovered_from:
                notes.append(f"{state.path}: {state.recovered_from}; run replaces it")
            if state.decisions_dropped:
                notes.append(f"{state.path}: {dropped_text(state)}; run drops them too")
            self._make_plane(state)
        return notes

    async def _open_socket(self) -> None:
        assert self.driver is not None  # noqa: S101 - start() made it
        assert self.state is not None  # noqa: S101 - _boot_dataplane() made it
        port = self.bundle.user_port(self.me)
        try:
            self.socket = await UserDataSocket.open(port, self.driver.datagrams_received)
        except OSError as exc:
            raise StartupError(
                f"cannot bind user-data port {port}: {exc.strerror} "
                "(is another participant with the same bundle index running?)",
                EX_OSERR,
            ) from None
        self.log.info(
            "dataplane_started",
            user_port=port,
            incarnation=self.state.boot,
            executed_restored=len(self.state.executed),
            decisions_restored=len(self.state.decisions),
            commander=self.is_commander,
            reports_readiness=self.reports_readiness,
        )

    async def stop(self) -> None:
        self._stopping = True
        if self.driver is not None:
            self.driver.close()
        # the last state written before we exit; a vehicle request still waiting for its
        # write goes nowhere: the bridge closes now (the safe side, "a crash loses a
        # command, never repeats one")
        await self.writer.flush()
        if self._held:
            self.log.warning("vehicle_requests_dropped_stopping", count=len(self._held))
            self._held.clear()
        if self.socket is not None:
            self.socket.close()
        if self.bridge is not None:
            await self.bridge.close()

    # ---- discovery input ------------------------------------------------------------------

    def peer_up(self, name: str, ipv4: str | None, epoch: int) -> None:
        """Discovery heard ``name`` at ``ipv4`` in boot ``epoch`` (its authenticated SPDP);
        again with a higher epoch when it restarted, or another address when it moved."""
        self._up[name] = (ipv4, epoch)
        if self.driver is None or self.core is None:
            return
        peer = self.bundle.participant(name)
        address = ipv4 or peer.ipv4
        if address is None:
            self.log.warning("peer_without_address", peer=name)
        locator = None if address is None else (address, self.bundle.user_port(peer))
        swarm = self.core
        self.driver.call(lambda now: swarm.peer_up(name, locator, epoch, now))

    def peer_moved(self, name: str, ipv4: str | None) -> None:
        """Discovery heard ``name`` announce another address (authenticated SPDP)."""
        known = self._up.get(name)
        if known is not None:
            self.peer_up(name, ipv4, known[1])

    def peer_down(self, name: str) -> None:
        self._up.pop(name, None)
        if self.driver is not None and self.core is not None:
            swarm = self.core
            self.driver.call(lambda now: swarm.peer_down(name, now))
