"""A failed save told, then a later write that holds it: the commander's mark clears
(session 15; docs/dataplane.md, "A failed save").

Until session 15 a member whose state-file write failed re-sent that decision's outcome
flagged ``OUTCOME_NOT_SAVED`` and the commander's row said ``save_failed`` for the rest of
the session, even after a later write on the member held the decision (a false alarm). Now
the member tells that too: the decision's outcome once more, flagged
``OUTCOME_NOW_SAVED``, and every mark or clear carries ``save_gen``, the member's count of
state-file writes answered in its life. The commander applies a word only if it is newer
than the last one it applied, so an older mark repeated, replayed or overtaken cannot set
the row again after the clear.

Virtual time on the swarm cores (``tests.test_cmd_in_flight.Flight``); the member's disk
is played by answering each ``PersistExecuted`` as ``SwarmApp._persist`` does. The
attacks: a replay of the flagged datagrams after the clear (refused by the replay window,
nothing moves), the same older marks sent again below the MAC (ignored: older than the
clear), a forged clear (no pair key: ``auth_failed``, counted, the mark stays) and
delivery reordered and duplicated by the network.
"""

from __future__ import annotations

import random
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from swarmd_lab.memnet import Channel

from swarmd.auth.freshness import Freshness
from swarmd.dataplane.reader import ReliableReader
from swarmd.dataplane.seal import TAG_BYTES, seal, user_data_key
from swarmd.dataplane.types import (
    OUTCOME_NOT_SAVED,
    OUTCOME_NOW_SAVED,
    CommandKind,
    CommandOutcome,
    CommandResult,
    encode_sample,
)
from swarmd.rtps import Data, Header, encode_message
from swarmd.rtps.types import PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, EntityId
from swarmd.swarm.commander import CommandTracker
from swarmd.swarm.events import OutcomeRecorded, OutcomeReported
from tests.test_cmd_in_flight import Flight, _issue
from tests.test_cmd_restart import replay_at_lead
from tests.test_cmd_save_failed import KINDS, _issued_onto_a_full_disk, _row
from tests.test_dataplane_swarm import address_of, keyring

OUT_W, OUT_R = EntityId.user(3, 0x03), EntityId.user(3, 0x04)


def _told(flight: Flight, cid: int) -> list[tuple[CommandResult, bool]]:
    """What m01 sent for ``cid``: (result, saved) in order."""
    events = flight.swarm.events["m01"]
    return [(e.result, e.saved) for e in events if isinstance(e, OutcomeReported)]


def _recorded(flight: Flight, cid: int) -> list[tuple[CommandResult, bool]]:
    events = flight.swarm.events["lead"]
    return [
        (e.result, e.saved)
        for e in events
        if isinstance(e, OutcomeRecorded) and e.command_id == cid
    ]


@pytest.mark.parametrize("freed", ["mid_task", "next_command"])
@pytest.mark.parametrize("kind", KINDS)
def test_a_later_write_that_holds_the_decision_clears_the_commanders_mark(
    kind: CommandKind, freed: str
) -> None:
    """m01's writes fail from the command on; the row is marked. Then the disk has room
    again: while the task runs (its COMPLETED is the first write that succeeds) or after
    it (the next command's write). Either way that write held the whole record, so m01
    tells the commander and the row's mark goes; the command ran once."""
    flight, disk, cid = _issued_onto_a_full_disk(80, kind)
    swarm = flight.swarm
    swarm.run(0.3)  # answered, the task still running (the played vehicle takes 1 s)
    assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == ("accepted", True)
    if freed == "mid_task":
        disk["full"] = False
        swarm.run(5.0)
    else:
        swarm.run(5.0)
        assert (_row(flight, cid)["state"], _row(flight, cid)["save_failed"]) == (
            "completed",
            True,
        )
        disk["full"] = False
        _issue(swarm, CommandKind.HOLD)
        swarm.run(5.0)
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", False), row
    assert len(flight.ran("m01", cid)) == 1
    m01 = swarm.cores["m01"]
    assert m01.executor_counters["told_not_saved"] == 1
    assert m01.executor_counters["told_saved"] == 1
    ran = {r["command_id"]: r["saved"] for r in m01.request_outcomes({}, swarm.net.now)["ran"]}
    assert ran[cid] is True
    # the last word on this decision was the clear, and the commander took it
    assert _recorded(flight, cid)[-1] == (CommandResult.COMPLETED, True)
    assert (CommandResult.COMPLETED, True) in _told(flight, cid)


def _cleared(seed: int) -> tuple[Flight, int, list[bytes], int]:
    """A HOLD issued onto m01's full disk, marked, then cleared by the next command's
    write; every datagram m01 sent the commander until the clear was sent, as an attacker
    on the air records them; m01's ``save_gen`` before the clear (every mark's is at most
    that)."""
    flight, disk, cid = _issued_onto_a_full_disk(seed, CommandKind.HOLD)
    swarm = flight.swarm
    swarm.run(5.0)
    assert _row(flight, cid)["save_failed"] is True
    lead_addr = address_of(swarm.bundle, "lead")
    captured = [
        t.payload
        for t in swarm.net.transmissions
        if t.node == swarm.ids["m01"] and t.target == lead_addr
    ]
    gen_before = swarm.cores["m01"].member._save_gen
    disk["full"] = False
    _issue(swarm, CommandKind.HOLD)
    swarm.run(5.0)
    assert _row(flight, cid)["save_failed"] is False
    return flight, cid, captured, gen_before


