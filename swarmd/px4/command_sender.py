"""One backend-neutral command sender: send a ``VehicleCommand``, wait for its ack, retry.

Theory of operation
-------------------
The MAVLink command protocol (reference 1.6; MAVSDK ``mavlink_command_sender``), which PX4
also follows for ``/fmu/in/vehicle_command`` -> ``/fmu/out/vehicle_command_ack`` over
XRCE-DDS: the sender transmits a command, waits ``ack_timeout_s`` for the ack naming that
command number, and retransmits at most ``retries`` times with ``confirmation`` counting
1, 2, 3. The ack's result decides what happens next:

================================  ===========================================================
ACCEPTED                          finished: ``ACCEPTED``
IN_PROGRESS                       keep waiting, ``in_progress_timeout_s`` from that ack
TEMPORARILY_REJECTED              wait ``retry_backoff_s``, retransmit from the same budget;
                                  budget spent: finished ``REFUSED``
DENIED, UNSUPPORTED, FAILED, ...  final: finished ``REFUSED`` (any result not listed above,
                                  including numbers MAV_RESULT does not define)
no ack after 1 + retries sends    finished ``NO_ACK`` (or ``REFUSED`` with the last result
                                  when an IN_PROGRESS / TEMPORARILY_REJECTED was the last word)
================================  ===========================================================

An ack can be lost on the way back while the command took effect, so the caller may end a
command early with ``confirm(handle, now, why)`` when the vehicle state shows the effect
(armed bit for ARM, mode AUTO.LAND for NAV_LAND, ...): finished ``CONFIRMED``. Success by
ack alone is the caller's choice; the take-off sequence and the LAND/HOLD/ABORT actions
(``swarmd.px4.actions``) declare success from state.

One outstanding command per command number (as MAVSDK: an ack names only the number, so two
in flight could not be told apart); sending a number again while it is pending cancels the
old one (finished ``CANCELLED``) and starts afresh with confirmation 0.

How a backend / driver uses it (sans-IO: no clock, no I/O, never raises on autopilot input)::

    sender = CommandSender(SenderConfig())
    handle = sender.send(VehicleCommand.make(MavCmd.NAV_LAND), now)
    # the driver loop, identical for MAVLink and XRCE-DDS backends:
    for cmd in sender.commands_to_send():   # VehicleCommand, confirmation filled in
        backend.send(cmd)                   # COMMAND_LONG, or /fmu/in/vehicle_command
    sender.observe(ack, now)                # every CommandAck the backend decodes
    sender.handle_timer(now)                # at (or after) sender.get_timer()
    while (event := sender.next_event()) is not None:
        ...                                 # CommandSent, AckReceived, CommandFinished

A backend only has to turn ``VehicleCommand`` into its wire and its ack message into
``messages.CommandAck``; the protocol above lives here once.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import StrEnum
from typing import Generic, TypeVar

from swarmd.px4.constants import MavResult
from swarmd.px4.messages import CommandAck, Observation, VehicleCommand


@dataclass(frozen=True, slots=True)
class SenderConfig:
    """Timing of the command protocol; defaults are MAVSDK's command sender."""

    ack_timeout_s: float = 0.5
    retries: int = 3  # retransmissions after the first send
    in_progress_timeout_s: float = 3.0
    retry_backoff_s: float = 0.5  # wait after TEMPORARILY_REJECTED

    def check(self) -> None:
        """Raise ValueError (one line) on a budget that is no budget."""
        if self.retries < 0 or self.ack_timeout_s <= 0:
            raise ValueError("command sender: retries must be >= 0 and ack_timeout_s > 0")

    def budget_s(self) -> float:
        """Worst case from the first send to a final answer without IN_PROGRESS."""
        return (1 + self.retries) * max(self.ack_timeout_s, self.retry_backoff_s)


class Finish(StrEnum):
    """How a command ended (``CommandFinished.finish``)."""

    ACCEPTED = "accepted"  # ack ACCEPTED
    CONFIRMED = "confirmed"  # the caller saw the effect in the vehicle state
    REFUSED = "refused"  # a final result, or a retryable one with the budget spent
    NO_ACK = "no_ack"  # 1 + retries sends, never an ack
    CANCELLED = "cancelled"  # by the caller, or superseded by the same command number


@dataclass(frozen=True, slots=True)
class CommandSent:
    command: str  # the MAV_CMD name
    confirmation: int
    handle: int = 0


@dataclass(frozen=True, slots=True)
class AckReceived:
    command: str
    result: str  # the MAV_RESULT name
    handle: int = 0


@dataclass(frozen=True, slots=True)
class CommandFinished:
    handle: int
    command: VehicleCommand
    finish: Finish
    result: MavResult | None  # the last ack's result, None when no ack came
    sends: int
    why: str

    @property
    def ok(self) -> bool:
        return self.finish in (Finish.ACCEPTED, Finish.CONFIRMED)

    @property
    def cause(self) -> str:
        """One code for an outcome line: ``DENIED``, ``no_ack``, ``cancelled``..."""
        if self.finish is Finish.CANCELLED:
            return "cancelled"
        return "no_ack" if self.result is None else self.result.name


SenderEvent = CommandSent | AckReceived | CommandFinished
"""Everything ``CommandSender.next_event`` returns."""


@dataclass(slots=True)
class _Pending:
    handle: int
    command: VehicleCommand
    sent: int
    deadline: float
    last_result: MavResult | None = None


