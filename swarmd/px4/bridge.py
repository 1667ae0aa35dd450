"""``Px4Bridge``: the asyncio driver that joins a backend to readiness and take-off.

The only asyncio in the PX4 logic path, and thin (style.md rule 11): the backend calls
``_observe(obs, loop.time())``; the bridge feeds the shared ``VehicleState``, then the
running ``TakeoffSequence`` if any, sends what the sequence queued, and re-arms one
``TimerHandle`` per engine (the sequence's ``get_timer()``, and the readiness deadline at
which a silent heartbeat turns stale). Readiness changes are pushed to subscribers the
moment they happen, including "the link went quiet", with no polling.

API for the daemon / commander::

    bridge = Px4Bridge.from_config(Px4Config(connection="udpin:127.0.0.1:14540", sysid=1))
    await bridge.start()
    bridge.on_readiness_change(lambda r: publish(r.as_dict()))
    verdict = bridge.readiness()               # Readiness(ready, reason, detail, ...)
    outcome = await bridge.takeoff(alt_m=10.0)  # TakeoffSucceeded | TakeoffFailed
    await bridge.close()
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from swarmd.px4.backend import VehicleBackend
from swarmd.px4.command_sender import AckReceived, CommandSent
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.messages import Observation
from swarmd.px4.readiness import Readiness, ReadinessConfig, VehicleState, readiness
from swarmd.px4.takeoff import (
    FailReason,
    PhaseChanged,
    SequenceEvent,
    TakeoffConfig,
    TakeoffFailed,
    TakeoffSequence,
    TakeoffSucceeded,
)

Outcome = TakeoffSucceeded | TakeoffFailed
ReadinessListener = Callable[[Readiness], None]


@dataclass(frozen=True, slots=True)
class Px4Config:
    """The daemon config's ``px4`` section."""

    connection: str = "udpin:127.0.0.1:14540"  # PX4 SITL / mavlink-router, loopback only
    sysid: int = 1  # the vehicle's MAV_SYS_ID; we are component 191 of it
    autopilot: str | None = None  # "IP:PORT" to pin; None: the first heartbeat's source
    signing_key: bytes | None = None  # MAVLink 2 signing (32 bytes); None: off
    backend: str = "mavlink"  # | "xrce-agent" | "xrce-client" (docs/px4.md)
    xrce_key: int | None = None  # xrce-agent: accept only this UXRCE_DDS_KEY (None: any)
    namespace: str | None = None  # PX4 UXRCE_DDS_NS
    readiness: ReadinessConfig = field(default_factory=ReadinessConfig)
    takeoff: TakeoffConfig = field(default_factory=TakeoffConfig)


