"""The flight matrix as a campaign (issue 20): which cells still lack a run, what they cost,
and running them, one at a time or two dilated ones at once, until a deadline.

    .venv/bin/python -m bench.wifi.flight_campaign                     # the plan: what is missing
    .venv/bin/python -m bench.wifi.flight_campaign --json              # the same, for scripts
    sudo .venv/bin/python -m bench.wifi.flight_campaign --run --until 02:30 \\
        --repeats 1 --n 20 --contenders cyclonedds,fastdds,zenoh,ros2   # run what fits
    sudo .venv/bin/python -m bench.wifi.flight_campaign --run --until 08:00 --parallel 2

A cell is (repeat, N, scenario, contender); its run file is the name ``flight_run`` writes
(``flight-<scenario>-<contender>-n<N>[-k<K>]-r<repeat>.json``) in the contender's directory:
swarmd's in ``--swarmd-out``, every other contender's in ``--stock-out``; both are
``bench/results/flight-stagger`` by default, the runs under the staggered start that the
matrix in docs/benchmarks.md reads (the lockstep runs before it: docs/flight-lockstep.md).
A cell whose file exists is done, whatever its validity (the matrix counts invalid runs as
such; a rerun is a new repeat). Cells are taken repeat by repeat (every cell's first run
before any second one), then by N, scenario and contender in the order given, so a campaign
cut short leaves whole columns, not scattered cells.

Each run is ``python -m bench.wifi.flight_run`` for one cell, bounded by a timeout. By
default one at a time (the runs share the two cores); ``--parallel 2`` flies two dilated
cells side by side, never an undilated one beside anything (``bench/wifi/flight_schedule.py``
has the rules; docs/testbed.md, "Two runs at a time", the lag they cost). Each run gets
``--beside B`` (runs already in flight at its start) and its file keeps it as
``concurrent_runs``, raised when another started during it. The estimate of a
run's real time is ``(scenario + the stock peers' tail) x k + OVERHEAD_S``: the dilated
window is nearly all of it (a Cyclone DDS split at N = 20, k = 6: 930 s estimated, 951 s
taken). A cell whose estimate would end after ``--until`` is skipped and the next, shorter
one tried. The time dilation k per contender and N is the testbed's: swarmd undilated (it
has no boot flood to follow), the others 3 at N = 10 and 6 at N = 20 (docs/benchmarks.md
"Time dilation": at k = 4 zenoh and Fast DDS lagged at N = 20).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Final

from bench.wifi import flight, flight_schedule
from bench.wifi.flight_run import (
    FLIGHT_CONTENDERS,
    PEER_OBSERVED,
    PEER_TAIL_S,
    REPO,
    run_file_name,
)
from bench.wifi.flight_schedule import minutes
from bench.wifi.run import parse_dilation
from swarmd.cli.pipes import reader_may_close_stdout

SWARMD: Final = "swarmd"
# the matrix's contenders, in its column order (bench/wifi/flight_matrix.py)
CONTENDERS: Final = (
    "swarmd", "cyclonedds", "fastdds", "fastdds-server", "zenoh", "ros2", "ros2-swarmd",
)  # fmt: skip
SIZES: Final = (10, 20)
DILATED_K: Final = "10:3,20:6"  # every contender but swarmd (module doc)
OVERHEAD_S: Final = 60.0  # namespaces, start-up, the barrier, assembling the run file
SWARMD_OUT: Final = REPO / "bench" / "results" / "flight-stagger"
STOCK_OUT: Final = SWARMD_OUT


@dataclass(frozen=True)
class Cell:
    """One run of the matrix: what it is, where its file goes, what it costs."""

    repeat: int
    n: int
    scenario: str
    contender: str
    k: float
    path: Path
    estimate_s: float

    @property
    def done(self) -> bool:
        return self.path.exists()

    @property
    def dilated(self) -> bool:
        """Whether it may fly beside another run (flight_schedule)."""
        return self.k > 1.0

    def argv(self, python: str, beside: int = 0) -> list[str]:
        return [
            python, "-m", "bench.wifi.flight_run", "--scenarios", self.scenario,
            "--n", str(self.n), "--first-run", str(self.repeat), "--contenders",
            self.contender, "--dilation", f"{self.k:g}", "--out", str(self.path.parents[1]),
            "--beside", str(beside),
        ]  # fmt: skip

    def label(self) -> str:
        return f"n={self.n} {self.scenario} {self.contender} r{self.repeat} k={self.k:g}"


def estimate_s(scenario: str, n: int, contender: str, k: float) -> float:
    """Real seconds one run takes (module doc)."""
    tail = PEER_TAIL_S if contender in PEER_OBSERVED else 0.0
    return (flight.make(scenario, n).duration_s + tail) * k + OVERHEAD_S


def plan(
    repeats: int,
    sizes: Sequence[int],
    scenarios: Sequence[str],
    contenders: Sequence[str],
    dilation: dict[int, float],
    swarmd_out: Path,
    stock_out: Path,
) -> list[Cell]:
    """Every cell, in campaign order (module doc)."""
    out = []
    for repeat in range(1, repeats + 1):
        for n in sizes:
            for s in scenarios:
                for c in contenders:
                    k = 1.0 if c == SWARMD else dilation.get(n, 1.0)
                    where = swarmd_out if c == SWARMD else stock_out
                    path = where / "runs" / run_file_name(s, c, n, repeat, k)
                    out.append(Cell(repeat, n, s, c, k, path, estimate_s(s, n, c, k)))
    return out


def hours_at_once(cells: Sequence[Cell], parallel: int) -> float:
    """The cells' hours at up to ``parallel`` at once: the dilated ones' sum divided by it,
    the undilated ones' added whole (they fly alone)."""
    alone = sum(c.estimate_s for c in cells if not c.dilated)
    beside = sum(c.estimate_s for c in cells if c.dilated)
    return (alone + beside / max(1, parallel)) / 3600


