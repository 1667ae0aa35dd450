"""A command's validity, dated on clocks that are never compared (docs/dataplane.md, "Validity").

Drones share no time: discovery assumes none, and each daemon's ``now`` is its own monotonic
clock. So no absolute time travels. A member stamps each readiness report with its own clock
(``Readiness.stamp_ms``); when the commander issues a command it echoes, for each target, the
stamp of the last report it holds from it and how long before the issue it received that
report (``TimeEcho.age_ms``, commander's clock), with the validity ``valid_ms``. The member
then knows, on its own clock alone, a moment no later than the issue: the report left at
``stamp`` and the commander received it ``age`` before the issue, so the issue happened at
least ``age`` after ``stamp`` (transit only makes this earlier than the truth). Its deadline
is ``stamp + age + valid``: never later than the commander's, whatever the clocks read.

What an attacker who holds and releases authenticated datagrams can do (replays are
refused by the freshness counters): delaying the command makes the member's elapsed time
grow, so the command is refused; delaying the member's report makes the commander's
``age`` smaller for the same stamp, so the deadline moves *earlier*. Delay can make a valid
command expire (as jamming can), never make an expired one run. The echoes are inside the
command sample, so they are under the pair MAC like everything else: editing them is
``auth_failed``.

Stamps are u32 milliseconds: elapsed times are taken modulo 2^32, so a stamp "from the
future" (another boot of the member's clock, or garbage) reads as a huge elapsed time and
the command is refused. Clock rates differ (crystals within +-100 ppm each): the commander's
measured ``age + valid`` is shortened by both tolerances before the member compares it with
its own elapsed time, so drift also errs towards refusing. That holds for a clock that counts
its crystal: the daemon's is CLOCK_MONOTONIC_RAW (``swarmd.rawclock``), never NTP's slewed
CLOCK_MONOTONIC (up to 83,333 ppm under chrony, docs/dataplane.md "Validity").

A life runs only its own commands (docs/dataplane.md, "A life runs only its own
commands"). The same echo bounds the issue from below: it happened no earlier than
``stamp + age`` on the member's clock (``age`` shortened by the drift allowance: the
commander's clock may run fast). A member whose daemon started at ``life_start`` (its clock)
runs a command only if that bound is at or after ``life_start`` (``issued_in_life``):
whatever it ran before, in a life whose record of executed ids may be lost, was issued
before. A stamp of an earlier OS boot (the monotonic clock started again) reads, modulo
2^32, as later than now or as before the life, or, by coincidence, as inside it. So each
echo also names the member's boot epoch under which the commander authenticated the
echoed report (``TimeEcho.epoch``), and a member refuses an echo of any other epoch than
its current one before reading its stamp (``another_life``). The clock rule stays for an
epoch used twice (a lost epoch file with no wall clock, ``swarmd.auth.epoch``).

Pure functions; no clock, no I/O.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from swarmd.dataplane.types import MAX_VALID_MS, Command, TimeEcho

STAMP_MODULUS: Final = 1 << 32
# Both clocks' rate tolerance summed (two crystals at +-100 ppm): the validity a member
# grants is this much shorter than what the commander measured.
DRIFT_PPM: Final = 200
# Reports older than this are not echoed: the bound they give stays sound, but a drone the
# commander has not heard for ten minutes is better refused than dated through drift.
MAX_ECHO_AGE_MS: Final = 600_000
# A report older than this can date no command that may still run: the echo is at most
# MAX_ECHO_AGE_MS old at the issue, and the validity at most MAX_VALID_MS after it.
REPORT_LOG_MS: Final = MAX_ECHO_AGE_MS + MAX_VALID_MS
# The shortest readiness period the config accepts (dataplane.readiness_period_s): one
# report a tick (swarm core's _tick), so at most this many in the log's span.
MIN_REPORT_PERIOD_MS: Final = 50
# A backstop on the log's length: the span at the fastest period (24,001; 1,200 at the
# shipped 1 Hz); past it the oldest go first (their commands are refused). It was 8,192,
# 409.6 s at 0.05 s: a command echoing an older report of the span was refused.
MAX_LOGGED_REPORTS: Final = REPORT_LOG_MS // MIN_REPORT_PERIOD_MS + 1

EXPIRED: Final = "expired"  # the reason a member reports (REJECTED) for a late command
# ... and for one it cannot prove was issued after its daemon started (its executed-id
# record may be lost: it may have run it before)
MEMORY_LOST: Final = "memory_lost"


def stamp_ms(now: float) -> int:
    """This node's clock ``now`` (seconds) as a u32 millisecond stamp, rounded down."""
    return math.floor(now * 1000.0) % STAMP_MODULUS


def echo_of(
    node: str, report_stamp_ms: int, received_at: float, now: float, *, epoch: int
) -> TimeEcho | None:
    """The echo of a report of ``node`` stamped ``report_stamp_ms``, authenticated under
    ``node``'s boot ``epoch`` and received at ``received_at`` (this node's clock), for a
    command issued ``now``; None when too old."""
    age_ms = math.floor(max(0.0, now - received_at) * 1000.0)  # down: the deadline errs early
    if age_ms > MAX_ECHO_AGE_MS:
        return None
    return TimeEcho(node, report_stamp_ms % STAMP_MODULUS, age_ms, epoch)


