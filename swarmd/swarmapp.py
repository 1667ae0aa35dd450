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
"""

from __future__ import annotations

import asyncio
import os
import socket
import time
from collections import deque
from collections.abc import Callable, Mapping
from functools import partial
from pathlib import Path
from typing import Any, Final, assert_never

from swarmd.auth.keys import NodeSecrets
from swarmd.bundle.model import Bundle
from swarmd.bundle.statedir import DaemonUser
from swarmd.config import DaemonConfig
from swarmd.control import STOPPING, PeerCredentials, RequestInvalid
from swarmd.dataplane import DataPlane, PairKeys
from swarmd.dataplane.convert import ReadinessVerdict
from swarmd.driver import Driver
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_OSERR, StartupError
from swarmd.filewriter import FileWriter
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.provision import SigningKeyError, ed25519_seed, signing_key_for
from swarmd.px4.readiness import Readiness, ReadinessConfig
from swarmd.px4.transport import (
    PX4_SOCKET,
    XRCE_SOCKET,
    parse_connection,
    unprivileged_port_start,
)
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished, VehicleRequest
from swarmd.px4.xrce_key import XrceKey, XrceKeyError
from swarmd.px4.xrce_key import check as check_xrce_key
from swarmd.px4.xrce_key import load_or_create as load_or_create_xrce_key
from swarmd.statefile import NodeState, StateDirError, boot, preview
from swarmd.swarm import issuer
from swarmd.swarm.commander import RESTARTED_RUNNING, CommandTracker, KeptDecision, ReadinessTable
from swarmd.swarm.core import SwarmCore, SwarmSettings
from swarmd.swarm.events import (
    CommandBeforeLife,
    CommandExecuting,
    CommandExpired,
    CommandIssued,
    CommandLifeEnded,
    CommandNotDelivered,
    CommandWithdrawn,
    MemberReadinessChanged,
    OutcomeRecorded,
    OutcomeReported,
    OutcomesReReported,
    PeerTrafficVerified,
    PersistExecuted,
    SentBy,
    SwarmEvent,
    UserDataDropped,
)
from swarmd.swarm.member import NO_VEHICLE
from swarmd.swarm.roles import Roles
from swarmd.userdata import UserDataSocket

Datagram = tuple[bytes, tuple[str, int]]
# command_requested logs the request's kind and targets as the client wrote them; a valid
# one has a short kind and at most a swarm's names, so these only bound a hostile line
MAX_LOGGED_ARG_CHARS: Final = 64
MAX_LOGGED_TARGETS: Final = 64


class SwarmApp:
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
        self.config = config
        self.bundle = bundle
        self.log = log
        self.link_q = link_q
        self.keys = keys
        self.epoch = epoch
        self.node_secrets = node_secrets  # the PX4 link's signing key derives from them
        # the link's port as systemd bound it: swarmd-px4.socket (MAVLink udpin:) or
        # swarmd-xrce.socket (the XRCE agent's udp:), docs/px4.md
        self.px4_socket = px4_socket
        self.booted_before = booted_before
        self.me = config.member_of(bundle)
        self.roles = Roles.of(bundle, self.me)
        self.bridge: Px4Bridge | None = None
        self.state: NodeState | None = None
        self.plane: DataPlane | None = None
        self.socket: UserDataSocket | None = None
        self.core: SwarmCore | None = None
        self.driver: Driver[bytes, Datagram, SwarmEvent] | None = None
        # discovered peers -> (address, boot epoch), replayed on start
        self._up: dict[str, tuple[str | None, int]] = {}
        self.counters: dict[str, int] = {"state_save_errors": 0, "state_file_missing": 0}
        self.writer = writer if writer is not None else FileWriter()
        # the write-ahead across threads: state writes asked for and answered so far, and
        # the vehicle requests waiting, each with the writes that must end before it goes
        self._saves_asked = 0
        self._saves_answered = 0
        self._held: deque[tuple[int, VehicleRequest]] = deque()
        self._stopping = False  # stop() began: a held request no longer goes to the vehicle
        # verified user data from a peer, by name: the daemon feeds it to discovery
        self.on_peer_traffic: Callable[[str], None] | None = None

    @property
    def is_commander(self) -> bool:
        return self.roles.is_commander

    @property
    def reports_readiness(self) -> bool:
        return self.roles.reports_readiness

    @property
    def targets_remote(self) -> list[str]:
        return list(self.roles.targets_remote)

    @property
    def table(self) -> ReadinessTable:
        return self._core().table

    @property
    def tracker(self) -> CommandTracker:
        return self._core().tracker

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
                earlier_decisions=[_on_clock(d, -offset) for d in earlier],
                told_unsaved=() if self.state is None else self.state.told_unsaved,
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
                notes.append(f"{state.path}: {_dropped_text(state)}; run drops them too")
            self._make_plane(state)
        return notes

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

    def _state(self, read: Callable[[str, str], NodeState]) -> NodeState:
        """The state file by ``read`` (``boot``, or ``preview`` for a check), its refusal as
        ``start``'s one line (exit 73)."""
        try:
            return read(self.config.dataplane.state_dir, self.me.name)
        except StateDirError as exc:
            raise StartupError(f"dataplane.state_dir: {exc}", EX_CANTCREAT) from None

    def _make_plane(self, state: NodeState) -> DataPlane:
        """The data plane on ``state``; its refusal of the bundle as one line (exit 78)."""
        try:
            return DataPlane(
                self.bundle,
                self.me.name,
                keys=self.keys,
                epoch=self.epoch,
                incarnation=state.boot,
                executed_command_ids=state.executed,
                executed_outcomes=state.outcomes,
            )
        except ValueError as exc:
            raise StartupError(f"bundle rejected by the data plane: {exc}", EX_CONFIG) from None

    def _boot_dataplane(self) -> None:
        self.state = self._state(boot)
        if self.state.recovered_from:
            self.log.warning(
                "state_file_replaced", path=str(self.state.path), why=self.state.recovered_from
            )
        if self.state.missing and self.booted_before:
            # the record of the commands an earlier life ran is gone: exactly once now rests
            # on refusing them (docs/operations.md, "memory_lost"); a true first boot is silent
            self.counters["state_file_missing"] += 1
            self.log.warning(
                "state_file_missing",
                path=str(self.state.path),
                why="this node booted before (its boot epoch file held one) but its state "
                "file is gone: commands of an earlier life are refused memory_lost",
            )
        if self.state.decisions_dropped:  # times that cannot be right (statefile.load)
            self.log.warning(
                "state_decisions_dropped",
                path=str(self.state.path),
                dropped=self.state.decisions_dropped,
                ids_kept=self.state.decision_ids_kept,
                why=_dropped_text(self.state),
            )
        if self.state.temps_removed:  # a crash mid-write (statefile.boot)
            self.log.warning(
                "state_temp_files_removed",
                path=str(self.state.path),
                count=self.state.temps_removed,
            )
        self.plane = self._make_plane(self.state)

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

    # ---- the core's events ----------------------------------------------------------------

    def _transmit(self, datagram: Datagram) -> None:
        if self.socket is None:
            self.counters["tx_closed"] = self.counters.get("tx_closed", 0) + 1
            return
        self.socket.send(*datagram)

    def _on_event(self, event: SwarmEvent) -> None:
        match event:
            case PersistExecuted():
                self._persist(event)
            case VehicleRequest():
                self._vehicle_request(event)
            case MemberReadinessChanged(member=member, ready=ready, reason=reason):
                self.log.info("member_readiness", member=member, ready=ready, reason=reason)
            case CommandIssued():
                self.log.info(
                    "command_sent",
                    command_id=event.command_id,
                    kind=event.kind.name,
                    altitude_m=event.altitude_m,
                    targets=list(event.targets),
                    refused=dict(event.refused),
                    sent_by=None if event.sent_by is None else event.sent_by.as_json(),
                )
            case CommandExecuting():
                self.log.info(
                    "command_received",
                    commander=event.commander,
                    command_id=event.command_id,
                    kind=event.kind.name,
                    altitude_m=event.altitude_m,
                )
            case CommandExpired() | CommandBeforeLife():
                # a member's refusal of a command it may not run (docs/operations.md,
                # "Validity" and "memory_lost": either way a new command runs it now)
                self.log.warning(
                    "command_expired"
                    if isinstance(event, CommandExpired)
                    else "command_refused_memory_lost",
                    commander=event.commander,
                    command_id=event.command_id,
                    kind=event.kind.name,
                    detail=event.detail,
                )
            case CommandWithdrawn():
                self.log.info("command_withdrawn", command_id=event.command_id)
            case CommandNotDelivered():
                self.log.warning(
                    "command_not_delivered",
                    member=event.member,
                    command_id=event.command_id,
                    reason=event.reason,
                )
            case CommandLifeEnded():
                self.log.warning(
                    "command_member_restarted",
                    member=event.member,
                    command_id=event.command_id,
                    reason=RESTARTED_RUNNING,
                )
            case OutcomeReported():
                self.log.info(
                    "command_outcome",
                    command_id=event.command_id,
                    kind=event.kind,
                    result=event.result.name,
                    reason=event.reason,
                    saved=event.saved,
                )
            case OutcomesReReported():
                self.log.info(
                    "command_outcomes_rereported",
                    commander=event.commander,
                    command_ids=list(event.command_ids),
                )
            case OutcomeRecorded():
                self.log.info(
                    "command_outcome_received",
                    member=event.member,
                    command_id=event.command_id,
                    result=event.result.name,
                    reason=event.reason,
                    known=event.known,
                    saved=event.saved,
                )
            case PeerTrafficVerified(node=node):
                if self.on_peer_traffic is not None:
                    self.on_peer_traffic(node)
            case UserDataDropped(reason=reason, source=source, detail=detail):
                self.log.debug("userdata_dropped", reason=reason, source=str(source), detail=detail)
            case _:
                assert_never(event)

    def _persist(self, event: PersistExecuted) -> None:
        """Write the state file, on the writer's thread (``swarmd.filewriter``): encoded
        now, so the write holds this event's state (or a newer one's, which holds it too).
        Each event is answered (``_saved``) once the write that holds it has ended."""
        if self.state is None:
            return
        self.state.executed = list(event.executed)
        self.state.outcomes = list(event.outcomes)
        offset = self._wall_offset()
        self.state.decisions = [_on_clock(d, offset) for d in event.decisions]
        self.state.told_unsaved = list(event.told_unsaved)
        self._saves_asked += 1
        write = partial(self.state.write, self.state.encode())
        self.writer.submit("state", write, partial(self._saved, event.command))

    def _saved(self, command: tuple[str, int] | None, error: Exception | None) -> None:
        """On the loop: a write of the state file ended. A failed write is told (logged
        ``state_save_failed`` with the command it would have kept, counted, the decision
        marked unsaved for ``swarmctl outcomes``, its commander told ``[not saved on
        drone]``) and does not stop the command: docs/dataplane.md, "A failed save". Then
        the vehicle requests it held go (``_vehicle_request``)."""
        why: str | None = None
        if error is not None:
            why = str(error)
            self.counters["state_save_errors"] += 1
            commander, command_id = command or (None, None)
            self.log.error(
                "state_save_failed",
                error=why,
                commander=commander,
                command_id=command_id,
                effect="the command still runs; after a restart its answer is not re-reported "
                "and no copy of it runs again (docs/dataplane.md, 'A failed save')",
            )
        self._saves_answered += 1
        if self.driver is not None and self.core is not None:
            swarm = self.core
            self.driver.call(lambda now: swarm.state_saved(command, why, now))
        while not self._stopping and self._held and self._held[0][0] <= self._saves_answered:
            self._submit(self._held.popleft()[1])

    def _vehicle_request(self, request: VehicleRequest) -> None:
        """To the bridge once every state write asked for before it has ended: the
        write-ahead (``PersistExecuted`` before ``VehicleRequest``, docs/dataplane.md,
        "Exactly once") now that writes run on another thread; in order, behind any
        request still waiting. A wait past the command's validity is the vehicle core's to
        judge when the request reaches it (``not_after``: docs/dataplane.md, "Validity at
        the vehicle")."""
        if self._held or self._saves_answered < self._saves_asked:
            self._held.append((self._saves_asked, request))
            return
        self._submit(request)

    def _submit(self, request: VehicleRequest) -> None:
        if self.bridge is not None:
            self.bridge.submit(request)

    def _wall_offset(self) -> float:
        """Unix time minus the core's clock (``loop.time()``, CLOCK_MONOTONIC_RAW): the
        state file dates decisions on the wall clock, the only one two lives share."""
        return time.time() - self._driver().now()

    # ---- commander requests (control socket) ----------------------------------------------

    # The state-changing requests (ControlServer's sender handlers): each is logged as
    # ``command_requested`` with who sent it, whatever became of it (docs/operations.md)

    def request_takeoff(
        self, request: Mapping[str, Any], peer: PeerCredentials | None = None
    ) -> dict[str, Any]:
        """Take-off of the targeted nodes that are ready now; ``require_all``: all or none."""
        return self._sent_request("takeoff", self._core().request_takeoff, request, peer)

    def request_command(
        self, request: Mapping[str, Any], peer: PeerCredentials | None = None
    ) -> dict[str, Any]:
        """Any command to the targets as they are: members judge for themselves."""
        return self._sent_request("command", self._core().request_command, request, peer)

    def _sent_request(
        self,
        cmd: str,
        handler: Callable[..., dict[str, Any]],
        request: Mapping[str, Any],
        peer: PeerCredentials | None,
    ) -> dict[str, Any]:
        sent_by = None if peer is None else SentBy(peer.uid, peer.user, peer.pid)
        who = {} if peer is None else peer.log_fields()
        # the request's own words, as data (a client chooses them), cut to what a valid
        # request holds so one log line stays a line's worth
        only = request.get("only")
        asked = {
            "kind": str(request.get("kind", cmd))[:MAX_LOGGED_ARG_CHARS],
            "only": [str(n)[:MAX_LOGGED_ARG_CHARS] for n in only[:MAX_LOGGED_TARGETS]]
            if isinstance(only, list)
            else None,
        }
        try:
            answer = self._request(lambda r, now: handler(r, now, sent_by=sent_by), request)
        except RequestInvalid as exc:
            self.log.info("command_requested", cmd=cmd, **asked, **who, sent=False, error=str(exc))
            raise
        self.log.info(
            "command_requested",
            cmd=cmd,
            **asked,
            **who,
            sent=bool(answer.get("sent")),
            command_id=answer.get("command_id"),
        )
        return answer

    def request_outcomes(self, request: Mapping[str, Any]) -> dict[str, Any]:
        return self._request(self._core().request_outcomes, request)

    def _request(
        self,
        handler: Callable[[Mapping[str, Any], float], dict[str, Any]],
        request: Mapping[str, Any],
    ) -> dict[str, Any]:
        try:
            answer = self._driver().call(lambda now: handler(request, now))
        except issuer.RequestInvalid as exc:
            raise RequestInvalid(str(exc)) from None
        if answer is None:  # the driver closed: the swarm core no longer runs
            # nothing ran (Driver.call): its code tells swarmctl "nothing sent", exit 2,
            # where a bare refusal read as a usage error, 64 (session 16)
            raise RequestInvalid("the daemon is stopping", code=STOPPING)
        return answer

    # ---- status ---------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The fragment merged into ``swarmctl status --json`` (docs/operations.md): a pure
        function of the cores' state, evaluated when asked."""
        swarm, driver = self._core(), self._driver()
        now = driver.now()
        dataplane: dict[str, Any] = {"enabled": self.plane is not None}
        if self.plane is not None:
            dataplane.update(self.plane.status(now))
            sock = {} if self.socket is None else self.socket.counters
            dataplane["adapter"] = {
                "socket_errors": sock.get("socket_error_user", 0),
                "tx_dropped_full": sock.get("tx_dropped_full_user", 0),
                "handler_errors": driver.counters["handler_errors"],
                "tx_closed": self.counters.get("tx_closed", 0),
            }
            dataplane["readiness_published"] = swarm.counters["readiness_published"]
            # what this life re-reported of its earlier lives' outcomes (docs/dataplane.md)
            dataplane["outcomes_rereported"] = swarm.counters["outcomes_rereported"]
            dataplane["state_save_errors"] = self.counters["state_save_errors"]
            dataplane["state_file_missing"] = self.counters["state_file_missing"]
        px4: dict[str, Any] = {"enabled": self.bridge is not None}
        if self.bridge is not None:
            px4.update(self.bridge.status())
        return {
            "role": self.roles.role,
            "clock_s": round(now, 3),
            "readiness": swarm.table.rows(now),
            "px4": px4,
            "dataplane": dataplane,
            "commands": swarm.tracker.recent(now) if self.is_commander else [],
            "executor": swarm.executor_status(now),
        }

    def _core(self) -> SwarmCore:
        if self.core is None:
            raise RuntimeError("the swarm layer is not started")
        return self.core

    def _driver(self) -> Driver[bytes, Datagram, SwarmEvent]:
        if self.driver is None:
            raise RuntimeError("the swarm layer is not started")
        return self.driver


def _on_clock(kept: KeptDecision, offset: float) -> KeptDecision:
    """``kept`` with ``received_at`` moved by ``offset``: from the core's clock to Unix time
    (``offset`` = Unix time - loop time) or back (its negative)."""
    return kept._replace(received_at=kept.received_at + offset)


def _dropped_text(state: NodeState) -> str:
    """The one line about the kept decisions ``statefile.load`` dropped for their time."""
    return (
        f"{state.decisions_dropped} earlier decision(s) dropped from swarmctl outcomes' view "
        f"({state.decisions_problem}); their ids stay executed, {state.decision_ids_kept} of "
        "them added there, so none of those commands runs again"
    )
