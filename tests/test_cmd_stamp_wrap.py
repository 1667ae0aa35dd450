"""A copy held back 2^32 ms must not read as fresh (docs/dataplane.md, "Validity";
docs/security.md, "The air: the data plane and commands").

A member's readiness stamps are u32 milliseconds, and ``validity.judge`` takes the elapsed
time since the echoed report modulo 2^32: a copy released 2^32 ms (49.7 days) after its
echoed report plus a second reads as one second old. The copy must still be sealed for
the member's current epoch and fresh in its replay window, and its SN not yet passed by
the member's reader: the attacker holds it and jams every later datagram of the commander
to that member (both daemons up 49.7 days, in the same epochs). Before the member checked
that the echoed stamp is one of its own recent reports (``SwarmCore``'s report log), such
a copy ran 49.7 days late.

Virtual time on the swarm cores (``tests.test_swarm_core.Swarm``): the 49.7 days are not
played (8.6 M readiness ticks); the member simply hears nothing from the commander in them,
which is what the jammer makes of them.
"""

from __future__ import annotations

from swarmd.dataplane.types import Command, CommandKind, TimeEcho
from swarmd.dataplane.validity import (
    EXPIRED,
    MAX_LOGGED_REPORTS,
    MIN_REPORT_PERIOD_MS,
    REPORT_LOG_MS,
    STAMP_MODULUS,
    ReportLog,
    judge,
    stamp_ms,
)
from swarmd.px4.vehicle import VehicleRequest
from swarmd.swarm.events import CommandExpired, OutcomeReported
from tests.test_cmd_validity import _command_datagrams, _cut_takeoff
from tests.test_dataplane_swarm import address_of
from tests.test_swarm_core import Swarm

WRAP_S = STAMP_MODULUS / 1000.0  # 49.7 days: the u32 millisecond stamps wrap


def _release(swarm: Swarm, datagram: bytes, at: float) -> list[object]:
    """The attacker releases ``datagram`` at m01 at ``at`` (m01's clock); m01's events."""
    core = swarm.cores["m01"]
    core.receive_datagram(datagram, address_of(swarm.bundle, "lead"), at)
    events: list[object] = []
    while (event := core.next_event()) is not None:
        events.append(event)
    return events


def test_a_copy_held_back_for_the_stamps_wrap_never_runs() -> None:
    swarm = Swarm(2, seed=22)
    cid, sent_at = _cut_takeoff(swarm)  # m01 is cut off: every copy towards it is held
    held = _command_datagrams(swarm, cid, "m01", sent_at)
    assert held
    # the copy would run at once if released now (guard: it is a genuine, valid copy) ...
    # ... but it is released one wrap later, 1 s after issue as the u32 stamps read it
    events = _release(swarm, held[0], sent_at + WRAP_S + 1.0)
    assert not [e for e in events if isinstance(e, VehicleRequest)]
    assert [e.command_id for e in events if isinstance(e, CommandExpired)] == [cid]
    refusals = [e for e in events if isinstance(e, OutcomeReported)]
    assert [(e.command_id, e.reason) for e in refusals] == [(cid, EXPIRED)]


def test_the_same_copy_released_in_time_runs() -> None:
    """Guard: the check refuses only what is not one of the member's recent reports."""
    swarm = Swarm(2, seed=22)
    cid, sent_at = _cut_takeoff(swarm)
    held = _command_datagrams(swarm, cid, "m01", sent_at)
    events = _release(swarm, held[0], sent_at + 1.0)
    assert [e.origin for e in events if isinstance(e, VehicleRequest)] == [("lead", cid)]


def test_the_report_log_keeps_exactly_the_span_a_runnable_command_can_echo() -> None:
    log = ReportLog()
    cmd = Command(7, CommandKind.HOLD, 0.0, ["m01"], 5_000, [TimeEcho("m01", 1_000, 0, 1)])
    assert log.unknown(cmd, "m01", 1.0) is not None  # never sent: refused
    log.sent(1_000, 1.0)
    assert log.unknown(cmd, "m01", 1.0 + REPORT_LOG_MS / 1000.0) is None
    assert log.unknown(cmd, "m01", 1.0 + REPORT_LOG_MS / 1000.0 + 0.001) is not None
    assert log.unknown(cmd, "m02", 1.0) is None  # no echo for m02: judge refuses it
    for i in range(MAX_LOGGED_REPORTS):  # bounded: the oldest leaves first
        log.sent(2_000 + i, 2.0)
    assert log.unknown(cmd, "m01", 2.0) is not None


def test_the_report_log_keeps_the_whole_span_at_the_fastest_report_period() -> None:
    """Review 13 (the log's cap): ``dataplane.readiness_period_s`` may be as short as 0.05 s
    (the config's floor), 24,000 reports in ``REPORT_LOG_MS``. With 8,192 kept, a report
    409.6 s old was gone: a command echoing a report 500 s old (its commander heard nothing
    newer from us, our reports lost on the way and its commands not) was refused as not one
    of ours, though ``judge`` leaves it time to run. The cap now covers the span at the
    config's floor."""
    log = ReportLog()
    period = MIN_REPORT_PERIOD_MS / 1000.0
    reports = REPORT_LOG_MS // MIN_REPORT_PERIOD_MS
    for i in range(reports):
        log.sent(stamp_ms(i * period), i * period)
    now = reports * period
    echoed = (reports - round(500.0 / period)) * period  # a report 500 s old
    echo = TimeEcho("m01", stamp_ms(echoed), 499_000, 1)
    cmd = Command(7, CommandKind.HOLD, 0.0, ["m01"], 600_000, [echo])
    assert judge(cmd, "m01", now).valid  # guard: the command has time left
    assert log.unknown(cmd, "m01", now) is None
