"""The reliable writer and reader, one submessage at a time on hand-set virtual time."""

from __future__ import annotations

import pytest

from swarmd.dataplane import writer as writer_module
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.reader import MAX_BUFFERED_SAMPLES, BestEffortReader, ReliableReader
from swarmd.dataplane.writer import (
    HEARTBEAT_PERIOD_S,
    MAX_HEARTBEAT_PERIOD_S,
    BestEffortWriter,
    ReliableWriter,
    first_sequence_number,
)
from swarmd.rtps import AckNack, Data, Gap, Heartbeat, SequenceNumberSet
from swarmd.rtps.types import EntityId, Guid, GuidPrefix

W = Guid(GuidPrefix(b"SW" + bytes(9) + b"\x00"), EntityId(b"\x00\x00\x02\x03"))
R = Guid(GuidPrefix(b"SW" + bytes(9) + b"\x01"), EntityId(b"\x00\x00\x02\x04"))
R2 = Guid(GuidPrefix(b"SW" + bytes(9) + b"\x02"), EntityId(b"\x00\x00\x02\x04"))
P = b"\x00\x01\x00\x00"  # an empty-bodied CDR_LE payload is enough for the protocol


def payload(i: int) -> bytes:
    return P + i.to_bytes(4, "little")


def data(sn: int) -> Data:
    return Data(R.entity_id, W.entity_id, sn, None, payload(sn))


def hb(first: int, last: int, count: int, final: bool = False) -> Heartbeat:
    return Heartbeat(R.entity_id, W.entity_id, first, last, count, final=final)


def acknack(base: int, missing: list[int], count: int) -> AckNack:
    return AckNack(R.entity_id, W.entity_id, SequenceNumberSet.of(base, missing), count)


def subs(out: list[Outgoing]) -> list[object]:
    return [o.submessage for o in out]


# --- reliable reader ------------------------------------------------------------------------


def test_reader_delivers_in_order_and_drops_duplicates() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    assert reader.on_data(W, data(2)).delivered == []
    assert reader.on_data(W, data(3)).delivered == []
    got = reader.on_data(W, data(1)).delivered
    assert [(d.sn, d.payload) for d in got] == [(1, payload(1)), (2, payload(2)), (3, payload(3))]
    assert reader.on_data(W, data(2)).dropped == "duplicate_sample"
    assert reader.on_data(W, data(3)).dropped == "duplicate_sample"
    assert reader.counters.delivered == 3 and reader.counters.duplicates == 2


def test_reader_acknacks_exactly_the_missing_set() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    for sn in (1, 3, 6):
        reader.on_data(W, data(sn))
    result = reader.on_heartbeat(W, hb(1, 7, count=1))
    (ack,) = subs(result.replies)
    assert isinstance(ack, AckNack)
    assert ack.reader_sn_state.base == 2 and ack.reader_sn_state.members() == [2, 4, 5, 7]
    assert ack.count == 1 and not ack.final
    assert (ack.reader_id, ack.writer_id) == (R.entity_id, W.entity_id)
    assert result.replies[0].peer == W.prefix


def test_reader_positive_ack_when_complete_and_silence_on_final_heartbeat() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    reader.on_data(W, data(1))
    (ack,) = subs(reader.on_heartbeat(W, hb(1, 1, count=1)).replies)
    assert isinstance(ack, AckNack)
    assert ack.reader_sn_state == SequenceNumberSet(2, 0, ()) and ack.final
    assert reader.on_heartbeat(W, hb(1, 1, count=2, final=True)).replies == []


def test_reader_ignores_a_reordered_old_heartbeat() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    reader.on_heartbeat(W, hb(1, 5, count=4))
    assert reader.on_heartbeat(W, hb(1, 3, count=2)).dropped == "stale_heartbeat"
    # a new writer life counts from 1 again but announces higher SNs: fresh
    fresh = reader.on_heartbeat(W, hb(2**32 + 1, 2**32 + 1, count=1))
    assert fresh.dropped is None and fresh.replies


def test_reader_moves_past_what_the_writer_no_longer_has() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    reader.on_data(W, data(4))
    reader.on_data(W, data(6))
    result = reader.on_heartbeat(W, hb(4, 6, count=1))
    assert [d.sn for d in result.delivered] == [4]
    (ack,) = subs(result.replies)
    assert isinstance(ack, AckNack) and ack.reader_sn_state.members() == [5]
    assert reader.counters.skipped == 3  # SNs 1..3 lost for good


def test_gap_advances_without_delivering() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    reader.on_data(W, data(5))
    gap = Gap(R.entity_id, W.entity_id, 1, SequenceNumberSet.of(3, [4]))  # 1, 2 and 4
    assert reader.on_gap(W, gap).delivered == []  # 3 still missing
    got = reader.on_data(W, data(3)).delivered
    assert [d.sn for d in got] == [3, 5]
    assert reader.counters.gapped == 3


