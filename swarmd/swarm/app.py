"""The swarm on top of discovery: readiness reports, commands and the PX4 bridge.

What the swarm is for: every member reports readiness to the commander, the commander
sends take-off, each drone's autopilot takes off. ``SwarmApp`` joins the pieces for one
daemon:

- discovery's ``PeerDiscovered``/``PeerRestarted``/``PeerLocatorsChanged``/``PeerLost`` ->
  the data plane's ``peer_up``/``peer_down`` (user unicast locator = the peer's address +
  ``Bundle.user_port``; the peer's boot epoch from its signed SPDP, to which the plane binds
  every datagram it sends it: docs/security.md);
- a member publishes ``swarm/ready`` every ``readiness_period_s`` (1 Hz, the paper's
  workload) and at once when its PX4 verdict changes, so a lost autopilot link reaches the
  commander within PX4's 2.5 s heartbeat timeout rather than up to a period later;
- a member executes each command id once (``CommandExecutor``), after persisting the id
  (``statefile``: write-ahead), and reports outcomes on ``swarm/outcome``;
- the commander keeps the ``ReadinessTable`` and the ``CommandTracker`` and answers the
  control socket's ``takeoff``/``command``/``outcomes``/``readiness`` requests. When the
  commander's drone has a PX4 link it flies with the swarm: it is a row of its own table and
  executes the commands that name it locally, through the same executor.

Roles come from the bundle, not from a flag: a node with a writer on ``swarm/command`` is a
commander, one with a writer on ``swarm/ready`` reports readiness.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from swarmd.auth.keys import NodeSecrets
from swarmd.bundle.model import Bundle, EndpointKind, Participant
from swarmd.config import DaemonConfig
from swarmd.control import RequestInvalid
from swarmd.dataplane import (
    TOPIC_COMMAND,
    TOPIC_READY,
    CommandReceived,
    DataPlane,
    DataPlaneEvent,
    OutcomeReceived,
    PacketDropped,
    PairKeys,
    ReadinessReceived,
)
from swarmd.dataplane.convert import ReadinessVerdict, readiness_sample
from swarmd.dataplane.types import MAX_ALTITUDE_M, CommandKind, CommandResult
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_OSERR, StartupError
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.provision import SigningKeyError, ed25519_seed, signing_key_for
from swarmd.px4.readiness import ReadinessConfig
from swarmd.swarm.commander import CommandTracker, ReadinessTable
from swarmd.swarm.executor import PX4_DISABLED, CommandExecutor
from swarmd.swarm.statefile import NodeState, StateDirError, boot
from swarmd.swarm.userdata import UserDataAdapter

MAX_TAKEOFF_ALT_M: Final = min(120.0, MAX_ALTITUDE_M)  # the bridge's own limit (docs/px4.md)
COMMAND_KINDS: Final = {k.name.lower(): k for k in CommandKind}


@dataclass(frozen=True, slots=True)
class _NoPx4:
    """The verdict of a node without a PX4 link: never ready, and says why."""

    ready: bool = False
    reason: str = PX4_DISABLED
    armed: bool | None = None
    landed_state: str | None = None
    gps_fix: int | None = None
    satellites: int | None = None
    battery_pct: int | None = None


def _writes(p: Participant, topic: str) -> bool:
    return any(e.topic == topic and e.kind == EndpointKind.WRITER for e in p.endpoints)


def _reads(p: Participant, topic: str) -> bool:
    return any(e.topic == topic and e.kind == EndpointKind.READER for e in p.endpoints)


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
    ) -> None:
        """``keys`` (the daemon's ``KeyRing``) and ``epoch`` (this boot's, the one its SPDP
        announces) authenticate the data plane's datagrams (docs/security.md)."""
        self.config = config
        self.bundle = bundle
        self.log = log
        self.link_q = link_q
        self.keys = keys
        self.epoch = epoch
        self.node_secrets = node_secrets  # the PX4 link's signing key derives from them
        self.me = config.member_of(bundle)
        self.is_commander = _writes(self.me, TOPIC_COMMAND)
        self.reports_readiness = _writes(self.me, TOPIC_READY)
        members = [
            p.name
            for p in bundle.participants
            if p.name != self.me.name and _writes(p, TOPIC_READY) and _reads(self.me, TOPIC_READY)
        ]
        self.targets_remote = [
            p.name
            for p in bundle.participants
            if p.name != self.me.name and _reads(p, TOPIC_COMMAND)
        ]
        self.table = ReadinessTable(members, stale_after_s=config.dataplane.stale_after_s)
        self.tracker = CommandTracker()
        self.bridge: Px4Bridge | None = None
        self.state: NodeState | None = None
        self.adapter: UserDataAdapter | None = None
        self.executor: CommandExecutor | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tick: asyncio.TimerHandle | None = None
        self._seq = 0
        self._local_commands: set[int] = set()
        self._last_verdict: tuple[bool, str | None] | None = None
        # discovered peers -> (address, boot epoch), replayed on start
        self._up: dict[str, tuple[str | None, int]] = {}
        self.counters: dict[str, int] = {"readiness_published": 0, "state_save_errors": 0}

    # ---- life -----------------------------------------------------------------------------

    async def start(self) -> None:
        """PX4 link, state directory, data plane socket; ``StartupError`` on failure."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        px4 = self.config.px4
        if px4.enabled:
            sysid = px4.sysid if px4.sysid is not None else self.me.mavlink_sysid
            signing_key: bytes | None = None
            if px4.signing:  # the per-drone MAVLink key (docs/px4.md, "Message signing")
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
                    )
                except SigningKeyError as exc:
                    raise StartupError(str(exc), EX_CONFIG) from None
            try:
                self.bridge = Px4Bridge.from_config(
                    Px4Config(
                        connection=px4.connection,
                        sysid=sysid,
                        autopilot=px4.autopilot,
                        signing_key=signing_key,
                        backend=px4.backend,
                        xrce_key=px4.xrce_key,
                        namespace=px4.namespace,
                        readiness=ReadinessConfig(
                            heartbeat_timeout_s=px4.heartbeat_timeout_s,
                            min_battery_pct=px4.min_battery_pct,
                            require_home=px4.require_home,
                            allow_unknown_battery=px4.allow_unknown_battery,
                        ),
                    ),
                    log=self.log,
                )
                await self.bridge.start()
            except (OSError, ValueError) as exc:
                self.bridge = None
                reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                raise StartupError(f"px4.connection {px4.connection}: {reason}", EX_OSERR) from None
        if self.config.dataplane.enabled:
            try:
                await self._start_dataplane()
            except BaseException:
                await self.stop()
                raise
        self.executor = CommandExecutor(self.bridge, self._report, log=self.log)
        if self.is_commander and self.bridge is not None:
            self.table.add_local(self.me.name)
        if self.bridge is not None:
            self.bridge.on_readiness_change(self._on_px4_change)
        self._schedule_tick(0.0)

    async def _start_dataplane(self) -> None:
        try:
            self.state = boot(self.config.dataplane.state_dir, self.me.name)
        except StateDirError as exc:
            raise StartupError(f"dataplane.state_dir: {exc}", EX_CANTCREAT) from None
        if self.state.recovered_from:
            self.log.warning(
                "state_file_replaced", path=str(self.state.path), why=self.state.recovered_from
            )
        try:
            plane = DataPlane(
                self.bundle,
                self.me.name,
                keys=self.keys,
                epoch=self.epoch,
                incarnation=self.state.boot,
                executed_command_ids=self.state.executed,
            )
        except ValueError as exc:
            raise StartupError(f"bundle rejected by the data plane: {exc}", EX_CONFIG) from None
        self.adapter = UserDataAdapter(plane, self._on_event, log=self.log)
        port = self.bundle.user_port(self.me)
        try:
            await self.adapter.open(port)
        except OSError as exc:
            self.adapter = None
            raise StartupError(
                f"cannot bind user-data port {port}: {exc.strerror} "
                "(is another participant with the same bundle index running?)",
                EX_OSERR,
            ) from None
        for name, (address, epoch) in list(self._up.items()):
            self.peer_up(name, address, epoch)
        self.log.info(
            "dataplane_started",
            user_port=port,
            incarnation=self.state.boot,
            executed_restored=len(self.state.executed),
            commander=self.is_commander,
            reports_readiness=self.reports_readiness,
        )

    async def stop(self) -> None:
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        if self.executor is not None:
            await self.executor.close()
        if self.adapter is not None:
            self.adapter.close()
        if self.bridge is not None:
            await self.bridge.close()

    # ---- discovery input ------------------------------------------------------------------

    def peer_up(self, name: str, ipv4: str | None, epoch: int) -> None:
        """Discovery heard ``name`` at ``ipv4`` in boot ``epoch`` (its authenticated SPDP);
        again with a higher epoch when it restarted, or another address when it moved."""
        self._up[name] = (ipv4, epoch)
        self.table.on_peer(name, True)
        if self.adapter is None:
            return
        peer = self.bundle.participant(name)
        address = ipv4 or peer.ipv4
        if address is None:
            self.log.warning("peer_without_address", peer=name)
            return
        self.adapter.peer_up(name, (address, self.bundle.user_port(peer)), epoch)

    def peer_moved(self, name: str, ipv4: str | None) -> None:
        """Discovery heard ``name`` announce another address (authenticated SPDP)."""
        known = self._up.get(name)
        if known is not None:
            self.peer_up(name, ipv4, known[1])

    def peer_down(self, name: str) -> None:
        self._up.pop(name, None)
        self.table.on_peer(name, False)
        if self.adapter is not None:
            self.adapter.peer_down(name)

    # ---- readiness ------------------------------------------------------------------------

    def verdict(self) -> ReadinessVerdict:
        return self.bridge.readiness() if self.bridge is not None else _NoPx4()

    def _on_px4_change(self, verdict: ReadinessVerdict) -> None:
        key = (bool(verdict.ready), None if verdict.reason is None else str(verdict.reason))
        if self._last_verdict is not None and key != self._last_verdict:
            self._schedule_tick(0.0)  # tell the commander now, not up to a period later
        self._last_verdict = key

    def _schedule_tick(self, delay: float) -> None:
        if self._loop is None:
            return
        if self._tick is not None:
            self._tick.cancel()
        self._tick = self._loop.call_later(delay, self._on_tick)

    def _on_tick(self) -> None:
        self._tick = None
        if self._loop is None:
            return
        if self.reports_readiness or self.table.names:
            self._seq += 1
            sample = readiness_sample(self.me.name, self._seq, self.verdict(), self.link_q())
            if self.reports_readiness and self.adapter is not None:
                self.adapter.publish_readiness(sample)
                self.counters["readiness_published"] += 1
            if self.me.name in self.table.names:
                self.table.on_report(self.me.name, sample, None, self._loop.time())
        self._schedule_tick(self.config.dataplane.readiness_period_s)

    # ---- data plane events ----------------------------------------------------------------

    def _on_event(self, event: DataPlaneEvent) -> None:
        now = self._loop.time() if self._loop is not None else 0.0
        match event:
            case ReadinessReceived(node=node, sample=sample, count=count):
                before = self.table.verdict(node, now)
                self.table.on_report(node, sample, count, now)
                after = self.table.verdict(node, now)
                if before != after:
                    self.log.info("member_readiness", member=node, ready=after[0], reason=after[1])
            case CommandReceived(commander=commander, command=command):
                self._persist_executed()  # write-ahead: a crash loses the command, never repeats it
                if self.executor is not None:
                    self.executor.execute(commander, command)
            case OutcomeReceived(node=node, outcome=outcome):
                known = self.tracker.record(
                    outcome.command_id, node, outcome.result, outcome.reason, now
                )
                self.log.info(
                    "command_outcome_received",
                    member=node,
                    command_id=outcome.command_id,
                    result=outcome.result.name,
                    reason=outcome.reason,
                    known=known,
                )
            case PacketDropped(reason=reason, source=source, detail=detail):
                self.log.debug("userdata_dropped", reason=reason, source=str(source), detail=detail)

    def _persist_executed(self) -> None:
        if self.state is None or self.adapter is None:
            return
        self.state.executed = self.adapter.plane.executed_command_ids
        try:
            self.state.save()
        except StateDirError as exc:
            self.counters["state_save_errors"] += 1
            self.log.error("state_save_failed", error=str(exc))

    def _report(self, command_id: int, result: CommandResult, reason: str) -> None:
        if command_id in self._local_commands:
            now = self._loop.time() if self._loop is not None else 0.0
            self.tracker.record(command_id, self.me.name, result, reason, now)
        elif self.adapter is not None:
            self.adapter.report_outcome(command_id, result, reason)

    # ---- commander requests (control socket) ----------------------------------------------

    def _require_commander(self) -> UserDataAdapter:
        if not self.is_commander:
            raise RequestInvalid(
                f"{self.me.name} is not a commander in swarm {self.bundle.swarm!r}; "
                "run swarmctl on the commander's drone"
            )
        if self.adapter is None:
            raise RequestInvalid("the data plane is disabled (dataplane.enabled: false)")
        return self.adapter

    def _targets(self, only: object) -> list[str]:
        known = self.table.names if self.table.names else self.targets_remote
        everyone = list(dict.fromkeys([*known, *self.targets_remote]))
        if self.bridge is not None and self.me.name not in everyone:
            everyone.insert(0, self.me.name)
        if only is None or only == []:
            return everyone
        if not isinstance(only, list) or not all(isinstance(n, str) for n in only):
            raise RequestInvalid('"only" must be a list of node names')
        unknown = [n for n in only if n not in everyone]
        if unknown:
            raise RequestInvalid(
                f"not a commandable node: {', '.join(unknown)}; known: {', '.join(everyone)}"
            )
        return list(dict.fromkeys(only))

    def _altitude(self, request: Mapping[str, Any]) -> float:
        alt = request.get("alt_m")
        if alt is None:
            return self.config.px4.takeoff_alt_m
        if isinstance(alt, bool) or not isinstance(alt, int | float) or not math.isfinite(alt):
            raise RequestInvalid(f"alt_m {alt!r} is not a number")
        if not 0 < alt <= MAX_TAKEOFF_ALT_M:
            raise RequestInvalid(f"alt_m {alt} is outside (0, {MAX_TAKEOFF_ALT_M:g}] m")
        return float(alt)

    def request_takeoff(self, request: Mapping[str, Any]) -> dict[str, Any]:
        """Take-off of the targeted nodes that are ready now; ``require_all``: all or none."""
        self._require_commander()
        alt = self._altitude(request)
        targets = self._targets(request.get("only"))
        now = self._loop.time() if self._loop is not None else 0.0
        ready, refused = self.table.split(targets, now)
        if refused and request.get("require_all"):
            return {"sent": False, "command_id": None, "ready": ready, "refused": refused}
        if not ready:
            return {"sent": False, "command_id": None, "ready": [], "refused": refused}
        command_id = self._send(CommandKind.TAKEOFF, ready, alt, refused)
        return {"sent": True, "command_id": command_id, "ready": ready, "refused": refused}

    def request_command(self, request: Mapping[str, Any]) -> dict[str, Any]:
        """Any command to the targets as they are: members judge for themselves."""
        self._require_commander()
        kind = COMMAND_KINDS.get(str(request.get("kind", "")).lower())
        if kind is None:
            raise RequestInvalid(f"kind must be one of: {', '.join(COMMAND_KINDS)}")
        alt = self._altitude(request) if kind == CommandKind.TAKEOFF else 0.0
        targets = self._targets(request.get("only"))
        command_id = self._send(kind, targets, alt, {})
        return {"sent": True, "command_id": command_id, "ready": targets, "refused": {}}

    def request_outcomes(self, request: Mapping[str, Any]) -> dict[str, Any]:
        command_id = request.get("command_id")
        if not isinstance(command_id, int) or isinstance(command_id, bool):
            raise RequestInvalid('"command_id" must be an integer')
        now = self._loop.time() if self._loop is not None else 0.0
        snap = self.tracker.snapshot(command_id, now)
        if snap is None:
            raise RequestInvalid(f"unknown command id {command_id}")
        return snap

    def _send(
        self, kind: CommandKind, targets: Sequence[str], alt: float, refused: dict[str, str]
    ) -> int:
        adapter = self._require_commander()
        now = self._loop.time() if self._loop is not None else 0.0
        remote = [n for n in targets if n != self.me.name]
        command = adapter.plane.make_command(kind, altitude_m=alt, targets=remote)
        self.tracker.sent(
            command.command_id,
            kind.name.lower(),
            targets,
            now,
            altitude_m=alt if kind == CommandKind.TAKEOFF else None,
            refused=refused,
        )
        self.log.info(
            "command_sent",
            command_id=command.command_id,
            kind=kind.name,
            altitude_m=alt if kind == CommandKind.TAKEOFF else None,
            targets=list(targets),
            refused=refused,
        )
        if remote:  # an empty target list would mean "every member" on the wire
            adapter.send_command(command)
        if self.me.name in targets and self.executor is not None:
            self._local_commands.add(command.command_id)
            self.executor.execute(self.me.name, command)
        return command.command_id

    # ---- status ---------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The fragment merged into ``swarmctl status --json`` (docs/operations.md)."""
        now = self._loop.time() if self._loop is not None else 0.0
        dataplane: dict[str, Any] = {"enabled": self.adapter is not None}
        if self.adapter is not None:
            dataplane.update(self.adapter.status())
            dataplane["readiness_published"] = self.counters["readiness_published"]
            dataplane["state_save_errors"] = self.counters["state_save_errors"]
        px4: dict[str, Any] = {"enabled": self.bridge is not None}
        if self.bridge is not None:
            px4.update(self.bridge.status())
        return {
            "role": "commander" if self.is_commander else "member",
            "clock_s": round(now, 3),
            "readiness": self.table.rows(now),
            "px4": px4,
            "dataplane": dataplane,
            "commands": self.tracker.recent(now) if self.is_commander else [],
            "executor": None if self.executor is None else self.executor.status(),
        }
