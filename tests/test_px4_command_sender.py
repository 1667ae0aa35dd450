"""The backend-neutral command sender on hand-set time: ack, retries, every MAV_RESULT."""

from __future__ import annotations

from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.px4.command_sender import (
    MAX_OWED_COMMANDS,
    MAX_OWED_PER_COMMAND,
    AckReceived,
    CommandFinished,
    CommandSender,
    CommandSent,
    Finish,
    OwedAcks,
    SenderConfig,
    SenderEvent,
)
from swarmd.px4.constants import MavCmd, MavResult
from swarmd.px4.messages import CommandAck, Heartbeat, VehicleCommand

LAND = VehicleCommand.make(MavCmd.NAV_LAND)


def drain(sender: CommandSender) -> list[SenderEvent]:
    return list(iter(sender.next_event, None))


def finished(events: list[SenderEvent]) -> list[CommandFinished]:
    return [e for e in events if isinstance(e, CommandFinished)]


def ack(command: int, result: int) -> CommandAck:
    return CommandAck(command, result, 0, 1, 191)


def test_accepted_finishes_at_once() -> None:
    s = CommandSender()
    handle = s.send(LAND, 0.0)
    sent = s.commands_to_send()
    assert [(c.command, c.confirmation) for c in sent] == [(MavCmd.NAV_LAND, 0)]
    assert s.get_timer() == 0.5
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 0.1)
    events = drain(s)
    assert [type(e) for e in events] == [CommandSent, AckReceived, CommandFinished]
    done = finished(events)[0]
    assert (done.handle, done.finish, done.result, done.sends) == (
        handle,
        Finish.ACCEPTED,
        MavResult.ACCEPTED,
        1,
    )
    assert done.ok and s.get_timer() is None and not s.pending(handle)


def test_no_ack_retransmits_with_confirmation_counts_then_gives_up() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    now = 0.0
    while (timer := s.get_timer()) is not None:
        now = timer
        s.handle_timer(now)
    assert [c.confirmation for c in s.commands_to_send()] == [0, 1, 2, 3]
    assert now == pytest.approx(2.0)  # 4 sends x 0.5 s
    done = finished(drain(s))[0]
    assert (done.finish, done.result, done.sends, done.cause) == (Finish.NO_ACK, None, 4, "no_ack")


def test_early_timer_call_is_harmless() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    s.commands_to_send()
    s.handle_timer(0.2)
    assert s.commands_to_send() == [] and s.get_timer() == 0.5


def test_in_progress_keeps_waiting() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.IN_PROGRESS), 0.2)
    assert s.get_timer() == pytest.approx(3.2)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 2.0)
    assert finished(drain(s))[0].finish is Finish.ACCEPTED
    assert len(s.commands_to_send()) == 1  # no retransmission while in progress


def test_temporarily_rejected_retries_later_from_the_same_budget() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    for i in range(4):
        s.observe(ack(MavCmd.NAV_LAND, MavResult.TEMPORARILY_REJECTED), s.get_timer() or 0.0)
        timer = s.get_timer()
        if timer is None:
            break
        assert i < 3
        s.handle_timer(timer)
    assert [c.confirmation for c in s.commands_to_send()] == [0, 1, 2, 3]
    done = finished(drain(s))[0]
    assert (done.finish, done.result, done.cause) == (
        Finish.REFUSED,
        MavResult.TEMPORARILY_REJECTED,
        "TEMPORARILY_REJECTED",
    )


def test_backoff_after_temporarily_rejected() -> None:
    s = CommandSender(SenderConfig(retry_backoff_s=1.5))
    s.send(LAND, 0.0)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.TEMPORARILY_REJECTED), 0.1)
    assert s.get_timer() == pytest.approx(1.6)


@pytest.mark.parametrize(
    "result", [MavResult.DENIED, MavResult.UNSUPPORTED, MavResult.FAILED, MavResult.CANCELLED]
)
def test_final_results_are_not_retried(result: MavResult) -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    s.observe(ack(MavCmd.NAV_LAND, result), 0.1)
    done = finished(drain(s))[0]
    assert (done.finish, done.result, done.cause) == (Finish.REFUSED, result, result.name)
    assert s.get_timer() is None and len(s.commands_to_send()) == 1


def test_an_undefined_result_number_is_final() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    s.observe(ack(MavCmd.NAV_LAND, 200), 0.1)
    assert finished(drain(s))[0].finish is Finish.REFUSED


def test_acks_for_other_commands_and_other_messages_are_ignored() -> None:
    s = CommandSender()
    s.send(LAND, 0.0)
    s.observe(ack(MavCmd.NAV_TAKEOFF, MavResult.ACCEPTED), 0.1)
    s.observe(Heartbeat(12, 2, 1, 0, 3), 0.1)
    assert finished(drain(s)) == [] and s.get_timer() == 0.5


def test_confirm_by_state_ends_retries() -> None:
    s = CommandSender()
    handle = s.send(LAND, 0.0)
    s.confirm(handle, 0.3, "mode AUTO.LAND")
    done = finished(drain(s))[0]
    assert (done.finish, done.why, done.ok) == (Finish.CONFIRMED, "mode AUTO.LAND", True)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 0.4)  # the late ack: nothing
    assert drain(s) == [] and s.get_timer() is None