def test_a_huge_gap_range_costs_nothing() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    far = Gap(R.entity_id, W.entity_id, 10, SequenceNumberSet.of(2**62, []))
    assert reader.on_gap(W, far).delivered == []
    assert reader.proxies[W].buffer == {}  # a future range too wide to mark is ignored


def test_reorder_buffer_is_capped_and_never_blocks_the_hole() -> None:
    reader = ReliableReader(R)
    reader.add_writer(W)
    top = MAX_BUFFERED_SAMPLES + 2
    for sn in range(3, top + 1):  # 64 samples above a hole at 1..2
        assert reader.on_data(W, data(sn)).dropped is None
    assert reader.on_data(W, data(top + 1)).dropped == "reorder_buffer_full"
    # a lower SN evicts the highest buffered one (it will be asked for again) ...
    assert reader.on_data(W, data(2)).dropped is None
    assert reader.counters.buffer_full == 2
    assert max(reader.proxies[W].buffer) == top - 1 and len(reader.proxies[W].buffer) == 64
    # ... and the SN that fills the hole is always taken
    got = reader.on_data(W, data(1)).delivered
    assert [d.sn for d in got] == list(range(1, top))


def test_best_effort_reader_keeps_only_newer_samples() -> None:
    reader = BestEffortReader(R)
    reader.add_writer(W)
    assert [d.sn for d in reader.on_data(W, data(3)).delivered] == [3]
    assert reader.on_data(W, data(2)).dropped == "stale_sample"
    assert reader.on_data(W, data(3)).dropped == "stale_sample"
    assert [d.sn for d in reader.on_data(W, data(7)).delivered] == [7]
    assert reader.on_heartbeat(W, hb(1, 7, 1)).replies == []


# --- reliable writer ------------------------------------------------------------------------


def test_write_pushes_data_with_a_piggybacked_heartbeat_to_every_reader() -> None:
    writer = ReliableWriter(W, depth=4)
    writer.add_reader(R, 0.0)
    writer.add_reader(R2, 0.0)
    sn, out = writer.write(payload(1), 1.0)
    assert sn == 1
    assert [(o.peer, type(o.submessage).__name__) for o in out] == [
        (R.prefix, "Data"),
        (R.prefix, "Heartbeat"),
        (R2.prefix, "Data"),
        (R2.prefix, "Heartbeat"),
    ]
    d, h = out[0].submessage, out[1].submessage
    assert isinstance(d, Data) and (d.reader_id, d.writer_id, d.writer_sn) == (
        R.entity_id,
        W.entity_id,
        1,
    )
    assert isinstance(h, Heartbeat) and (h.first_sn, h.last_sn) == (1, 1)
    assert writer.deadline() == 1.0 + HEARTBEAT_PERIOD_S


def test_unanswered_heartbeats_back_off_and_carry_the_lost_data_again() -> None:
    writer = ReliableWriter(W, depth=4)
    writer.add_reader(R, 0.0)
    writer.write(payload(1), 0.0)
    gaps: list[float] = []
    now = 0.0
    for _ in range(8):
        deadline = writer.deadline()
        assert deadline is not None
        gaps.append(round(deadline - now, 6))
        now = deadline
        out = subs(writer.on_timer(now))
        assert [type(s).__name__ for s in out] == ["Data", "Heartbeat"]  # eager repair
    assert gaps == [0.2, 0.2, 0.3, 0.45, 0.675, 1.0, 1.0, 1.0]
    assert max(gaps) == MAX_HEARTBEAT_PERIOD_S
    # a live reader answers: back to the short period, and nothing is pushed unasked
    writer.write(payload(2), now)
    assert writer.on_acknack(R, acknack(2, [], count=1), now) == []  # acks 1, has not seen 2
    assert writer.deadline() == now + HEARTBEAT_PERIOD_S
    assert [type(s).__name__ for s in subs(writer.on_timer(now + 0.2))] == ["Heartbeat"]
    assert writer.on_acknack(R, acknack(3, [], count=2), now + 0.3) == []
    assert writer.deadline() is None  # all acknowledged: silence


