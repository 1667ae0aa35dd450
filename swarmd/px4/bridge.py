"""``Px4Bridge``: one vehicle's backend joined to its sans-IO ``VehicleCore`` by the driver.

The backend (MAVLink, or any ``VehicleBackend``) hands each decoded observation to the
``swarmd.driver.Driver``, which feeds the ``VehicleCore`` (state, readiness, take-off,
LAND/HOLD/ABORT, all commands through the ``CommandSender``) at ``loop.time()``, sends what
it queued through ``backend.send`` and re-arms its one timer. The bridge only turns the
core's events into log lines, readiness listeners and the futures of ``takeoff()``.

API for the daemon / commander::

    bridge = Px4Bridge.from_config(Px4Config(connection="udpin:127.0.0.1:14540", sysid=1))
    await bridge.start()
    bridge.on_readiness_change(lambda r: publish(r.as_dict()))
    bridge.on_task_finished(lambda done: report(done.token, done.ok, done.reason))
    verdict = bridge.readiness()               # Readiness(ready, reason, detail, ...)
    outcome = await bridge.takeoff(alt_m=10.0)  # TakeoffSucceeded | TakeoffFailed
    bridge.submit(VehicleRequest(token, TaskKind.LAND))  # HOLD, ABORT, TAKEOFF (alt_m)
    await bridge.close()
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, assert_never

from swarmd.driver import Driver
from swarmd.px4.actions import ActionFinished
from swarmd.px4.backend import VehicleBackend
from swarmd.px4.command_sender import AckReceived, CommandSent
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.messages import Observation, StateReset, VehicleCommand
from swarmd.px4.readiness import Readiness, ReadinessConfig, VehicleState
from swarmd.px4.takeoff import (
    DISARM_UNCONFIRMED,
    DisarmRepeatsEnded,
    TakeoffConfig,
    TakeoffFailed,
    TakeoffPhaseChanged,
    TakeoffSucceeded,
)
from swarmd.px4.vehicle import (
    DisarmUnconfirmed,
    ReadinessChanged,
    TaskFinished,
    TaskKind,
    VehicleCore,
    VehicleEvent,
    VehicleRequest,
)

Outcome = TakeoffSucceeded | TakeoffFailed
ReadinessListener = Callable[[Readiness], None]
# a task's end, and the amendment a failed take-off's unconfirmed DISARM adds to it
TaskListener = Callable[[TaskFinished | DisarmUnconfirmed], None]


@dataclass(frozen=True, slots=True)
class Px4Config:
    """The daemon config's ``px4`` section."""

    connection: str = "udpin:127.0.0.1:14540"  # PX4 SITL / mavlink-router, loopback only
    sysid: int = 1  # the vehicle's MAV_SYS_ID; we are component 191 of it
    autopilot: str | None = None  # "IP:PORT" to pin; None: the first heartbeat's source
    signing_key: bytes | None = None  # MAVLink 2 signing (32 bytes); None: off
    backend: str = "mavlink"  # | "xrce-agent" | "xrce-client" (docs/px4.md)
    # xrce-agent: the vehicle's UXRCE_DDS_KEY, binding the agent to it (None: unbound, lab only;
    # the daemon always resolves one, swarmd.px4.xrce_key)
    xrce_key: int | None = None
    namespace: str | None = None  # PX4 UXRCE_DDS_NS
    xrce_domain_id: int = 0  # xrce-client: its participant's DDS domain (UXRCE_DDS_DOM_ID)
    # xrce-agent: the uid PX4 SITL runs as on loopback (px4.loopback_user); None: any local user
    loopback_user: int | None = None
    readiness: ReadinessConfig = field(default_factory=ReadinessConfig)
    takeoff: TakeoffConfig = field(default_factory=TakeoffConfig)
    # the socket systemd bound for a MAVLink udpin: (swarmd-px4.socket) or the XRCE agent's
    # udp: (swarmd-xrce.socket), docs/px4.md; None: bind it ourselves
    listen_socket: socket.socket | None = field(default=None, compare=False)


