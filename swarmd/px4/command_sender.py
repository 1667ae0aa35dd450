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

Answers still owed (``OwedAcks``): a COMMAND_ACK carries no request id and does not echo
``confirmation`` (mavlink.io, "Command Protocol": the ack names the command and its target
only), so a late answer to an earlier command of the same number (a retransmission's, or a
failed take-off's DISARM, which has ARM's number) would be taken as a later command's. Each
COMMAND_LONG transmission may draw one final answer, so when a command ends (any finish)
with fewer final answers than sends, the difference is *owed*, per command number. An ack
first pays such a debt (dropped, counted ``paid``) before it is matched to the pending
command. Bounded: ``MAX_OWED_PER_COMMAND`` debts per number are kept one by one, more
are pooled as a count (one vehicle owes up to eight on ARM's number after one failed
take-off: four ARMs, then up to four DISARMs, px4.md "A failed take-off's DISARM"; and
one per superseded LAND, so no cap a vehicle cannot pass exists; a debt dropped would let
its late answer fail the next command), at most ``MAX_OWED_COMMANDS`` numbers (the vehicle
sends four), each debt forgotten ``owed_window_s`` after its command ended (a pooled one
with the latest of the pool), and a retransmission forgets its number's debts: a debt
whose answer was lost swallows at most the answer to the later command's first
transmission, never one to a retransmission.
IN_PROGRESS never pays (the final answer is still owed) and is not credited while a debt
is owed. Senders of one vehicle share one ``OwedAcks`` (``swarmd.px4.vehicle``), so a
debt survives the task that made it.

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
from typing import Final, Generic, TypeVar

from swarmd.px4.constants import MavResult
from swarmd.px4.messages import CommandAck, Observation, VehicleCommand


@dataclass(frozen=True, slots=True)
class SenderConfig:
    """Timing of the command protocol; defaults are MAVSDK's command sender."""

    ack_timeout_s: float = 0.5
    retries: int = 3  # retransmissions after the first send
    in_progress_timeout_s: float = 3.0
    retry_backoff_s: float = 0.5  # wait after TEMPORARILY_REJECTED
    # how long an ended command's unanswered transmissions are owed an answer (OwedAcks):
    # PX4 answers within milliseconds on loopback or a UART, so two ack timeouts cover an
    # answer the sender gave up on; longer only delays a later command's first answer
    owed_window_s: float = 1.0

    def check(self) -> None:
        """Raise ValueError (one line) on a budget that is no budget."""
        if self.retries < 0 or self.ack_timeout_s <= 0:
            raise ValueError("command sender: retries must be >= 0 and ack_timeout_s > 0")
        if self.owed_window_s < 0:
            raise ValueError("command sender: owed_window_s must be >= 0")

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


MAX_OWED_PER_COMMAND: Final = 4
"""Debts kept one by one per command number (one command's 1 + 3 sends), each with its own
expiry. More than that is normal for one vehicle: a take-off whose four ARMs went
unanswered then sends its DISARM, repeated up to four times while unanswered (up to eight
on ARM's number), and each LAND a later LAND
supersedes owes one more, as many as the operator sends within ``owed_window_s``. The debts
beyond it are *pooled*: kept as a count that expires with the latest of them, so memory
stays bounded and no owed answer is ever credited to a later command. Only our own sends
create debts; whatever PX4 answers, a retransmission still forgets them all."""
MAX_OWED_COMMANDS: Final = 8
"""Command numbers with debts. The vehicle sends four (ARM/DISARM, NAV_TAKEOFF, NAV_LAND,
DO_SET_MODE: ``tests/test_px4_stale_ack.py`` pins it), so this is never reached; the cap
keeps that true of any future caller. The number with the oldest debt is evicted."""


@dataclass(slots=True)
class _Debts:
    """One command number's debts: up to ``MAX_OWED_PER_COMMAND`` expiry times, oldest
    first, and the older ones pooled as a count with the latest of their expiries (never
    later than ``times[0]``: ``now`` only grows)."""

    times: deque[float]
    pooled: int = 0
    pooled_until: float = 0.0

    def count(self) -> int:
        return self.pooled + len(self.times)

    def oldest(self) -> float:
        return self.pooled_until if self.pooled else self.times[0]


