"""The campaign's scheduler (bench/wifi/flight_schedule.py): up to K dilated runs at once,
an undilated one always alone, driven by a fake runner on a virtual clock: no testbed, no
ns-3, no real time."""

from __future__ import annotations

import itertools
import json
import os
import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest

from bench.wifi import flight_campaign as fc
from bench.wifi import flight_schedule as fs


@dataclass
class Clock:
    now: float = 1_000_000.0
    on_sleep: Any = None

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        if self.on_sleep is not None:
            self.on_sleep()
        self.now += seconds


@dataclass
class FakeRun:
    """A flight_run stand-in: takes 90 % of its cell's estimate, then writes the run file
    (with the ``concurrent_runs`` flight_run would write) or exits 1 if told to fail."""

    cell: fc.Cell
    clock: Clock
    beside: int
    started: float
    code: int = 0
    returncode: int | None = None
    ended: float | None = None
    terminated: bool = False

    def poll(self) -> int | None:
        if self.returncode is None and self.clock.now >= self.started + 0.9 * self.cell.estimate_s:
            if self.code == 0:
                self.cell.path.parent.mkdir(parents=True, exist_ok=True)
                body = {"valid": True, "rt_lag_p99_ms": 0.1, "concurrent_runs": self.beside}
                self.cell.path.write_text(json.dumps(body))
            self.returncode, self.ended = self.code, self.clock.now
        return self.returncode

    def terminate(self) -> None:
        self.terminated = True
        if self.returncode is None:
            self.returncode, self.ended = -signal.SIGTERM, self.clock.now

    def wait(self, timeout: float | None = None) -> int:
        assert self.returncode is not None
        return self.returncode


@dataclass
class Runner:
    clock: Clock
    fail: tuple[str, ...] = ()
    runs: list[FakeRun] = field(default_factory=list)

    def __call__(self, cell: fc.Cell, beside: int) -> FakeRun:
        code = 1 if cell.contender in self.fail else 0
        run = FakeRun(cell, self.clock, beside, self.clock.now, code)
        self.runs.append(run)
        return run

    def overlapping(self) -> list[tuple[FakeRun, FakeRun]]:
        def end(r: FakeRun) -> float:
            return r.ended if r.ended is not None else float("inf")

        return [
            (a, b)
            for a, b in itertools.combinations(self.runs, 2)
            if a.started < end(b) and b.started < end(a)
        ]

    def most_at_once(self) -> int:
        return max(
            sum(1 for r in self.runs if r.started <= a.started < (r.ended or float("inf")))
            for a in self.runs
        )


def cells(tmp_path: Path, **kw: Any) -> list[fc.Cell]:
    return plan_of(tmp_path, **kw).cells


def plan_of(tmp_path: Path, **kw: Any) -> fc.Plan:
    args: dict[str, Any] = {
        "repeats": 1,
        "sizes": (10, 20),
        "scenarios": ("split", "blackout"),
        "contenders": ("swarmd", "cyclonedds", "fastdds", "zenoh"),
        "dilation": {10: 3.0, 20: 6.0},
        "swarmd_out": tmp_path / "seek",
        "stock_out": tmp_path / "stock",
    }
    args.update(kw)
    return fc.plan(**args)


def run(plan: list[fc.Cell], parallel: int, until_s: float = 1e6, **kw: Any) -> tuple[int, Runner]:
    clock = Clock()
    runner = Runner(clock, **kw)
    code = fs.run_cells(plan, clock.now + until_s, runner, parallel, clock=clock, sleep=clock.sleep)
    return code, runner


def test_an_undilated_cell_never_flies_beside_another(tmp_path: Path) -> None:
    code, runner = run(cells(tmp_path, repeats=2), parallel=2)
    assert code == 0
    pairs = runner.overlapping()
    assert pairs, "two dilated cells should have flown at once"
    for a, b in pairs:
        assert a.cell.dilated and b.cell.dilated, (a.cell.label(), b.cell.label())
    swarmd = [r for r in runner.runs if r.cell.contender == "swarmd"]
    assert len(swarmd) == 8 and all(r.beside == 0 for r in swarmd)


@pytest.mark.parametrize("parallel", [1, 2, 3])
def test_at_most_k_runs_fly_at_once_and_k_is_reached(tmp_path: Path, parallel: int) -> None:
    stock = cells(tmp_path, contenders=("cyclonedds", "fastdds", "zenoh"))
    code, runner = run(stock, parallel)
    assert code == 0
    assert runner.most_at_once() == parallel
    assert all(c.done for c in stock)


def test_no_cell_flies_twice_nor_beside_its_own_other_repeat(tmp_path: Path) -> None:
    plan = cells(tmp_path, repeats=3, sizes=(20,), scenarios=("split",),
                 contenders=("cyclonedds",))  # fmt: skip
    code, runner = run(plan, parallel=2)
    assert code == 0
    assert [r.cell.repeat for r in runner.runs] == [1, 2, 3]
    assert runner.overlapping() == []  # a free slot, but only the same cell left to fill it
    # a second campaign over the same plan finds every cell done and starts nothing
    again, second = run(plan, parallel=2)
    assert again == 0 and second.runs == []