def test_cancel_and_supersede() -> None:
    s = CommandSender()
    first = s.send(LAND, 0.0)
    second = s.send(LAND, 0.1)
    assert first != second
    assert [c.confirmation for c in s.commands_to_send()] == [0, 0]
    done = finished(drain(s))
    assert [(d.handle, d.finish) for d in done] == [(first, Finish.CANCELLED)]
    s.cancel(second, 0.2)
    assert [(d.handle, d.finish, d.cause) for d in finished(drain(s))] == [
        (second, Finish.CANCELLED, "cancelled")
    ]
    assert s.get_timer() is None


def test_two_command_numbers_run_side_by_side() -> None:
    s = CommandSender()
    land = s.send(LAND, 0.0)
    disarm = s.send(VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=0.0), 0.2)
    s.observe(ack(MavCmd.COMPONENT_ARM_DISARM, MavResult.ACCEPTED), 0.3)
    assert [d.handle for d in finished(drain(s))] == [disarm]
    assert s.pending(land) and s.get_timer() == 0.5


def test_a_budget_that_is_no_budget_is_refused() -> None:
    with pytest.raises(ValueError, match="retries"):
        CommandSender(SenderConfig(retries=-1))


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(
        st.tuples(st.sampled_from(["timer", "ack"]), st.integers(0, 255), st.floats(0, 1)),
        max_size=30,
    )
)
def test_any_ack_sequence_ends_in_one_finish_within_the_budget(
    steps: list[tuple[str, int, float]],
) -> None:
    """Whatever the autopilot answers, the sender never raises, never sends more than
    1 + retries times, and finishes each command exactly once."""
    s = CommandSender()
    s.send(LAND, 0.0)
    now = 0.0
    events: list[SenderEvent] = []
    for what, result, dt in steps:
        now += dt
        if what == "ack":
            s.observe(ack(MavCmd.NAV_LAND, result), now)
        else:
            s.handle_timer(max(now, s.get_timer() or now))
        events += drain(s)
    while (timer := s.get_timer()) is not None:  # let it run out
        s.handle_timer(timer)
    events += drain(s)
    assert len(s.commands_to_send()) <= 4
    assert len(finished(events)) == 1


# ---- answers still owed (command_sender docstring; docs/security.md, case 2) ----------------


def test_a_retransmissions_late_answer_pays_its_debt_and_not_the_next_command() -> None:
    """The first send's DENIED ends the command; the retransmission's DENIED, late, is owed
    and dropped; the next command's own answer is credited to it."""
    s = CommandSender()
    s.send(LAND, 0.0)
    s.handle_timer(0.5)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.DENIED), 0.6)
    later = s.send(LAND, 0.7)
    drain(s)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.DENIED), 0.71)  # the retransmission's
    assert drain(s) == [] and s.pending(later) and s.owed.paid == 1
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 0.72)  # the later one's own
    assert [(d.handle, d.finish) for d in finished(drain(s))] == [(later, Finish.ACCEPTED)]


def test_a_lost_debt_costs_at_most_one_retransmission() -> None:
    """The earlier command's answer never comes: its debt swallows the later command's first
    answer, but the retransmission forgets it, so the answer to that is credited."""
    s = CommandSender()
    s.send(LAND, 0.0)
    later = s.send(LAND, 0.1)  # supersedes: the first send is owed an answer
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 0.2)  # the later one's, swallowed
    assert s.pending(later)
    s.handle_timer(0.6)  # retransmission, confirmation 1
    s.observe(ack(MavCmd.NAV_LAND, MavResult.ACCEPTED), 0.7)
    assert [(d.handle, d.finish) for d in finished(drain(s))][-1] == (later, Finish.ACCEPTED)


def test_in_progress_pays_no_debt_and_is_not_credited_while_one_is_owed() -> None:
    s = CommandSender()
    first = s.send(LAND, 0.0)
    s.cancel(first, 0.1)
    later = s.send(LAND, 0.2)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.IN_PROGRESS), 0.21)  # the first one's progress
    assert s.owed.owes(MavCmd.NAV_LAND, 0.21) == 1 and s.get_timer() == pytest.approx(0.7)
    s.observe(ack(MavCmd.NAV_LAND, MavResult.DENIED), 0.22)  # its final answer
    s.observe(ack(MavCmd.NAV_LAND, MavResult.IN_PROGRESS), 0.23)  # the later one's
    assert s.get_timer() == pytest.approx(3.23) and s.pending(later)