class OwedAcks:
    """Per command number, the answers ended commands still owe (module docstring, "Answers
    still owed"): ``_Debts``, oldest first. Pure, keyed by ``now``; expired debts are
    dropped when touched, so it needs no timer."""

    def __init__(self, window_s: float) -> None:
        self.window_s = window_s
        self._owed: dict[int, _Debts] = {}
        self._last: tuple[CommandAck, bool] | None = None
        self.paid = 0  # acks dropped as an earlier command's answer
        self.forgotten = 0  # debts expired or cleared by a retransmission
        self.pooled = 0  # debts past MAX_OWED_PER_COMMAND, kept as a count (_Debts)
        self.evicted = 0  # debts dropped by MAX_OWED_COMMANDS: their answers may be credited

    def owe(self, command: int, count: int, now: float) -> None:
        """An ended command of number ``command`` left ``count`` transmissions unanswered."""
        if count <= 0:
            return
        self._prune(now)
        debts = self._owed.get(command)
        if debts is None:
            if len(self._owed) >= MAX_OWED_COMMANDS:
                oldest = min(self._owed, key=lambda c: self._owed[c].oldest())
                self.evicted += self._owed.pop(oldest).count()
            debts = self._owed[command] = _Debts(deque())
        for _ in range(count):
            if len(debts.times) >= MAX_OWED_PER_COMMAND:
                # pooled, not dropped: an answer owed and forgotten would be credited to
                # the next command of this number (a late DENIED failing a LAND PX4 flies)
                debts.pooled_until = debts.times.popleft()
                debts.pooled += 1
                self.pooled += 1
            debts.times.append(now + self.window_s)

    def forget(self, command: int) -> None:
        """A retransmission of ``command``: its answer is what we wait for now, so nothing
        owed before it may swallow it (a lost debt costs at most one retransmission)."""
        debts = self._owed.pop(command, None)
        if debts is not None:
            self.forgotten += debts.count()

    def owes(self, command: int, now: float) -> int:
        self._prune(now)
        debts = self._owed.get(command)
        return 0 if debts is None else debts.count()

    def pay(self, ack: CommandAck, now: float) -> bool:
        """Is ``ack`` an earlier command's answer (True: drop it)? A final result pays one
        debt, the oldest; IN_PROGRESS pays none but is dropped while one is owed. Several
        senders of one vehicle share this table and see the same observation: its first
        verdict stands."""
        if self._last is not None and self._last[0] is ack:
            return self._last[1]
        verdict = self.owes(ack.command, now) > 0
        if verdict and ack.result != MavResult.IN_PROGRESS:
            debts = self._owed[ack.command]
            if debts.pooled:
                debts.pooled -= 1
            else:
                debts.times.popleft()
            if not debts.count():
                del self._owed[ack.command]
            self.paid += 1
        self._last = (ack, verdict)
        return verdict

    def stats(self) -> dict[str, int]:
        """Counters for ``swarmctl status`` (px4 ``owed_acks``)."""
        return {
            "paid": self.paid,
            "forgotten": self.forgotten,
            "pooled": self.pooled,
            "evicted": self.evicted,
        }

    def _prune(self, now: float) -> None:
        for command in list(self._owed):
            debts = self._owed[command]
            if debts.pooled and debts.pooled_until <= now:
                self.forgotten += debts.pooled
                debts.pooled = 0
            while debts.times and debts.times[0] <= now:
                debts.times.popleft()
                self.forgotten += 1
            if not debts.count():
                del self._owed[command]


@dataclass(slots=True)
class _Pending:
    handle: int
    command: VehicleCommand
    sent: int
    deadline: float
    last_result: MavResult | None = None
    answers: int = 0  # final answers taken (not IN_PROGRESS): sent - answers are owed at the end