def test_a_replay_of_the_flagged_outcome_after_the_clear_does_not_set_it_again() -> None:
    """The attacker replays, after the clear, every datagram m01 sent the commander while
    the HOLD was unsaved (its ACCEPTED, the flagged ACCEPTED and COMPLETED, their
    repairs): each is refused by the replay window or is a sample already delivered; no
    outcome is recorded and the row stays cleared."""
    flight, cid, captured, _ = _cleared(81)
    recorded = _recorded(flight, cid)
    moved = replay_at_lead(flight.swarm, captured)
    assert moved["dropped_auth_replayed"] >= 1, moved
    assert moved["dropped_auth_replayed"] + moved["rx_authenticated"] == len(captured), moved
    assert _recorded(flight, cid) == recorded
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", False)


def test_an_older_mark_sent_again_under_the_mac_is_older_than_the_clear() -> None:
    """Below the MAC (a member's repeat, or a replay the window let through): m01's plane
    sends the marks it sent before the clear again, as new samples, at their old
    ``save_gen``. The same word is a duplicate; the same generation on another result is
    news to the dedup but older than the clear: the row stays cleared. A newer mark (a
    new failure) does set it again, and a clear at the same generation as that mark
    does not lift it."""
    flight, cid, _, gen_before = _cleared(82)
    swarm = flight.swarm
    m01 = swarm.cores["m01"].plane
    assert m01 is not None

    def send(result: CommandResult, flags: int, gen: int) -> None:
        swarm.call(
            "m01",
            lambda now: m01.report_outcome(
                cid, result, now, commander="lead", flags=flags, save_gen=gen
            ),
        )
        swarm.run(0.5)

    for result in (CommandResult.ACCEPTED, CommandResult.COMPLETED, CommandResult.FAILED):
        for gen in range(gen_before + 1):
            send(result, OUTCOME_NOT_SAVED, gen)
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", False), row
    newest = swarm.cores["m01"].member._save_gen
    send(CommandResult.COMPLETED, OUTCOME_NOT_SAVED, newest + 1)
    assert _row(flight, cid)["save_failed"] is True
    send(CommandResult.COMPLETED, OUTCOME_NOW_SAVED, newest + 1)
    assert _row(flight, cid)["save_failed"] is True
    send(CommandResult.COMPLETED, OUTCOME_NOW_SAVED, newest + 2)
    assert _row(flight, cid)["save_failed"] is False


def _outcome_datagram(flight: Flight, outcome: CommandOutcome, *, seq: int, forged: bool) -> bytes:
    """A DATA carrying ``outcome`` from m01's outcome writer at the commander's next
    expected SN, with m01's epoch and a fresh sequence (all public); sealed under the pair
    key, or (``forged``) with a tag the attacker had to guess."""
    swarm = flight.swarm
    bundle = swarm.bundle
    m01, lead = bundle.participant("m01"), bundle.participant("lead")
    plane = swarm.lead.plane
    assert plane is not None
    reader = plane._endpoints.readers[OUT_R][1]
    assert isinstance(reader, ReliableReader)
    writer = m01.guid(next(e for e in m01.endpoints if e.topic == "swarm/outcome"))
    sn = reader.proxies[writer].next_expected
    data = Data(OUT_R, OUT_W, sn, None, encode_sample(outcome))
    message = encode_message(
        Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, m01.guid_prefix), [data]
    )
    key = keyring(bundle, "m01").pair_key(lead.guid_prefix)
    assert key is not None
    good = seal(user_data_key(key), message, Freshness(1, seq), lead.guid_prefix, 1)
    if not forged:
        return good
    return good[:-TAG_BYTES] + random.Random(seq).randbytes(TAG_BYTES)


def test_a_forged_clear_is_dropped_and_counted() -> None:
    """m01's disk stays full, its row is marked. An outsider sends the commander a clear
    in m01's name (``OUTCOME_NOW_SAVED`` at the highest generation) with everything public
    right and a guessed tag: refused ``auth_failed`` and counted before anything is
    decoded; the mark stays. The control: the same datagram sealed under the pair key
    (what only m01 can make) does clear it, so the assertion can fail."""
    flight, _, cid = _issued_onto_a_full_disk(83, CommandKind.HOLD)
    swarm = flight.swarm
    swarm.run(5.0)
    assert _row(flight, cid)["save_failed"] is True
    plane = swarm.lead.plane
    assert plane is not None
    clear = CommandOutcome(cid, "m01", CommandResult.COMPLETED, "", OUTCOME_NOW_SAVED, 2**32 - 1)
    source = address_of(swarm.bundle, "m01")
    before = plane.counters.copy()
    recorded = _recorded(flight, cid)
    forged = _outcome_datagram(flight, clear, seq=100_000, forged=True)
    swarm.lead.receive_datagram(forged, source, swarm.net.now)
    moved = plane.counters - before
    assert moved["dropped_auth_failed"] == 1, moved
    assert _recorded(flight, cid) == recorded
    assert _row(flight, cid)["save_failed"] is True
    genuine = _outcome_datagram(flight, clear, seq=100_001, forged=False)
    swarm.lead.receive_datagram(genuine, source, swarm.net.now)
    assert _row(flight, cid)["save_failed"] is False