def plan_lines(cells: Sequence[Cell], parallel: int = 1) -> list[str]:
    todo = [c for c in cells if not c.done]
    at_once = (
        "one at a time"
        if parallel <= 1
        else f"about {hours_at_once(todo, parallel):.1f} h at up to {parallel} dilated at once"
    )
    lines = [
        f"flight campaign: {len(cells) - len(todo)} of {len(cells)} cells have a run file; "
        f"{len(todo)} missing, about {sum(c.estimate_s for c in todo) / 3600:.1f} h of runs "
        f"({at_once})"
    ]
    for repeat in sorted({c.repeat for c in todo}):
        mine = [c for c in todo if c.repeat == repeat]
        lines.append(
            f"  repeat {repeat}: {len(mine)} missing, {minutes(sum(c.estimate_s for c in mine))}"
        )
        for c in mine:
            lines.append(f"    {c.label():40} ~{minutes(c.estimate_s):>7}  {c.path.name}")
    return lines


def parse_until(text: str, now: dt.datetime) -> float:
    """``HH:MM`` (today, or tomorrow if already past, in the machine's local time) as epoch
    seconds."""
    hour, _, minute = text.partition(":")
    at = now.replace(hour=int(hour), minute=int(minute), second=0, microsecond=0)
    if at <= now:
        at += dt.timedelta(days=1)
    return at.timestamp()


def run_cells(cells: Sequence[Cell], until: float, python: str, parallel: int = 1) -> int:
    """Run the missing cells that fit before ``until`` (``flight_schedule.run_cells``), each
    as ``python -m bench.wifi.flight_run``; 0, 1 if a run wrote no file, 130 if stopped."""
    launch = flight_schedule.popen_launch(python, REPO)
    return flight_schedule.run_cells(cells, until, launch, parallel)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--repeats", type=int, default=3, help="repeats per cell (default 3)")
    p.add_argument("--n", default=",".join(map(str, SIZES)), help="sizes (default 10,20)")
    p.add_argument("--scenarios", default=",".join(flight.SCENARIOS))
    p.add_argument("--contenders", default=",".join(CONTENDERS))
    p.add_argument("--dilation", default=DILATED_K, help="N:K for every contender but swarmd")
    p.add_argument("--swarmd-out", type=Path, default=SWARMD_OUT)
    p.add_argument("--stock-out", type=Path, default=STOCK_OUT)
    p.add_argument("--json", action="store_true", help="the plan as JSON")
    p.add_argument("--run", action="store_true", help="run the missing cells (root)")
    p.add_argument("--until", help="with --run: start no run that would end after HH:MM")
    p.add_argument(
        "--parallel", type=int, default=1, metavar="K",
        help="with --run: up to K dilated runs at once; an undilated one always alone",
    )  # fmt: skip
    args = p.parse_args(argv)
    scenarios = [s for s in args.scenarios.split(",") if s]
    contenders = [c for c in args.contenders.split(",") if c]
    for s in scenarios:
        if s not in flight.SCENARIOS:
            p.error(f"--scenarios: unknown {s!r}; use {', '.join(flight.SCENARIOS)}")
    for c in contenders:
        if c not in FLIGHT_CONTENDERS:
            p.error(f"--contenders: {c!r} has no flight observer; use {', '.join(CONTENDERS)}")
    try:
        sizes = [int(x) for x in args.n.split(",") if x]
        spec = parse_dilation(args.dilation)
    except ValueError:
        p.error("--n: sizes as 10,20; --dilation: N:K,N:K")
    dilation = dict(spec) if isinstance(spec, tuple) else dict.fromkeys(sizes, spec)
    if args.repeats < 1:
        p.error("--repeats: at least 1")
    if args.parallel < 1:
        p.error("--parallel: at least 1")
    cells = plan(
        args.repeats, sizes, scenarios, contenders, dilation, args.swarmd_out, args.stock_out
    )
    if args.json:
        print(json.dumps([{**asdict(c), "path": str(c.path), "done": c.done} for c in cells]))
    else:
        print("\n".join(plan_lines(cells, args.parallel)))
    if not args.run:
        return 0
    if args.until is None:
        p.error("--run needs --until HH:MM (every campaign is bounded in time)")
    try:
        until = parse_until(args.until, dt.datetime.now())
    except ValueError:
        p.error(f"--until: {args.until!r} is not HH:MM")
    return run_cells(cells, until, sys.executable, args.parallel)


if __name__ == "__main__":
    with reader_may_close_stdout():
        code = main()
    raise SystemExit(code)