def test_every_first_run_starts_before_any_second(tmp_path: Path) -> None:
    # N = 10 (k = 3) ends well before N = 20 (k = 6): a slot frees while repeat 1's swarmd
    # cells still wait to fly alone; repeat 2's dilated ones must not take it
    plan = cells(tmp_path, repeats=2, scenarios=("split",), contenders=("swarmd", "cyclonedds"))
    code, runner = run(plan, parallel=2)
    assert code == 0
    assert [r.cell.repeat for r in runner.runs] == [1] * 4 + [2] * 4


def test_a_replacement_for_an_invalid_first_run_flies_before_any_second_run(
    tmp_path: Path,
) -> None:
    """A cell whose r1 is invalid needs its first valid run: its r2 belongs to round 1 and
    flies before any cell's second run, though its number is 2."""
    kw: dict[str, Any] = {"repeats": 2, "sizes": (20,), "scenarios": ("split",),
                          "contenders": ("cyclonedds", "fastdds")}  # fmt: skip
    invalid = cells(tmp_path, **kw)[0]
    invalid.path.parent.mkdir(parents=True)
    invalid.path.write_text(json.dumps({"scenario": "split", "contender": "cyclonedds", "n": 20,
                                        "run": 1, "valid": False}))  # fmt: skip
    plan = cells(tmp_path, **kw)
    for parallel in (1, 2):
        for c in plan:
            c.path.unlink(missing_ok=True)
        code, runner = run(plan, parallel)
        assert code == 0
        flown = [(r.cell.contender, r.cell.repeat) for r in runner.runs]
        assert flown[:2] in (
            [("cyclonedds", 2), ("fastdds", 1)],
            [("fastdds", 1), ("cyclonedds", 2)],
        ), (parallel, flown)
        assert sorted(flown[2:]) == [("cyclonedds", 3), ("fastdds", 2)]


def test_until_holds_per_start(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = cells(tmp_path, sizes=(10,), scenarios=("blackout",))
    swarmd = next(c for c in plan if c.contender == "swarmd")
    stock = [c for c in plan if c.dilated]
    assert swarmd.estimate_s < 300 < min(c.estimate_s for c in stock)
    code, runner = run(plan, parallel=2, until_s=300)
    assert code == 0
    assert [r.cell for r in runner.runs] == [swarmd]
    assert not any(c.done for c in stock)
    assert capsys.readouterr().out.count("would end after --until") == len(stock)


def test_a_failing_run_does_not_stop_the_others(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = cells(tmp_path)
    code, runner = run(plan, parallel=2, fail=("zenoh",))
    assert code == 1
    assert len(runner.runs) == len(plan)
    assert all(c.done != (c.contender == "zenoh") for c in plan)
    out = capsys.readouterr().out
    assert out.count("no run file (exit 1)") == 4
    assert "valid, lag p99 0.10 ms" in out


def test_sigterm_stops_every_run_in_flight(tmp_path: Path) -> None:
    plan = cells(tmp_path, sizes=(20,), contenders=("cyclonedds", "fastdds"))
    clock = Clock()
    runner = Runner(clock)
    # the campaign gets SIGTERM while two runs fly (as `kill <campaign pid>` would)
    clock.on_sleep = lambda: os.kill(os.getpid(), signal.SIGTERM)
    before = signal.getsignal(signal.SIGTERM)
    code = fs.run_cells(plan, clock.now + 1e6, runner, 2, clock=clock, sleep=clock.sleep)
    assert code == 130
    assert len(runner.runs) == 2 and all(r.terminated for r in runner.runs)
    assert not any(c.done for c in plan)
    assert signal.getsignal(signal.SIGTERM) == before  # the caller's handler is back


def test_a_run_another_started_beside_later_records_it(tmp_path: Path) -> None:
    plan = cells(tmp_path, sizes=(20,), scenarios=("split",), contenders=("cyclonedds", "fastdds"))
    code, runner = run(plan, parallel=2)
    assert code == 0
    first, second = runner.runs
    assert (first.beside, second.beside) == (0, 1)
    # flight_run wrote 0 for the first (alone at its start); the campaign raised it
    for c in plan:
        assert json.loads(c.path.read_text())["concurrent_runs"] == 1


def test_the_plan_divides_only_the_dilated_hours_by_k(tmp_path: Path) -> None:
    plan = cells(tmp_path)
    alone = sum(c.estimate_s for c in plan if not c.dilated) / 3600
    beside = sum(c.estimate_s for c in plan if c.dilated) / 3600
    assert fc.hours_at_once(plan, 1) == pytest.approx(alone + beside)
    assert fc.hours_at_once(plan, 2) == pytest.approx(alone + beside / 2)
    assert "at up to 2 dilated at once" in fc.plan_lines(plan_of(tmp_path), 2)[0]
    assert "(one at a time)" in fc.plan_lines(plan_of(tmp_path))[0]
    argv = plan[1].argv("py", 1)
    assert argv[argv.index("--beside") + 1] == "1"
