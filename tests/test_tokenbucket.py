"""swarmd.tokenbucket: the one bucket every budget is made of, on virtual time."""

from __future__ import annotations

from swarmd.tokenbucket import TokenBucket


def test_take_spends_the_burst_then_one_token_per_refill_interval() -> None:
    bucket = TokenBucket(rate=2.0, burst=3.0, now=0.0)
    assert [bucket.take(0.0) for _ in range(4)] == [True, True, True, False]
    assert bucket.take(0.4) is False  # 0.8 of a token
    assert bucket.take(0.5) is True  # one token at 0.5 s
    assert bucket.take(0.5) is False


def test_has_token_and_spend_decide_as_take_does() -> None:
    taking = TokenBucket(rate=1.0, burst=2.0, now=0.0)
    split = TokenBucket(rate=1.0, burst=2.0, now=0.0)
    times = [0.0, 0.0, 0.0, 0.3, 1.0, 1.0, 2.5, 2.6, 2.7, 9.0]
    taken = [taking.take(t) for t in times]
    decided = []
    for t in times:
        ok = split.has_token(t)
        if ok:
            split.spend()
        decided.append(ok)
    assert decided == taken
    # one of the burst's two tokens is left at 9.0; asking, however often, spends none
    assert [split.has_token(9.0) for _ in range(3)] == [True, True, True]
    split.spend()
    assert split.has_token(9.0) is False


def test_is_full_once_the_burst_is_back() -> None:
    bucket = TokenBucket(rate=1.0, burst=2.0, now=0.0)
    assert bucket.is_full(0.0)
    bucket.take(0.0)
    assert not bucket.is_full(0.5)
    assert bucket.is_full(1.0)


def test_a_bucket_of_seconds_spent_by_cost_runs_into_a_debt_the_refill_pays_first() -> None:
    """swarmd.senderuid's use: 0.1 s of work a second, each call spending what it cost."""
    bucket = TokenBucket(0.1, 0.05, now=0.0)
    assert bucket.balance(0.0) == 0.05
    bucket.spend(0.2)  # a dump that cost 0.2 s
    assert bucket.balance(0.0) < 0.0
    assert bucket.balance(1.0) < 0.0  # 1 s repays 0.1 of the 0.15 owed
    assert 0.0 < bucket.balance(2.0) <= 0.05
    assert bucket.balance(100.0) == 0.05  # never past the burst