class CommandSender:
    """Commands awaiting their acks. Driven by ``send``, ``observe``, ``handle_timer``
    (and ``confirm``/``cancel``); outputs ``commands_to_send``, ``get_timer``,
    ``next_event``. See the module docstring."""

    def __init__(self, config: SenderConfig | None = None) -> None:
        self.config = config or SenderConfig()
        self.config.check()
        self._pending: dict[int, _Pending] = {}  # command number -> its one pending send
        self._next_handle = 1
        self._out: list[VehicleCommand] = []
        self._events: deque[SenderEvent] = deque()

    # ---- inputs -------------------------------------------------------------------------

    def send(self, command: VehicleCommand, now: float) -> int:
        """Send ``command`` (confirmation 0) and start waiting for its ack; its handle."""
        old = self._pending.get(command.command)
        if old is not None:
            self._finish(old, Finish.CANCELLED, "superseded by a new send of the same command")
        handle = self._next_handle
        self._next_handle += 1
        pending = _Pending(handle, command, sent=0, deadline=now)
        self._pending[command.command] = pending
        self._transmit(pending, now)
        return handle

    def observe(self, obs: Observation, now: float) -> None:
        """Any autopilot observation; only ``CommandAck`` matters here."""
        if not isinstance(obs, CommandAck):
            return
        pending = self._pending.get(obs.command)
        if pending is None:
            return  # an answer to someone else's command, or to one we finished with
        try:
            result = MavResult(obs.result)
        except ValueError:
            result = MavResult.FAILED  # a number MAV_RESULT does not define: final
        self._events.append(AckReceived(pending.command.label, result.name, pending.handle))
        pending.last_result = result
        match result:
            case MavResult.ACCEPTED:
                self._finish(pending, Finish.ACCEPTED, "ack ACCEPTED")
            case MavResult.IN_PROGRESS:
                pending.deadline = now + self.config.in_progress_timeout_s
            case MavResult.TEMPORARILY_REJECTED:
                if pending.sent <= self.config.retries:
                    pending.deadline = now + self.config.retry_backoff_s
                else:
                    self._give_up(pending)
            case _:
                self._finish(pending, Finish.REFUSED, f"ack {result.name}")

    def handle_timer(self, now: float) -> None:
        """Call at (or after) ``get_timer()``; early calls are harmless."""
        for pending in list(self._pending.values()):
            if now < pending.deadline:
                continue
            if pending.sent <= self.config.retries:
                self._transmit(pending, now)
            else:
                self._give_up(pending)

    def confirm(self, handle: int, now: float, why: str) -> None:
        """The caller saw the command's effect in the vehicle state: finished, no retries."""
        pending = self._by_handle(handle)
        if pending is not None:
            self._finish(pending, Finish.CONFIRMED, why)

    def cancel(self, handle: int, now: float, why: str = "cancelled by caller") -> None:
        pending = self._by_handle(handle)
        if pending is not None:
            self._finish(pending, Finish.CANCELLED, why)

    # ---- outputs ------------------------------------------------------------------------

    def commands_to_send(self) -> list[VehicleCommand]:
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float | None:
        return min((p.deadline for p in self._pending.values()), default=None)

    def next_event(self) -> SenderEvent | None:
        return self._events.popleft() if self._events else None

    def pending(self, handle: int) -> bool:
        return self._by_handle(handle) is not None

    # ---- internals ----------------------------------------------------------------------

    def _by_handle(self, handle: int) -> _Pending | None:
        return next((p for p in self._pending.values() if p.handle == handle), None)

    def _transmit(self, pending: _Pending, now: float) -> None:
        cmd = pending.command.retransmission(pending.sent)
        pending.sent += 1
        pending.deadline = now + self.config.ack_timeout_s
        self._out.append(cmd)
        self._events.append(CommandSent(cmd.label, cmd.confirmation, pending.handle))

    def _give_up(self, pending: _Pending) -> None:
        if pending.last_result is None:
            self._finish(pending, Finish.NO_ACK, f"no ack after {pending.sent} sends")
        else:
            why = f"answered {pending.last_result.name} after {pending.sent} sends"
            self._finish(pending, Finish.REFUSED, why)

    def _finish(self, pending: _Pending, finish: Finish, why: str) -> None:
        del self._pending[pending.command.command]
        self._events.append(
            CommandFinished(
                pending.handle, pending.command, finish, pending.last_result, pending.sent, why
            )
        )


E = TypeVar("E")


class SenderTask(Generic[E]):
    """Base of a sans-IO task built on one ``CommandSender`` (the take-off sequence, the
    LAND/HOLD/DISARM actions): it owns the sender, the commands going out and the event
    queue, in order. A subclass says when it is finished, what it waits for besides acks
    (``_own_deadline``) and what a finished command means to it (``_on_finished``)."""

    def __init__(self, config: SenderConfig | None) -> None:
        self._sender = CommandSender(config)
        self._out: list[VehicleCommand] = []
        self._events: deque[E | CommandSent | AckReceived] = deque()

    def commands_to_send(self) -> list[VehicleCommand]:
        out, self._out = self._out, []
        return out

    def get_timer(self) -> float | None:
        if self._finished():
            return None
        deadline = self._sender.get_timer()
        return deadline if deadline is not None else self._own_deadline()

    def next_event(self) -> E | CommandSent | AckReceived | None:
        return self._events.popleft() if self._events else None

    @property
    def done(self) -> bool:
        return self._finished()

    def _finished(self) -> bool:
        # a method, not a property: mypy narrows a property across calls that change it
        raise NotImplementedError

    def _own_deadline(self) -> float | None:
        return None

    def _on_finished(self, done: CommandFinished, now: float) -> None:
        raise NotImplementedError

    def _drain(self, now: float) -> None:
        """Take the sender's transmissions and events, in order; act on its verdicts."""
        while (event := self._sender.next_event()) is not None:
            self._out += self._sender.commands_to_send()
            if isinstance(event, CommandFinished):
                self._on_finished(event, now)
            else:
                self._events.append(event)
        self._out += self._sender.commands_to_send()