class Px4Bridge:
    """One vehicle: live ``VehicleState``, readiness on demand and on change, take-off."""

    def __init__(
        self,
        backend: VehicleBackend,
        *,
        readiness_config: ReadinessConfig | None = None,
        takeoff_config: TakeoffConfig | None = None,
        log: Any = None,
    ) -> None:
        self.backend = backend
        self.readiness_config = readiness_config or ReadinessConfig()
        self.takeoff_config = takeoff_config or TakeoffConfig()
        self.takeoff_config.check()
        self.state = VehicleState()
        self._log = log
        self._loop: asyncio.AbstractEventLoop | None = None
        self._listeners: list[ReadinessListener] = []
        self._last_key: tuple[bool, str | None] | None = None
        self._stale_timer: asyncio.TimerHandle | None = None
        self._sequence: TakeoffSequence | None = None
        self._seq_timer: asyncio.TimerHandle | None = None
        self._done: asyncio.Future[Outcome] | None = None
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
            )
        else:
            backend = MavlinkBackend(
                config.connection,
                sysid=config.sysid,
                autopilot=config.autopilot,
                signing_key=config.signing_key,
            )
        return cls(
            backend, readiness_config=config.readiness, takeoff_config=config.takeoff, log=log
        )

    # ---- life -----------------------------------------------------------------------------

    async def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        await self.backend.start(self._observe)
        self._info("px4_bridge_started", **self.backend.stats())
        self._evaluate(self._loop.time())

    async def close(self) -> None:
        if self._sequence is not None and not self._sequence.done and self._loop is not None:
            self._sequence.cancel(self._loop.time(), "bridge closing")
            self._pump(self._loop.time())
        for timer in (self._stale_timer, self._seq_timer):
            if timer is not None:
                timer.cancel()
        await self.backend.close()

    # ---- readiness ------------------------------------------------------------------------

    def readiness(self) -> Readiness:
        """The verdict now (``loop.time()``)."""
        return readiness(self.state, self._now(), self.readiness_config)

    def on_readiness_change(self, listener: ReadinessListener) -> None:
        """Call ``listener`` whenever ready/reason changes (and once at once)."""
        self._listeners.append(listener)
        listener(self.readiness())

    # ---- take-off -------------------------------------------------------------------------

    async def takeoff(self, alt_m: float | None = None) -> Outcome:
        """Arm and take off to ``alt_m`` above home (None: PX4's MIS_TAKEOFF_ALT).

        Refused at once, with the readiness reason, when the vehicle is not ready. Only one
        take-off runs at a time; a second call while one runs fails with ``busy``.
        """
        now = self._now()
        if self._sequence is not None and not self._sequence.done:
            return TakeoffFailed(FailReason.BUSY, None, "a take-off is already running", 0.0)
        loop = asyncio.get_running_loop()
        self._done = loop.create_future()
        seq = TakeoffSequence(
            self.state,
            alt_m,
            config=self.takeoff_config,
            readiness_config=self.readiness_config,
        )
        self._sequence = seq
        self._info("px4_takeoff_requested", alt_m=alt_m)
        seq.start(now)
        self._pump(now)
        try:
            return await asyncio.shield(self._done)
        except asyncio.CancelledError:
            if not seq.done:
                seq.cancel(self._now(), "caller cancelled")
                self._pump(self._now())
            raise

    def status(self) -> dict[str, Any]:
        """JSON-ready snapshot for ``swarmctl status``."""
        out = self.last_outcome
        return {
            "readiness": self.readiness().as_dict(),
            "takeoff": None
            if self._sequence is None
            else {
                "phase": str(self._sequence.phase),
                "outcome": None if out is None else _outcome_dict(out),
            },
            "backend": self.backend.stats(),
        }

    # ---- driving --------------------------------------------------------------------------

    def _now(self) -> float:
        loop = self._loop or asyncio.get_running_loop()
        return loop.time()

    def _observe(self, obs: Observation, now: float) -> None:
        self.state.observe(obs, now)
        if self._sequence is not None and not self._sequence.done:
            self._sequence.observe(obs, now)
            self._pump(now)
        self._evaluate(now)

    def _pump(self, now: float) -> None:
        seq = self._sequence
        if seq is None:
            return
        for cmd in seq.commands_to_send():
            self.backend.send(cmd)
        while (event := seq.next_event()) is not None:
            self._log_event(event)
            if isinstance(event, TakeoffSucceeded | TakeoffFailed):
                self.last_outcome = event
                if self._done is not None and not self._done.done():
                    self._done.set_result(event)
        if self._seq_timer is not None:
            self._seq_timer.cancel()
            self._seq_timer = None
        deadline = seq.get_timer()
        if deadline is not None and self._loop is not None:
            self._seq_timer = self._loop.call_at(deadline, self._on_seq_timer)

    def _on_seq_timer(self) -> None:
        self._seq_timer = None
        now = self._now()
        if self._sequence is not None:
            self._sequence.handle_timer(now)
            self._pump(now)

    def _evaluate(self, now: float) -> None:
        verdict = readiness(self.state, now, self.readiness_config)
        key = (verdict.ready, None if verdict.reason is None else str(verdict.reason))
        if key != self._last_key:
            self._last_key = key
            self._info("px4_readiness", ready=verdict.ready, reason=key[1], detail=verdict.detail)
            for listener in list(self._listeners):
                listener(verdict)
        if self._stale_timer is not None:
            self._stale_timer.cancel()
            self._stale_timer = None
        deadline = self.state.next_deadline(self.readiness_config)
        if deadline is not None and deadline > now and self._loop is not None:
            self._stale_timer = self._loop.call_at(deadline, self._on_stale_timer)

    def _on_stale_timer(self) -> None:
        self._stale_timer = None
        self._evaluate(self._now())

    # ---- logging --------------------------------------------------------------------------

    def _info(self, event: str, **fields: Any) -> None:
        if self._log is not None:
            self._log.info(event, **fields)

    def _log_event(self, event: SequenceEvent) -> None:
        match event:
            case PhaseChanged():
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


def _outcome_dict(out: Outcome) -> dict[str, Any]:
    if isinstance(out, TakeoffSucceeded):
        return {
            "ok": True,
            "elapsed_s": round(out.elapsed_s, 3),
            "landed_state": out.landed_state,
            "mode": out.mode,
            "target_amsl_m": out.target_amsl_m,
        }
    return {
        "ok": False,
        "reason": str(out.reason),
        "cause": out.cause,
        "detail": out.detail,
        "elapsed_s": round(out.elapsed_s, 3),
    }
