"""``swarmd.auth.freshness`` and ``swarmd.auth.epoch``: counters only grow, replays are refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.auth.epoch import EpochError, epoch_path, next_epoch
from swarmd.auth.freshness import (
    U32_MAX,
    WINDOW,
    CounterExhausted,
    Freshness,
    ReplayWindow,
    SendCounter,
)


def test_freshness_orders_by_epoch_then_seq_and_packs_to_8_bytes() -> None:
    assert Freshness(1, 99) < Freshness(2, 1) < Freshness(2, 2)
    f = Freshness(0x01020304, 0xA0B0C0D0)
    assert f.pack() == bytes.fromhex("04030201d0c0b0a0")
    assert Freshness.unpack(f.pack()) == f
    with pytest.raises(ValueError, match="u32"):
        Freshness(U32_MAX + 1, 0)


def test_send_counter_starts_at_one_and_refuses_to_wrap() -> None:
    c = SendCounter(7)
    assert [c.next(), c.next()] == [Freshness(7, 1), Freshness(7, 2)]
    last = SendCounter(7, U32_MAX - 1)
    assert last.next() == Freshness(7, U32_MAX)
    with pytest.raises(CounterExhausted):
        last.next()


def test_window_refuses_replays_and_old_epochs_and_takes_reordering() -> None:
    w = ReplayWindow()
    assert w.is_fresh(Freshness(5, 10))
    assert w.accept(Freshness(5, 10))
    assert not w.is_fresh(Freshness(5, 10))  # replay
    assert not w.accept(Freshness(5, 10))
    assert w.is_fresh(Freshness(5, 9))  # late, inside the window, not seen
    assert w.accept(Freshness(5, 9)) and not w.is_fresh(Freshness(5, 9))
    assert w.accept(Freshness(5, 10 + WINDOW))
    assert not w.is_fresh(Freshness(5, 10))  # fell out of the window
    assert not w.is_fresh(Freshness(4, U32_MAX))  # an earlier life
    assert w.accept(Freshness(6, 1))  # restart: a new epoch
    assert not w.is_fresh(Freshness(5, 11 + WINDOW))
    assert w.high == Freshness(6, 1)


def test_is_fresh_changes_nothing() -> None:
    w = ReplayWindow()
    w.accept(Freshness(1, 5))
    for _ in range(3):
        assert w.is_fresh(Freshness(9, 9))
    assert w.high == Freshness(1, 5)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 200)), max_size=80))
def test_window_accepts_exactly_the_fresh_values(values: list[tuple[int, int]]) -> None:
    """Against a model: accepted iff never accepted before and not older than the window."""
    w = ReplayWindow()
    seen: set[Freshness] = set()
    high: Freshness | None = None
    for e, s in values:
        f = Freshness(e, s)
        if high is None or f > high:
            expect = True
        elif f.epoch < high.epoch or high.seq - f.seq >= WINDOW:
            expect = False
        else:
            expect = f not in seen
        assert w.is_fresh_at(e, s) == expect  # the verifier's check on the raw numbers
        assert w.accept(f) == expect
        if expect:
            seen.add(f)
            high = f if high is None or f > high else high


def test_epoch_uses_the_clock_when_the_file_is_missing(tmp_path: Path) -> None:
    r = next_epoch(tmp_path, "uav1", 1_800_000_000.7)
    assert r.epoch == 1_800_000_000 and r.stored is None and r.recovered_from is None
    assert epoch_path(tmp_path, "uav1").read_text() == "1800000000\n"


def test_epoch_grows_even_when_the_clock_goes_back(tmp_path: Path) -> None:
    assert next_epoch(tmp_path, "uav1", 1_800_000_000).epoch == 1_800_000_000
    again = next_epoch(tmp_path, "uav1", 1_000.0)  # clock reset to 1970
    assert again.epoch == 1_800_000_001 and again.stored == 1_800_000_000
    assert next_epoch(tmp_path, "uav1", 1_900_000_000).epoch == 1_900_000_000


def test_epoch_recovers_from_a_corrupt_file_and_reports_it(tmp_path: Path) -> None:
    epoch_path(tmp_path, "uav1").write_text("garbage")
    r = next_epoch(tmp_path, "uav1", 1_800_000_000)
    assert r.epoch == 1_800_000_000 and r.recovered_from is not None
    assert "corrupt" in r.recovered_from
    lost = next_epoch(tmp_path / "new", "uav1", 0.0)  # no file and no clock: reported
    assert lost.epoch == 1 and lost.recovered_from == "missing and no wall clock"


def test_epoch_exhausted_or_unwritable_is_one_line(tmp_path: Path) -> None:
    epoch_path(tmp_path, "uav1").write_text(f"{U32_MAX}\n")
    with pytest.raises(EpochError, match="exhausted"):
        next_epoch(tmp_path, "uav1", 0.0)
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(EpochError, match="cannot be written"):
        next_epoch(blocker / "sub", "uav1", 0.0)