def test_owed_answers_past_the_cap_are_pooled_and_forgotten_after_the_window() -> None:
    """More debts than ``MAX_OWED_PER_COMMAND`` on one number are kept as a count (memory
    bounded: the rest ride on one counter), each answer pays one, and all go when the
    window ends. The number cap evicts the oldest number (never reached by a vehicle)."""
    owed = OwedAcks(1.0)
    owed.owe(MavCmd.NAV_LAND, 10, 0.0)  # more than a command's 1 + 3 sends
    assert owed.owes(MavCmd.NAV_LAND, 0.5) == 10
    assert len(owed._owed[MavCmd.NAV_LAND].times) == MAX_OWED_PER_COMMAND
    assert owed.stats()["pooled"] == 10 - MAX_OWED_PER_COMMAND
    for _ in range(3):
        assert owed.pay(ack(MavCmd.NAV_LAND, MavResult.DENIED), 0.6)
    assert owed.owes(MavCmd.NAV_LAND, 0.6) == 7
    assert owed.owes(MavCmd.NAV_LAND, 1.0) == 0  # the window is over
    assert (owed.paid, owed.forgotten, owed.evicted) == (3, 7, 0)
    for command in range(MAX_OWED_COMMANDS + 3):
        owed.owe(command, 1, 2.0 + command / 100)
    assert sum(owed.owes(c, 2.2) for c in range(MAX_OWED_COMMANDS + 3)) == MAX_OWED_COMMANDS
    assert owed.owes(0, 2.2) == 0  # the oldest number went first
    assert owed.evicted == 3


def test_pooled_debts_expire_with_the_latest_of_them_and_before_the_kept_ones() -> None:
    """Two commands' debts, the second pushing the first's into the pool: the pool expires
    at the first's expiry, the kept ones at the second's; a retransmission forgets both."""
    owed = OwedAcks(1.0)
    owed.owe(MavCmd.NAV_LAND, 4, 0.0)  # until 1.0
    owed.owe(MavCmd.NAV_LAND, 4, 0.5)  # until 1.5: the first four pooled
    assert owed.owes(MavCmd.NAV_LAND, 0.9) == 8
    assert owed.owes(MavCmd.NAV_LAND, 1.0) == 4
    owed.forget(MavCmd.NAV_LAND)
    assert owed.owes(MavCmd.NAV_LAND, 1.1) == 0
    assert owed.forgotten == 8


_RESULTS = [
    MavResult.ACCEPTED,
    MavResult.IN_PROGRESS,
    MavResult.TEMPORARILY_REJECTED,
    MavResult.DENIED,
    MavResult.FAILED,
]


@settings(max_examples=300, deadline=None)
@given(
    steps=st.lists(
        st.tuples(
            st.sampled_from(["send", "timer", "tick", "deliver", "lose"]),
            st.sampled_from(_RESULTS),
            st.floats(0.0, 0.4),
        ),
        max_size=40,
    )
)
def test_stale_answers_are_never_credited_and_real_ones_lost_at_most_once(
    steps: list[tuple[str, MavResult, float]],
) -> None:
    """Random interleavings of sends (superseding), retransmissions (the timer), answers and
    losses on one command number over a FIFO link (MAVLink over UDP loopback or a UART keeps
    order; each transmission draws at most one answer). (1) An answer to an ended command's
    transmission is never credited to the pending command, as long as it comes within
    ``owed_window_s`` of that command's end, and no debt was let go (a retransmission, a
    cap) while such answers were still on the way: MAVLink cannot tell answers apart, so
    after that the count is off until they are through. (2) An answer to the pending
    command's retransmission is always credited to it: a lost answer costs at most one
    retransmission."""
    s = CommandSender()
    window = s.config.owed_window_s
    now = 0.0
    link: deque[tuple[int, int]] = deque()  # (handle, confirmation) in flight, FIFO
    pending: int | None = None
    ended: dict[int, float] = {}  # handle -> end time
    off = False  # a debt was let go while an ended command's answer was on the way
    evicted = 0

    def stale_in_flight() -> bool:
        return any(h in ended for h, _ in link)

    def collect() -> list[SenderEvent]:
        nonlocal pending, off, evicted
        events = drain(s)
        s.commands_to_send()
        for e in events:
            if isinstance(e, CommandSent):
                if e.confirmation > 0 and stale_in_flight():
                    off = True  # the retransmission forgot the debts
                link.append((e.handle, e.confirmation))
                pending = e.handle
            elif isinstance(e, CommandFinished):
                ended[e.handle] = now
                if pending == e.handle:
                    pending = None
        if s.owed.evicted > evicted:
            evicted, off = s.owed.evicted, True
        return events

    for what, result, dt in steps:
        if not stale_in_flight():
            off = False  # every ended command's answer is through: the count is right again
        if what == "send":
            s.send(LAND, now)
        elif what == "timer":
            now = max(now, s.get_timer() or now)
            s.handle_timer(now)
        elif what == "tick":
            now += dt
        elif link:
            handle, confirmation = link.popleft()
            if what == "lose":
                continue
            waiting = pending
            s.observe(ack(MavCmd.NAV_LAND, result), now)
            credited = [e for e in collect() if isinstance(e, AckReceived)]
            if handle != waiting and waiting is not None:
                if now < ended[handle] + window and not off:
                    assert credited == [], (handle, waiting)
            elif handle == waiting and confirmation > 0:
                assert [e.handle for e in credited] == [handle]
            continue
        collect()
