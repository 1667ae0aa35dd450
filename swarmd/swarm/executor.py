"""A member executes the swarm's commands on its own vehicle, through the PX4 bridge.

The data plane hands over each command id once (docs/dataplane.md, "Exactly once"); this
module turns it into autopilot actions and reports back on ``swarm/outcome``:

- TAKEOFF: refused at once (REJECTED, reason = the readiness code, e.g. ``no_3d_fix``) when the
  vehicle is not ready *now* — the commander's view is up to one report old; else ACCEPTED at
  once (the commander's latency measure), then ``Px4Bridge.takeoff`` and COMPLETED (reason
  = the landed state, ``TAKEOFF``/``IN_AIR``) or FAILED (reason = the sequence's code and
  cause, e.g. ``arm_rejected: TEMPORARILY_REJECTED``).
- LAND (``NAV_LAND``) and HOLD (``DO_SET_MODE`` AUTO.LOITER, PX4's Hold): COMPLETED when
  the autopilot's COMMAND_ACK says ACCEPTED, FAILED with the MAV_RESULT name or ``no_ack``.
- ABORT: stops a running take-off (the sequence disarms if it armed), then lands a vehicle
  in the air or disarms one armed on the ground — never a forced disarm, which PX4 would
  obey in the air.

Without a PX4 bridge (``px4.enabled: false``) every command is REJECTED ``px4_disabled``.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from typing import Any, Final

from swarmd.dataplane.types import Command, CommandKind, CommandResult
from swarmd.px4.bridge import Px4Bridge
from swarmd.px4.constants import (
    LandedState,
    MavCmd,
    MavResult,
    Px4AutoSubMode,
    Px4MainMode,
)
from swarmd.px4.messages import CommandAck, VehicleCommand
from swarmd.px4.takeoff import FailReason, TakeoffSucceeded

Report = Callable[[int, CommandResult, str], None]

PX4_DISABLED: Final = "px4_disabled"
# MAVLink command protocol as MAVSDK: an ACK within 0.5 s, else resend (3 times)
ACK_TIMEOUT_S: Final = 0.5
ACK_POLL_S: Final = 0.05
SEND_ATTEMPTS: Final = 4
MODE_FLAG_CUSTOM: Final = 1.0  # DO_SET_MODE param1: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


class CommandExecutor:
    """Runs each command it is given on the vehicle and reports the outcome."""

    def __init__(self, bridge: Px4Bridge | None, report: Report, *, log: Any) -> None:
        self.bridge = bridge
        self.report = report
        self.log = log
        self.counters: dict[str, int] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._takeoff: asyncio.Task[None] | None = None

    def execute(self, commander: str, command: Command) -> None:
        """Start executing ``command`` (never blocks, never raises)."""
        kind = CommandKind(command.kind)
        self._count(f"received_{kind.name.lower()}")
        self.log.info(
            "command_received",
            commander=commander,
            command_id=command.command_id,
            kind=kind.name,
            altitude_m=command.altitude_m if kind == CommandKind.TAKEOFF else None,
        )
        if self.bridge is None:
            self._report(command, CommandResult.REJECTED, PX4_DISABLED)
            return
        if kind == CommandKind.TAKEOFF:
            verdict = self.bridge.readiness()
            if not verdict.ready:
                self._report(command, CommandResult.REJECTED, str(verdict.reason))
                return
            self._report(command, CommandResult.ACCEPTED, "")
            self._takeoff = self._spawn(self._run_takeoff(command), f"takeoff-{command.command_id}")
        elif kind == CommandKind.LAND:
            self._report(command, CommandResult.ACCEPTED, "")
            self._spawn(self._run_simple(command, _land()), f"land-{command.command_id}")
        elif kind == CommandKind.HOLD:
            self._report(command, CommandResult.ACCEPTED, "")
            self._spawn(self._run_simple(command, _hold()), f"hold-{command.command_id}")
        else:
            self._report(command, CommandResult.ACCEPTED, "")
            self._spawn(self._run_abort(command), f"abort-{command.command_id}")

    async def close(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def status(self) -> dict[str, Any]:
        return {"running": len(self._tasks), "counters": dict(sorted(self.counters.items()))}

    # ---- the actions ----------------------------------------------------------------------

    async def _run_takeoff(self, command: Command) -> None:
        assert self.bridge is not None  # noqa: S101 - execute() checked it
        try:
            outcome = await self.bridge.takeoff(command.altitude_m)
        except asyncio.CancelledError:  # ABORT, or the daemon stopping
            self._report(command, CommandResult.FAILED, str(FailReason.CANCELLED))
            raise
        if isinstance(outcome, TakeoffSucceeded):
            self._report(command, CommandResult.COMPLETED, outcome.landed_state)
            return
        reason = str(outcome.reason) + (f": {outcome.cause}" if outcome.cause else "")
        result = (
            CommandResult.REJECTED
            if outcome.reason == FailReason.NOT_READY
            else CommandResult.FAILED
        )
        self._report(command, result, reason)

    async def _run_simple(self, command: Command, vehicle_command: VehicleCommand) -> None:
        result = await self._send_with_ack(vehicle_command)
        if result == MavResult.ACCEPTED:
            self._report(command, CommandResult.COMPLETED, "")
        else:
            self._report(command, CommandResult.FAILED, "no_ack" if result is None else result.name)

    async def _run_abort(self, command: Command) -> None:
        assert self.bridge is not None  # noqa: S101 - execute() checked it
        running = self._takeoff
        if running is not None and not running.done():
            running.cancel()  # the bridge cancels the sequence, which disarms if it armed
            with contextlib.suppress(asyncio.CancelledError):
                await running
        state = self.bridge.state
        if state.landed_state not in (None, LandedState.ON_GROUND):
            action: VehicleCommand | None = _land()
        elif state.armed:
            action = VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=0.0)
        else:
            action = None
        if action is None:
            self._report(command, CommandResult.COMPLETED, "on_ground_disarmed")
            return
        result = await self._send_with_ack(action)
        if result == MavResult.ACCEPTED:
            self._report(command, CommandResult.COMPLETED, action.label)
        else:
            self._report(command, CommandResult.FAILED, "no_ack" if result is None else result.name)

    async def _send_with_ack(self, command: VehicleCommand) -> MavResult | None:
        """Send, resend until an ACK for it arrives; its result, or None after the budget."""
        assert self.bridge is not None  # noqa: S101 - callers checked it
        state = self.bridge.state
        loop = asyncio.get_running_loop()
        for attempt in range(SEND_ATTEMPTS):
            before = state.last_ack
            self.bridge.backend.send(command.retransmission(attempt))
            deadline = loop.time() + ACK_TIMEOUT_S
            # the bridge records every ACK in its VehicleState; a short poll is simpler than a
            # second subscription path into it, and runs only for an operator's command
            while loop.time() < deadline:
                await asyncio.sleep(ACK_POLL_S)
                ack = state.last_ack
                if ack is not before and isinstance(ack, CommandAck):
                    if ack.command == command.command:
                        try:
                            return MavResult(ack.result)
                        except ValueError:
                            return MavResult.FAILED
        return None

    # ---- helpers --------------------------------------------------------------------------

    def _spawn(self, coro: Any, name: str) -> asyncio.Task[None]:
        task: asyncio.Task[None] = asyncio.get_running_loop().create_task(coro, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._done)
        return task

    def _done(self, task: asyncio.Task[None]) -> None:
        self._tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            self._count("task_errors")
            self.log.error(
                "command_task_failed", task=task.get_name(), error=repr(task.exception())
            )

    def _report(self, command: Command, result: CommandResult, reason: str) -> None:
        self._count(f"outcome_{result.name.lower()}")
        self.log.info(
            "command_outcome",
            command_id=command.command_id,
            kind=CommandKind(command.kind).name,
            result=result.name,
            reason=reason,
        )
        self.report(command.command_id, result, reason)

    def _count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1


def _land() -> VehicleCommand:
    return VehicleCommand.make(MavCmd.NAV_LAND)


def _hold() -> VehicleCommand:
    return VehicleCommand.make(
        MavCmd.DO_SET_MODE,
        p1=MODE_FLAG_CUSTOM,
        p2=float(Px4MainMode.AUTO),
        p3=float(Px4AutoSubMode.LOITER),
    )