def test_acknack_is_answered_with_data_and_gap_for_evicted_samples() -> None:
    writer = ReliableWriter(W, depth=2)
    writer.add_reader(R, 0.0)
    for i in range(1, 5):
        writer.write(payload(i), 0.0)
    out = subs(writer.on_acknack(R, acknack(1, [1, 2, 3, 4], count=1), 0.5))
    datas = [s for s in out if isinstance(s, Data)]
    gaps = [s for s in out if isinstance(s, Gap)]
    assert [d.writer_sn for d in datas] == [3, 4]
    assert len(gaps) == 1 and gaps[0].gap_start == 1 and gaps[0].gap_list.base == 3
    assert isinstance(out[-1], Heartbeat) and (out[-1].first_sn, out[-1].last_sn) == (3, 4)
    assert writer.counters.data_resent == 2 and writer.counters.gaps_sent == 1


def test_duplicate_acknack_is_ignored_until_the_reader_looks_restarted() -> None:
    writer = ReliableWriter(W, depth=4)
    writer.add_reader(R, 0.0)
    writer.write(payload(1), 0.0)
    assert writer.on_acknack(R, acknack(1, [1], count=5), 0.1)
    assert writer.on_acknack(R, acknack(1, [1], count=5), 0.1) == []
    assert writer.counters.acknacks_stale == 1
    # the reader restarts, counting from 1: after a few unanswered heartbeats, resync
    now = 0.1
    for _ in range(3):
        now = writer.deadline() or now
        writer.on_timer(now)
    assert any(isinstance(s, Data) for s in subs(writer.on_acknack(R, acknack(1, [1], 1), now)))


def test_volatile_late_joiner_is_not_sent_older_samples() -> None:
    writer = ReliableWriter(W, depth=8)
    writer.add_reader(R, 0.0)
    writer.write(payload(1), 0.0)
    writer.write(payload(2), 0.0)
    assert writer.add_reader(R2, 1.0) == []
    out = subs(
        writer.on_acknack(
            R2, AckNack(R2.entity_id, W.entity_id, SequenceNumberSet.of(1, [1, 2]), 1), 1.0
        )
    )
    assert not any(isinstance(s, Data) for s in out)
    assert any(isinstance(s, Gap) for s in out)
    _, out3 = writer.write(payload(3), 2.0)
    (hb2,) = [
        o.submessage for o in out3 if o.peer == R2.prefix and isinstance(o.submessage, Heartbeat)
    ]
    assert hb2.first_sn == 3  # announces only what is relevant to it


def test_transient_local_late_joiner_is_offered_the_history_at_once() -> None:
    writer = ReliableWriter(W, depth=8, transient_local=True)
    writer.write(payload(1), 0.0)
    (h,) = subs(writer.add_reader(R, 5.0))
    assert isinstance(h, Heartbeat) and (h.first_sn, h.last_sn) == (1, 1)


def test_incarnation_moves_the_sequence_numbers_above_every_earlier_life() -> None:
    assert first_sequence_number(0) == 1
    writer = ReliableWriter(W, depth=1, incarnation=3)
    assert writer.write(payload(1), 0.0)[0] == (3 << 32) + 1
    assert BestEffortWriter(W, next_sn=first_sequence_number(3)).write(P, 0.0)[0] == (3 << 32) + 1
    with pytest.raises(ValueError, match="incarnation"):
        first_sequence_number(2**31)


# --- one sample, one copy per reader (docs/dataplane.md, "One copy per member") -------------


def _only(out: list[Outgoing], to: Guid, kind: type) -> list[object]:
    return [o.submessage for o in out if o.peer == to.prefix and isinstance(o.submessage, kind)]


def _payloads(out: list[Outgoing], to: Guid) -> list[bytes | None]:
    return [d.serialized_payload for d in _only(out, to, Data) if isinstance(d, Data)]


def test_a_sample_with_one_copy_per_reader_sends_each_its_own_and_gaps_the_rest() -> None:
    """R gets its copy under the one SN; R2, which the sample has no copy for, a GAP for
    that SN: on the write, on an ACKNACK asking for it, and on an eager resend."""
    w = ReliableWriter(W, depth=4)
    w.add_reader(R, 0.0)
    w.add_reader(R2, 0.0)
    mine = payload(7)
    sn, out = w.write({R.prefix: mine}, 0.0)
    (sent,) = _only(out, R, Data)
    assert isinstance(sent, Data) and (sent.writer_sn, sent.serialized_payload) == (sn, mine)
    assert _only(out, R2, Data) == []
    (gap,) = _only(out, R2, Gap)
    assert isinstance(gap, Gap) and gap.gap_start == sn and gap.gap_list.base == sn + 1
    assert w.counters.data_sent == 1 and w.counters.gaps_sent == 1
    # repair on request: R gets its copy again, R2 a GAP again
    again = w.on_acknack(R, acknack(sn, [sn], 1), 0.1)
    assert _payloads(again, R) == [mine]
    ask = AckNack(R2.entity_id, W.entity_id, SequenceNumberSet.of(sn, [sn]), 1)
    repair = w.on_acknack(R2, ask, 0.1)
    assert _only(repair, R2, Data) == [] and len(_only(repair, R2, Gap)) == 1
    # eager resend after an unanswered heartbeat: still each reader's own
    w.on_timer(0.3)
    eager = w.on_timer(1.0)
    assert _payloads(eager, R) == [mine]
    assert _only(eager, R2, Data) == []