class Px4Bridge:
    """One vehicle: live ``VehicleState``, readiness on demand and on change, its tasks."""

    def __init__(
        self,
        backend: VehicleBackend,
        *,
        readiness_config: ReadinessConfig | None = None,
        takeoff_config: TakeoffConfig | None = None,
        log: Any = None,
    ) -> None:
        self.backend = backend
        self.core = VehicleCore(readiness_config=readiness_config, takeoff_config=takeoff_config)
        self._log = log
        self._driver: Driver[Observation, VehicleCommand, VehicleEvent] | None = None
        self._listeners: list[ReadinessListener] = []
        self._task_listeners: list[TaskListener] = []
        self._waiting: dict[int, asyncio.Future[TaskFinished]] = {}
        self._own_token = 0  # takeoff() callers get negative tokens: never a command id
        self.last_outcome: Outcome | None = None

    @classmethod
    def from_config(cls, config: Px4Config, *, log: Any = None) -> Px4Bridge:
        """A bridge on the configured backend; raises ValueError (one line) on a bad config."""
        backend: VehicleBackend
        if config.backend in ("xrce-agent", "xrce-client"):
            from swarmd.px4.xrce_backend import XrceBackend  # only XRCE configs pay for it

            backend = XrceBackend(
                config.backend,  # type: ignore[arg-type]
                config.connection,
                sysid=config.sysid,
                expected_key=config.xrce_key,
                namespace=config.namespace,
                domain_id=config.xrce_domain_id,
                loopback_user=config.loopback_user,
                log=log,
                inherited=config.listen_socket,
                command_life_s=config.takeoff.command.ack_timeout_s,
            )
        else:
            backend = MavlinkBackend(
                config.connection,
                sysid=config.sysid,
                autopilot=config.autopilot,
                signing_key=config.signing_key,
                inherited=config.listen_socket,
            )
        return cls(
            backend, readiness_config=config.readiness, takeoff_config=config.takeoff, log=log
        )

    # ---- life -----------------------------------------------------------------------------

    async def start(self) -> None:
        self._driver = Driver(
            self.core,
            transmit=self.backend.send,
            on_event=self._on_event,
            name="px4",
            log=self._log,
        )
        await self.backend.start(self._observe)
        self._info("px4_bridge_started", **self.backend.stats())
        self._driver.call(self.core.handle_timer)  # the first verdict, and its stale timer

    async def close(self) -> None:
        if self._driver is not None:
            self._driver.call(lambda now: self.core.cancel_all(now, "bridge closing"))
            self._driver.close()
        await self.backend.close()

    @property
    def state(self) -> VehicleState:
        return self.core.state

    # ---- readiness ------------------------------------------------------------------------

    def readiness(self) -> Readiness:
        """The verdict now (``loop.time()``)."""
        return self.core.readiness(self._drive().now())

    def on_readiness_change(self, listener: ReadinessListener) -> None:
        """Call ``listener`` whenever ready/reason changes (and once at once)."""
        self._listeners.append(listener)
        listener(self.readiness())

    # ---- tasks ----------------------------------------------------------------------------

    def on_task_finished(self, listener: TaskListener) -> None:
        """Call ``listener`` with each ``TaskFinished`` of a ``submit``ted request, and with
        the ``DisarmUnconfirmed`` that may follow a failed take-off's (the operator is told:
        docs/px4.md, "A failed take-off's DISARM")."""
        self._task_listeners.append(listener)

    def submit(self, request: VehicleRequest) -> None:
        """Start a take-off, LAND, HOLD or ABORT; its end comes to ``on_task_finished``."""
        self._drive().call(lambda now: self.core.request(request, now))

    async def takeoff(self, alt_m: float | None = None) -> Outcome:
        """Arm and take off to ``alt_m`` above home (None: PX4's MIS_TAKEOFF_ALT).

        Refused at once, with the readiness reason, when the vehicle is not ready. Only one
        take-off runs at a time; a second call while one runs fails with ``busy``.
        """
        driver = self._drive()
        self._own_token -= 1
        token = self._own_token
        done: asyncio.Future[TaskFinished] = driver.loop.create_future()
        self._waiting[token] = done
        self._info("px4_takeoff_requested", alt_m=alt_m)
        driver.call(
            lambda now: self.core.request(VehicleRequest(token, TaskKind.TAKEOFF, alt_m), now)
        )
        try:
            finished = await asyncio.shield(done)
        except asyncio.CancelledError:
            driver.call(lambda now: self.core.cancel(token, now, "caller cancelled"))
            raise
        finally:
            self._waiting.pop(token, None)
        outcome = finished.outcome
        assert isinstance(outcome, TakeoffSucceeded | TakeoffFailed)  # noqa: S101 - takeoff
        return outcome

    def status(self) -> dict[str, Any]:
        """JSON-ready snapshot for ``swarmctl status``."""
        out = self.last_outcome
        seq = self.core.last_takeoff
        return {
            "readiness": self.readiness().as_dict(),
            "takeoff": None
            if seq is None
            else {
                "phase": str(seq.phase),
                "outcome": None if out is None else _outcome_dict(out),
            },
            "backend": self.backend.stats(),
            # late answers to ended commands dropped, not credited (docs/security.md case 2)
            "owed_acks": self.core.owed.stats(),
            # failed take-offs that left the vehicle maybe armed on the ground (docs/px4.md)
            "disarm_unconfirmed": self.core.disarm_unconfirmed,
        }

    # ---- driving --------------------------------------------------------------------------

    def _drive(self) -> Driver[Observation, VehicleCommand, VehicleEvent]:
        if self._driver is None:
            raise RuntimeError("the PX4 bridge is not started")
        return self._driver

    def _observe(self, obs: Observation, now: float) -> None:
        if isinstance(obs, StateReset):
            # a new PX4 life (XRCE: a new session; MAVLink: its boot clock went back): every
            # fact of the last one is forgotten (docs/px4.md, "Fresh state")
            self._info("px4_state_reset", backend=self.backend.name, why=obs.why)
        self._drive().datagram_received(obs, None)

    def _on_event(self, event: VehicleEvent) -> None:
        match event:
            case ReadinessChanged(verdict=verdict):
                reason = None if verdict.reason is None else str(verdict.reason)
                self._info(
                    "px4_readiness", ready=verdict.ready, reason=reason, detail=verdict.detail
                )
                for listener in list(self._listeners):
                    listener(verdict)
            case TaskFinished():
                if isinstance(event.outcome, TakeoffSucceeded | TakeoffFailed):
                    self.last_outcome = event.outcome
                waiting = self._waiting.get(event.token)
                if waiting is not None:
                    if not waiting.done():
                        waiting.set_result(event)
                    return
                for task_listener in list(self._task_listeners):
                    task_listener(event)
            case DisarmUnconfirmed():
                for task_listener in list(self._task_listeners):
                    task_listener(event)  # px4_takeoff_disarm logged it (DisarmRepeatsEnded)
            case TakeoffPhaseChanged():
                self._info(
                    "px4_takeoff_phase", old=str(event.old), new=str(event.new), why=event.why
                )
            case CommandSent():
                self._info(
                    "px4_command_sent", command=event.command, confirmation=event.confirmation
                )
            case AckReceived():
                self._info("px4_command_ack", command=event.command, result=event.result)
            case TakeoffSucceeded() | TakeoffFailed():
                self._info("px4_takeoff_outcome", **_outcome_dict(event))
            case DisarmRepeatsEnded():
                # after a failed take-off's outcome: did its DISARM arrive (docs/px4.md, "A
                # failed take-off's DISARM")? Unconfirmed: the vehicle may sit armed, a
                # warning, so ``journalctl -p warning`` shows it (docs/operations.md, logs)
                ended = "confirmed" if event.confirmed else "stopped" if event.stopped else None
                log = self._warning if ended is None else self._info
                log("px4_takeoff_disarm", ended=ended or DISARM_UNCONFIRMED, why=event.why)
            case ActionFinished():
                self._info(
                    "px4_action_outcome",
                    action=str(event.kind),
                    ok=event.ok,
                    reason=event.reason,
                    detail=event.detail,
                )
            case _:
                assert_never(event)

    # ---- logging --------------------------------------------------------------------------

    def _info(self, event: str, **fields: Any) -> None:
        if self._log is not None:
            self._log.info(event, **fields)

    def _warning(self, event: str, **fields: Any) -> None:
        if self._log is not None:
            self._log.warning(event, **fields)


def _outcome_dict(out: Outcome) -> dict[str, Any]:
    if isinstance(out, TakeoffSucceeded):
        return {
            "ok": True,
            "elapsed_s": round(out.elapsed_s, 3),
            "landed_state": out.landed_state,
            "mode": out.mode,
            "target_amsl_m": out.target_amsl_m,
            "altitude_ref": out.altitude_ref,
        }
    return {
        "ok": False,
        "reason": str(out.reason),
        "cause": out.cause,
        "detail": out.detail,
        "elapsed_s": round(out.elapsed_s, 3),
    }
