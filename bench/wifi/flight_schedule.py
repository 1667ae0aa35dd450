"""Which campaign cells fly when (``flight_campaign --run [--parallel K]``).

The rules, in order (docs/testbed.md, "Two runs at a time"):

- Round by round: no cell of round r + 1 starts while a cell of round r waits, so every
  cell's first valid run comes before any second one. A cell's round is which of its valid
  runs it would be (``Cell.round``), not its file's repeat number: a cell whose first run
  was invalid flies its replacement (repeat 2) in round 1.
- At most ``parallel`` runs at once, and only **dilated** ones side by side: a dilated run
  (k > 1) spends most of its real time waiting on its slowed clock, so two leave ns-3 room
  to keep up; an undilated run (swarmd, k = 1) needs both cores (session 11: anything
  CPU-heavy beside it made it invalid), so it starts only when nothing runs, and nothing
  starts beside it.
- Never two runs of the same (N, scenario, contender) at once.
- With ``parallel`` > 1 the longest cells of a round go first (they pack better; the short
  undilated ones, last, run alone); with 1 the plan's order is kept.
- ``until`` holds per start: a cell whose estimate would end after it is skipped.

Time, the child processes and the pause between polls are injected, so the tests drive the
rules with a fake runner on a virtual clock (tests/test_flight_schedule.py).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, Final, Protocol

from bench.wifi.flight_cells import read_run, validity

if TYPE_CHECKING:
    from bench.wifi.flight_campaign import Cell

POLL_S: Final = 5.0  # real seconds between looks at the runs in flight
SLACK_S: Final = 600.0  # timeout past a run's estimate before it is stopped
STOP_WAIT_S: Final = 120.0  # flight_run removes its testbed on SIGTERM within this


class Child(Protocol):
    """What the scheduler needs of a run's process (``subprocess.Popen`` has it)."""

    @property
    def returncode(self) -> int | Any: ...

    def poll(self) -> int | None: ...

    def terminate(self) -> None: ...

    def wait(self, timeout: float | None = None) -> int: ...


Launch = Callable[["Cell", int], Child]  # (cell, runs already in flight) -> its process


@dataclass
class _Flying:
    cell: Cell
    child: Child
    started: float
    beside: int  # other runs in flight at its start (flight_run --beside)
    most: int  # the most other runs in flight at once while it ran


class _Stop(Exception):
    pass


def _raise_stop(signum: int, frame: FrameType | None) -> None:
    raise _Stop


def minutes(seconds: float) -> str:
    return f"{seconds / 60:.0f} min"


def _key(c: Cell) -> tuple[int, str, str]:
    return (c.n, c.scenario, c.contender)


def may_start(c: Cell, flying: Sequence[Cell], parallel: int) -> bool:
    """Whether ``c`` may start beside the runs in flight (module doc)."""
    if not flying:
        return True
    if len(flying) >= parallel or not c.dilated or not all(f.dilated for f in flying):
        return False
    return all(_key(f) != _key(c) for f in flying)


def _outcome(c: Cell, code: int | None) -> str:
    """The end line's verdict: validity and lag p99 from the run file (the matrix's judge,
    ``flight_cells.validity``), else why none."""
    if code != 0 or not c.done:
        return f"no run file (exit {code})"
    try:
        return validity(read_run(c.path))
    except ValueError as exc:
        return f"run file unreadable: {exc}"


def note_concurrency(path: Path, most: int) -> None:
    """Raise the run file's ``concurrent_runs`` to ``most`` when another run started after
    it (flight_run only knew the runs in flight at its own start)."""
    try:
        r = read_run(path)
    except ValueError:
        return
    if int(r.get("concurrent_runs") or 0) >= most:
        return
    r["concurrent_runs"] = most
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(r) + "\n")
    tmp.replace(path)


def popen_launch(python: str, cwd: Path) -> Launch:
    def launch(c: Cell, beside: int) -> Child:
        return subprocess.Popen(c.argv(python, beside), cwd=cwd)

    return launch


def run_cells(
    cells: Sequence[Cell],
    until: float,
    launch: Launch,
    parallel: int = 1,
    *,
    clock: Callable[[], float] = time.time,
    sleep: Callable[[float], None] = time.sleep,
) -> int:
    """Run the missing cells that fit before ``until``, up to ``parallel`` at once (module
    doc); 0 if every run started wrote its file, 1 if one did not, 130 if stopped (SIGTERM
    or ^C: every run in flight is terminated, which removes its testbed)."""
    todo = [c for c in cells if not c.done]
    if parallel > 1:  # longest first within a round (stable: the plan's order on ties)
        todo.sort(key=lambda c: (c.round, -c.estimate_s))
    number = {id(c): i for i, c in enumerate(todo, 1)}
    flying: list[_Flying] = []
    failed = 0
    previous = signal.signal(signal.SIGTERM, _raise_stop)

    def say(text: str) -> None:
        print(f"{time.strftime('%H:%M:%S', time.localtime(clock()))} {text}", flush=True)

    try:
        while todo or flying:
            for f in [f for f in flying if f.child.poll() is not None]:
                flying.remove(f)
                if f.most > f.beside and f.cell.done:
                    note_concurrency(f.cell.path, f.most)
                code = f.child.returncode
                failed += code != 0 or not f.cell.done
                say(f"end   {f.cell.label()}: {_outcome(f.cell, code)}")
            for f in flying:
                if clock() > f.started + f.cell.estimate_s + SLACK_S:
                    say(f"stop  {f.cell.label()}: past its estimate by {SLACK_S:.0f} s")
                    f.child.terminate()
                    f.child.wait(timeout=STOP_WAIT_S)
            wave = todo[0].round if todo else 0
            for c in [c for c in todo if c.round == wave]:
                now = clock()
                if now + c.estimate_s > until:
                    todo.remove(c)
                    say(f"[{number[id(c)]}/{len(number)}] skip {c.label()}: "
                        f"~{minutes(c.estimate_s)} would end after --until")  # fmt: skip
                    continue
                if not may_start(c, [f.cell for f in flying], parallel):
                    continue
                todo.remove(c)
                beside = len(flying)
                flying.append(_Flying(c, launch(c, beside), now, beside, beside))
                for f in flying:
                    f.most = max(f.most, len(flying) - 1)
                say(f"[{number[id(c)]}/{len(number)}] start {c.label()} "
                    f"(~{minutes(c.estimate_s)}, beside {beside})")  # fmt: skip
            if flying:
                sleep(POLL_S)
    except (KeyboardInterrupt, _Stop):
        for f in flying:
            f.child.terminate()
        for f in flying:
            f.child.wait(timeout=STOP_WAIT_S)
        print(f"flight campaign: stopped; the {len(flying)} run(s) under way were removed",
              file=sys.stderr)  # fmt: skip
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 1 if failed else 0