# --- a reader lost and matched again (docs/dataplane.md, "Rejoining while a command is valid")


def test_a_reader_resumed_in_the_same_life_is_handed_what_was_written_for_it_meanwhile() -> None:
    """R acknowledged SN 1, was lost, SNs 2 (a copy for R) and 3 (none) were written; on
    its return R gets its copy of 2 at once and a GAP for 3, and never 1 again."""
    w = ReliableWriter(W, depth=8)
    w.add_reader(R, 0.0)
    w.add_reader(R2, 0.0)
    s1, _ = w.write({R.prefix: payload(1), R2.prefix: payload(1)}, 0.0)
    w.on_acknack(R, acknack(s1 + 1, [], 1), 0.1)
    w.remove_reader(R)
    s2, out2 = w.write({R.prefix: payload(2), R2.prefix: payload(2)}, 1.0)
    assert _only(out2, R, Data) == []  # lost: nothing goes to it
    s3, _ = w.write({R2.prefix: payload(3)}, 1.0)
    back = w.add_reader(R, 5.0, resume=True)
    (handed,) = _only(back, R, Data)
    assert isinstance(handed, Data) and (handed.writer_sn, handed.serialized_payload) == (
        s2,
        payload(2),
    )
    (gap,) = _only(back, R, Gap)
    assert isinstance(gap, Gap) and gap.gap_start == s3
    (beat,) = _only(back, R, Heartbeat)
    assert isinstance(beat, Heartbeat) and (beat.first_sn, beat.last_sn) == (s2, s3)
    assert w.counters.resumed == 1 and w.counters.handed_over == 1
    # a reader that reset its own proxy asks from 1: what it acknowledged is a GAP now
    repair = w.on_acknack(R, acknack(1, [s1, s2, s3], 2), 5.1)
    assert _payloads(repair, R) == [payload(2)]
    # once it acknowledges, the writer is quiet again
    w.on_acknack(R, acknack(s3 + 1, [], 3), 5.2)
    w.on_acknack(R2, acknack(s3 + 1, [], 1), 5.2)
    assert w.deadline() is None


def test_a_withdrawn_sample_is_not_handed_to_a_resumed_reader() -> None:
    """The owner withdraws a command at the end of its validity: a reader back after that
    is not sent it (the heartbeat moves it past)."""
    w = ReliableWriter(W, depth=8)
    w.add_reader(R, 0.0)
    w.remove_reader(R)
    sn, _ = w.write({R.prefix: payload(1)}, 1.0)
    assert w.withdraw(sn)
    back = w.add_reader(R, 40.0, resume=True)
    assert _only(back, R, Data) == []
    beats = _only(back, R, Heartbeat)
    assert all(isinstance(b, Heartbeat) and b.first_sn > sn for b in beats)


def test_a_reader_back_in_another_life_starts_afresh_and_its_missed_copies_are_named() -> None:
    w = ReliableWriter(W, depth=8)
    w.add_reader(R, 0.0)
    w.add_reader(R2, 0.0)
    acked, _ = w.write({R.prefix: payload(1)}, 0.0)
    w.on_acknack(R, acknack(acked + 1, [], 1), 0.1)
    w.remove_reader(R)
    mine, _ = w.write({R.prefix: payload(2)}, 1.0)
    w.write({R2.prefix: payload(3)}, 1.0)
    assert w.forget_reader(R) == [mine]  # unacked, addressed to R, still held
    assert w.forget_reader(R) == []  # forgotten once
    assert w.add_reader(R, 2.0, resume=True) == []  # no place kept: a new volatile reader
    assert w.forget_reader(R2) == []  # never lost


def test_lost_readers_kept_for_a_resume_are_capped(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(writer_module, "MAX_LOST_READERS", 1)
    w = ReliableWriter(W, depth=8)
    w.add_reader(R, 0.0)
    w.add_reader(R2, 0.0)
    w.remove_reader(R)
    w.remove_reader(R2)  # evicts R's kept place
    assert w.counters.lost_evicted == 1
    w.write({R.prefix: payload(1), R2.prefix: payload(1)}, 1.0)
    assert _only(w.add_reader(R, 2.0, resume=True), R, Data) == []  # afresh: volatile
    assert len(_only(w.add_reader(R2, 2.0, resume=True), R2, Data)) == 1