@pytest.mark.parametrize("seed", range(84, 90))
def test_reordered_and_duplicated_delivery_never_sets_the_mark_after_the_clear(
    seed: int,
) -> None:
    """The network reorders (2-52 ms one way), duplicates (30 %) and drops (20 %) every
    datagram. m01's writes fail for a TAKEOFF and succeed again while it runs. From the
    moment the commander took the clear, the row never says ``save_failed`` again, and it
    ends cleared; the command ran once."""
    flight, disk, cid = _issued_onto_a_full_disk(seed, CommandKind.TAKEOFF)
    swarm = flight.swarm
    swarm.net.channel = Channel(loss=0.2, duplicate=0.3, delay_s=0.002, jitter_s=0.05)
    trace: list[bool] = []

    def observe(node_id: int, now: float) -> None:
        row = swarm.lead.request_outcomes({"command_id": cid}, now)["nodes"]["m01"]
        trace.append(bool(row["save_failed"]))

    swarm.net.after_input = observe
    swarm.run(0.4)
    disk["full"] = False
    swarm.run(15.0)
    assert swarm.net.stats.reordered > 0
    row = _row(flight, cid)
    assert (row["state"], row["save_failed"]) == ("completed", False), row
    assert True in trace  # it was marked
    last_mark = max(i for i, marked in enumerate(trace) if marked)
    assert not any(trace[last_mark + 1 :])
    recorded = _recorded(flight, cid)
    cleared_at = max(i for i, (_, saved) in enumerate(recorded) if saved)
    assert all(saved for _, saved in recorded[cleared_at:])
    assert len(flight.ran("m01", cid)) == 1


# the words a member says on one decision's record: (result, mark, save_gen); a mark at a
# generation may repeat on another result (ACCEPTED and COMPLETED flagged before a write is
# answered), a clear is one per generation
words = st.lists(st.booleans(), min_size=1, max_size=6).flatmap(
    lambda marks: st.permutations(
        [
            (result, mark, gen)
            for gen, mark in enumerate(marks, 1)
            for result in (
                (CommandResult.ACCEPTED, CommandResult.COMPLETED)
                if mark
                else (CommandResult.COMPLETED,)
            )
        ]
    ).flatmap(lambda order: st.tuples(st.just(order), st.lists(st.sampled_from(order), max_size=6)))
)


@given(words)
def test_the_newest_word_on_the_record_wins_in_any_order(
    delivery: tuple[list[tuple[CommandResult, bool, int]], list[Any]],
) -> None:
    """Unit: the tracker given a member's marks and clears in any order, with repeats:
    the row ends with the newest word (the highest ``save_gen``), and once that word is in,
    no older one moves it."""
    order, repeats = delivery
    tracker = CommandTracker()
    tracker.sent(1, "hold", ["m01"], 0.0, valid_for_s=5.0, epochs={"m01": 1})
    newest = max(order, key=lambda w: w[2])
    seen_newest = False
    for step, (result, mark, gen) in enumerate([*order, *repeats]):
        tracker.record(
            1,
            "m01",
            result,
            "",
            0.1 * step,
            epoch=1,
            not_saved=mark,
            now_saved=not mark,
            save_gen=gen,
        )
        seen_newest = seen_newest or gen == newest[2]
        row = tracker.snapshot(1, 0.1 * step)["nodes"]["m01"]  # type: ignore[index]
        if seen_newest:
            assert row["save_failed"] is newest[1]
    row = tracker.snapshot(1, 10.0)["nodes"]["m01"]  # type: ignore[index]
    assert row["save_failed"] is newest[1]


def test_a_session_14_members_mark_still_marks_and_a_clear_without_a_generation_is_ignored() -> (
    None
):
    """Unit, mixed builds: a session-14 member flags at ``save_gen`` 0 (it has no such
    field) and never clears: the row is marked as before. A clear at generation 0 has no
    order to check against: ignored."""
    tracker = CommandTracker()
    tracker.sent(1, "hold", ["m01"], 0.0, valid_for_s=5.0, epochs={"m01": 1})
    tracker.record(1, "m01", CommandResult.ACCEPTED, "", 0.1, epoch=1, not_saved=True)
    assert tracker.snapshot(1, 0.2)["nodes"]["m01"]["save_failed"] is True  # type: ignore[index]
    tracker.record(1, "m01", CommandResult.COMPLETED, "", 0.3, epoch=1, now_saved=True)
    assert tracker.snapshot(1, 0.4)["nodes"]["m01"]["save_failed"] is True  # type: ignore[index]