def valid_ms_of(valid_for_s: float) -> int:
    """A validity in seconds as the wire's milliseconds (rounded down, at least 1)."""
    return min(max(1, math.floor(valid_for_s * 1000.0)), MAX_VALID_MS)


@dataclass(frozen=True, slots=True)
class Judgement:
    """A member's verdict on a command's validity: ``remaining_ms`` > 0 when it may run."""

    valid: bool
    remaining_ms: int
    detail: str


def judge(command: Command, me: str, now: float) -> Judgement:
    """Whether ``command`` is still within its validity for member ``me`` at ``now``
    (``me``'s clock). Fails closed: no validity, or no echo for ``me``, is not valid."""
    if command.valid_ms == 0:
        return Judgement(False, 0, "no validity")
    echo = _echo_for(command.echoes, me)
    if echo is None:
        return Judgement(False, 0, f"no time reference for {me}")
    # +1: our stamp is rounded down, so the true elapsed time may be up to 1 ms more
    elapsed_ms = (stamp_ms(now) - echo.stamp_ms) % STAMP_MODULUS + 1
    granted_ms = (echo.age_ms + command.valid_ms) * (1_000_000 - DRIFT_PPM) // 1_000_000
    remaining = granted_ms - elapsed_ms
    if remaining <= 0:
        detail = f"{elapsed_ms} ms since our report, {granted_ms} ms granted"
        return Judgement(False, remaining, detail)
    return Judgement(True, remaining, "")


def issued_in_life(command: Command, me: str, life_start: float, now: float) -> Judgement:
    """Whether ``command``'s echo for ``me`` proves, on ``me``'s clock, that it was issued
    at or after ``life_start`` (when this life's record of executed ids began), at ``now``.
    Fails closed: no echo proves nothing."""
    echo = _echo_for(command.echoes, me)
    if echo is None:
        return Judgement(False, 0, f"no time reference for {me}")
    # the issue on our clock is no earlier than the report's stamp (rounded down) plus the
    # commander's age, shortened by the drift allowance (its clock may run fast)
    age_low_ms = echo.age_ms * (1_000_000 - DRIFT_PPM) // 1_000_000
    issued_low_ms = (echo.stamp_ms + age_low_ms) % STAMP_MODULUS
    since_issue_ms = (stamp_ms(now) - issued_low_ms) % STAMP_MODULUS
    # both on the same rounded-down millisecond scale: exact, and never negative
    since_life_ms = math.floor(now * 1000.0) - math.floor(life_start * 1000.0)
    if since_issue_ms > since_life_ms:
        detail = f"issued at least {since_issue_ms} ms ago, this life began {since_life_ms} ms ago"
        return Judgement(False, since_life_ms - since_issue_ms, detail)
    return Judgement(True, since_life_ms - since_issue_ms, "")


def another_life(command: Command, me: str, epoch: int) -> str | None:
    """Why ``command``'s echo for ``me`` dates another life of ``me`` than the one in boot
    ``epoch`` (its current one), or None when it names this life or there is no echo (then
    ``judge`` refuses it: nothing dates it). The echoed report was authenticated under the
    epoch the echo names, so its stamp is on that life's clock: after an OS reboot, a clock
    that started again (docs/dataplane.md, "A life runs only its own commands")."""
    echo = _echo_for(command.echoes, me)
    if echo is None or echo.epoch == epoch:
        return None
    return f"dated by a report of boot epoch {echo.epoch}, this life is epoch {epoch}"


class ReportLog:
    """The stamps of this member's own readiness reports of the last ``REPORT_LOG_MS``,
    with when it sent each (its clock). Stamps are u32 milliseconds, so ``judge`` reads a
    copy released 2^32 ms (49.7 days) after its echoed report plus one second as one
    second old; a member whose daemon has been up that long, and whose commander's later
    datagrams an attacker jammed, ran such a copy 49.7 days late. A copy may run only if
    its echo is a stamp this member sent within the log's span (``unknown``).
    What is left: an old stamp equal, to the millisecond, to one sent within the span
    (docs/security.md, "Residual risks: the data plane and commands")."""

    def __init__(self) -> None:
        self._sent: OrderedDict[int, float] = OrderedDict()  # stamp -> sent at, oldest first

    def sent(self, stamp: int, now: float) -> None:
        """This member sent a report stamped ``stamp`` at ``now``."""
        self._sent[stamp] = now
        self._sent.move_to_end(stamp)
        horizon = now - REPORT_LOG_MS / 1000.0
        while self._sent and (
            next(iter(self._sent.values())) < horizon or len(self._sent) > MAX_LOGGED_REPORTS
        ):
            self._sent.popitem(last=False)

    def unknown(self, command: Command, me: str, now: float) -> str | None:
        """Why ``command``'s echo for ``me`` is not a report this member sent within
        ``REPORT_LOG_MS`` of ``now``, or None when it is (no echo: ``judge`` refuses)."""
        echo = _echo_for(command.echoes, me)
        if echo is None:
            return None
        sent = self._sent.get(echo.stamp_ms)
        if sent is not None and now - sent <= REPORT_LOG_MS / 1000.0:
            return None
        return f"stamp {echo.stamp_ms} is not one of our reports of the last {REPORT_LOG_MS} ms"


def _echo_for(echoes: Iterable[TimeEcho], me: str) -> TimeEcho | None:
    for echo in echoes:
        if echo.node == me:
            return echo
    return None