class CommandSender:
    """Commands awaiting their acks. Driven by ``send``, ``observe``, ``handle_timer``
    (and ``confirm``/``cancel``); outputs ``commands_to_send``, ``get_timer``,
    ``next_event``. See the module docstring."""

    def __init__(self, config: SenderConfig | None = None, owed: OwedAcks | None = None) -> None:
        self.config = config or SenderConfig()
        self.config.check()
        self.owed = owed if owed is not None else OwedAcks(self.config.owed_window_s)
        self._pending: dict[int, _Pending] = {}  # command number -> its one pending send
        self._next_handle = 1
        self._out: list[VehicleCommand] = []
        self._events: deque[SenderEvent] = deque()

    # ---- inputs -------------------------------------------------------------------------

    def send(self, command: VehicleCommand, now: float) -> int:
        """Send ``command`` (confirmation 0) and start waiting for its ack; its handle."""
        old = self._pending.get(command.command)
        if old is not None:
            self._finish(old, Finish.CANCELLED, "superseded by a new send of the same command", now)
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
        if self.owed.pay(obs, now):
            return  # an ended command's answer (module docstring, "Answers still owed")
        pending = self._pending.get(obs.command)
        if pending is None:
            return  # an answer to someone else's command, or to one we finished with
        try:
            result = MavResult(obs.result)
        except ValueError:
            result = MavResult.FAILED  # a number MAV_RESULT does not define: final
        self._events.append(AckReceived(pending.command.label, result.name, pending.handle))
        pending.last_result = result
        if result is not MavResult.IN_PROGRESS:
            pending.answers += 1
        match result:
            case MavResult.ACCEPTED:
                self._finish(pending, Finish.ACCEPTED, "ack ACCEPTED", now)
            case MavResult.IN_PROGRESS:
                pending.deadline = now + self.config.in_progress_timeout_s
            case MavResult.TEMPORARILY_REJECTED:
                if pending.sent <= self.config.retries:
                    pending.deadline = now + self.config.retry_backoff_s
                else:
                    self._give_up(pending, now)
            case _:
                self._finish(pending, Finish.REFUSED, f"ack {result.name}", now)

    def handle_timer(self, now: float) -> None:
        """Call at (or after) ``get_timer()``; early calls are harmless."""
        for pending in list(self._pending.values()):
            if now < pending.deadline:
                continue
            if pending.sent <= self.config.retries:
                self._transmit(pending, now)
            else:
                self._give_up(pending, now)

    def confirm(self, handle: int, now: float, why: str) -> None:
        """The caller saw the command's effect in the vehicle state: finished, no retries."""
        pending = self._by_handle(handle)
        if pending is not None:
            self._finish(pending, Finish.CONFIRMED, why, now)

    def cancel(self, handle: int, now: float, why: str = "cancelled by caller") -> None:
        pending = self._by_handle(handle)
        if pending is not None:
            self._finish(pending, Finish.CANCELLED, why, now)

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

    def would_send(self, now: float) -> bool:
        """Would ``handle_timer(now)`` put a frame on the wire (a retransmission due, its
        budget not spent)? The take-off asks before it lets one go (its validity)."""
        return any(
            p.deadline <= now and p.sent <= self.config.retries for p in self._pending.values()
        )

    # ---- internals ----------------------------------------------------------------------

    def _by_handle(self, handle: int) -> _Pending | None:
        return next((p for p in self._pending.values() if p.handle == handle), None)

    def _transmit(self, pending: _Pending, now: float) -> None:
        cmd = pending.command.retransmission(pending.sent)
        if pending.sent > 0:
            self.owed.forget(cmd.command)
        pending.sent += 1
        pending.deadline = now + self.config.ack_timeout_s
        self._out.append(cmd)
        self._events.append(CommandSent(cmd.label, cmd.confirmation, pending.handle))

    def _give_up(self, pending: _Pending, now: float) -> None:
        if pending.last_result is None:
            self._finish(pending, Finish.NO_ACK, f"no ack after {pending.sent} sends", now)
        else:
            why = f"answered {pending.last_result.name} after {pending.sent} sends"
            self._finish(pending, Finish.REFUSED, why, now)

    def _finish(self, pending: _Pending, finish: Finish, why: str, now: float) -> None:
        del self._pending[pending.command.command]
        self.owed.owe(pending.command.command, pending.sent - pending.answers, now)
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

    def __init__(self, config: SenderConfig | None, owed: OwedAcks | None = None) -> None:
        self._sender = CommandSender(config, owed)
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
