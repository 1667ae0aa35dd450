"""The flight matrix as a campaign (issue 20): which cells still lack a run, what they cost,
and running them, one at a time or two dilated ones at once, until a deadline.

    .venv/bin/python -m bench.wifi.flight_campaign                     # the plan: what is missing
    .venv/bin/python -m bench.wifi.flight_campaign --json              # the same, for scripts
    sudo .venv/bin/python -m bench.wifi.flight_campaign --run --until 02:30 \\
        --repeats 1 --n 20 --contenders cyclonedds,fastdds,zenoh,ros2   # run what fits
    sudo .venv/bin/python -m bench.wifi.flight_campaign --run --until 08:00 --parallel 2

A cell is (N, scenario, contender), and ``--repeats R`` asks R **valid** runs of it, counted
as the matrix in docs/benchmarks.md counts them. Its run files are the names ``flight_run``
writes (``flight-<scenario>-<contender>-n<N>[-k<K>]-r<repeat>.json``, any k) in the
contender's directory: swarmd's in ``--swarmd-out``, every other contender's in
``--stock-out``; both are ``bench/results/flight-stagger`` by default, the runs under the
staggered start that the matrix reads (the lockstep runs before it: docs/flight-lockstep.md).
A file counts when the matrix would use it: valid by its own fields (``flight_cells.is_valid``,
the matrix's judge) and, for a contender whose daemon is swarmd (swarmd, ROS 2 on swarmd),
made at its ``--since-commit`` or after (``flight_cells.current`` and ``Since``, the matrix's
rule: a default and any contender's own, ``ros2-swarmd=C``; by default those that
docs/benchmarks.md's generated block names). Every other file is kept and
listed in the plan, not counted: invalid (the file's ``invalid_reason`` and lag p99), older
(its commit) or unreadable (why); the cell's next free repeat number is planned in its place.
A cell's missing runs are taken round by round (round r: a cell's r-th valid run, whatever
its file's number, so every cell's first valid run comes before any second one), then by N,
scenario and contender in the order given, so a campaign cut short leaves whole columns,
not scattered cells.

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
import itertools
import json
import re
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Final

from bench.wifi import flight, flight_matrix, flight_schedule
from bench.wifi.flight_cells import (
    Counts,
    Since,
    commit,
    current,
    is_valid,
    parse_since,
    read_run,
    validity,
)
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
DOCS: Final = REPO / "docs" / "benchmarks.md"  # its matrix block names --since-commit
# what a run file in a cell's place is to the plan; only VALID counts
VALID, INVALID, OLDER, UNREADABLE = "valid", "invalid", "older", "unreadable"


@dataclass(frozen=True)
class Cell:
    """One run of the matrix to fly: what it is, where its file goes, what it costs."""

    repeat: int  # the run file's number (flight_run --first-run): the cell's next free one
    n: int
    scenario: str
    contender: str
    k: float
    path: Path
    estimate_s: float
    round: int = 1  # which valid run of its cell it would be (1: its first; module doc)

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


@dataclass(frozen=True)
class Held:
    """A run file already in a cell's place, and how the matrix takes it."""

    repeat: int
    n: int
    scenario: str
    contender: str
    path: Path
    status: str  # VALID (counted), INVALID, OLDER (on swarmd, before --since-commit), UNREADABLE
    why: str  # its status and why: the file's validity fields, its commit, what is wrong

    @property
    def counted(self) -> bool:
        return self.status == VALID

    def label(self) -> str:
        return f"n={self.n} {self.scenario} {self.contender} r{self.repeat}"


@dataclass(frozen=True)
class Plan:
    """What the campaign found and what it would fly."""

    repeats: int  # valid runs wanted per cell
    size: int  # cells planned: sizes x scenarios x contenders
    cells: list[Cell]  # to fly, in campaign order (module doc)
    held: list[Held]  # every run file in a planned cell's place, counted or not
    since: Since | None  # --since-commit for the contenders on swarmd (None: every commit)

    def counted(self) -> int:
        """Valid runs the matrix would use, up to ``repeats`` per cell."""
        per_cell: dict[tuple[int, str, str], int] = {}
        for h in self.held:
            key = (h.n, h.scenario, h.contender)
            per_cell[key] = per_cell.get(key, 0) + h.counted
        return sum(min(self.repeats, k) for k in per_cell.values())


def judge(
    path: Path,
    repeat: int,
    n: int,
    scenario: str,
    contender: str,
    counts: Counts | None,
) -> Held:
    """A run file as the matrix would take it (module doc): the matrix's own rule and judge
    (``flight_cells.current``, ``is_valid``), not a second one."""

    def held(status: str, why: str) -> Held:
        return Held(repeat, n, scenario, contender, path, status, why)

    try:
        run = read_run(path)
    except ValueError as exc:
        return held(UNREADABLE, f"unreadable: {exc}")
    placed = (run.get("scenario"), run.get("contender"), run.get("n"), run.get("run"))
    if placed != (scenario, contender, n, repeat):
        return held(UNREADABLE, f"unreadable: holds {placed}, not the cell its name says")
    if not current(run, counts):
        return held(OLDER, f"older: made at {commit(run)}, before its --since-commit")
    return held(VALID if is_valid(run) else INVALID, validity(run))


def held_files(
    names: Sequence[Path],
    n: int,
    scenario: str,
    contender: str,
    counts: Counts | None,
) -> list[Held]:
    """The run files among ``names`` in the cell's place (any k), by repeat, judged."""
    pattern = re.compile(
        rf"flight-{re.escape(scenario)}-{re.escape(contender)}-n{n}(?:-k[0-9.]+)?-r([0-9]+)\.json"
    )
    found = [(int(m[1]), p) for p in names if (m := pattern.fullmatch(p.name))]
    return [judge(p, r, n, scenario, contender, counts) for r, p in sorted(found)]


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
    counts: Counts | None = None,
    since: Since | None = None,
) -> Plan:
    """The run files in every cell's place, and the runs that would bring each cell to
    ``repeats`` valid ones, in campaign order (module doc); ``counts``: whether a run on
    swarmd counts at its commit (``flight_matrix.since_counts(since)``; None: every
    commit)."""
    listing: dict[Path, list[Path]] = {}
    held: list[Held] = []
    cells: list[Cell] = []
    for n in sizes:
        for s in scenarios:
            for c in contenders:
                k = 1.0 if c == SWARMD else dilation.get(n, 1.0)
                runs = (swarmd_out if c == SWARMD else stock_out) / "runs"
                if runs not in listing:
                    listing[runs] = sorted(runs.glob("flight-*.json"))
                mine = held_files(listing[runs], n, s, c, counts)
                held += mine
                taken = {h.repeat for h in mine}
                free = (r for r in itertools.count(1) if r not in taken)
                for wanted in range(sum(h.counted for h in mine) + 1, repeats + 1):
                    r = next(free)
                    path = runs / run_file_name(s, c, n, r, k)
                    cells.append(Cell(r, n, s, c, k, path, estimate_s(s, n, c, k), wanted))
    cells.sort(key=lambda c: c.round)  # stable: N, scenario, contender within a round
    size = len(sizes) * len(scenarios) * len(contenders)
    return Plan(repeats, size, cells, held, since)


def hours_at_once(cells: Sequence[Cell], parallel: int) -> float:
    """The cells' hours at up to ``parallel`` at once: the dilated ones' sum divided by it,
    the undilated ones' added whole (they fly alone)."""
    alone = sum(c.estimate_s for c in cells if not c.dilated)
    beside = sum(c.estimate_s for c in cells if c.dilated)
    return (alone + beside / max(1, parallel)) / 3600


def plan_lines(p: Plan, parallel: int = 1) -> list[str]:
    todo = [c for c in p.cells if not c.done]
    at_once = (
        "one at a time"
        if parallel <= 1
        else f"about {hours_at_once(todo, parallel):.1f} h at up to {parallel} dilated at once"
    )
    since = f"runs on swarmd from {p.since} on" if p.since else "runs of every commit"
    if p.since is not None and p.since.own:
        own = ", ".join(f"{c} from {at} on" for c, at in p.since.own)
        head = f"runs on swarmd from {p.since.default} on; " if p.since.default else ""
        since = f"{head}{own}"
    lines = [
        f"flight campaign: {p.counted()} of {p.repeats * p.size} valid runs counted "
        f"({p.repeats} in each of {p.size} cells; {since}); {len(todo)} to run, about "
        f"{sum(c.estimate_s for c in todo) / 3600:.1f} h of runs ({at_once})"
    ]
    kept = [h for h in p.held if not h.counted]
    if kept:
        lines.append(
            f"  kept, not counted: {len(kept)} run file(s) (the matrix leaves them out; a cell "
            "short of valid runs gets its next free repeat)"
        )
        for h in kept:
            lines.append(f"    {h.label():34} {h.why}  {h.path.name}")
    for wave in sorted({c.round for c in todo}):
        mine = [c for c in todo if c.round == wave]
        lines.append(
            f"  round {wave}: {len(mine)} to run, {minutes(sum(c.estimate_s for c in mine))}"
        )
        for c in mine:
            lines.append(f"    {c.label():40} ~{minutes(c.estimate_s):>7}  {c.path.name}")
    return lines


def plan_rows(p: Plan) -> list[dict[str, Any]]:
    """The plan as JSON rows: each run file found (``status`` valid, invalid, older or
    unreadable; ``done`` true), then each run to fly (``status`` "to run")."""
    rows: list[dict[str, Any]] = [
        {**asdict(h), "path": str(h.path), "done": True, "counted": h.counted} for h in p.held
    ]
    rows += [
        {**asdict(c), "path": str(c.path), "status": "to run", "done": c.done, "counted": False}
        for c in p.cells
    ]
    return rows


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
    p.add_argument(
        "--since-commit", metavar="[CONTENDER=]C", action="append", default=[],
        help="count the runs on swarmd (swarmd, ROS 2 on swarmd) made at C or after it, and "
        "CONTENDER's at its own C (repeatable), as flight_report --matrix does; default: "
        "those docs/benchmarks.md's matrix block names; 'any': every commit",
    )  # fmt: skip
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
    if "any" in args.since_commit and args.since_commit != ["any"]:
        p.error("--since-commit any: alone (every commit counts)")
    try:
        since = (
            parse_since([v for v in args.since_commit if v != "any"])
            if args.since_commit
            else flight_matrix.documented_since(DOCS)
        )
        counts = flight_matrix.since_counts(since, REPO)
    except ValueError as exc:
        p.error(str(exc))
    found = plan(
        args.repeats, sizes, scenarios, contenders, dilation, args.swarmd_out, args.stock_out,
        counts, since,
    )  # fmt: skip
    if args.json:
        print(json.dumps(plan_rows(found)))
    else:
        print("\n".join(plan_lines(found, args.parallel)))
    if not args.run:
        return 0
    if args.until is None:
        p.error("--run needs --until HH:MM (every campaign is bounded in time)")
    try:
        until = parse_until(args.until, dt.datetime.now())
    except ValueError:
        p.error(f"--until: {args.until!r} is not HH:MM")
    return run_cells(found.cells, until, sys.executable, args.parallel)


if __name__ == "__main__":
    with reader_may_close_stdout():
        code = main()
    raise SystemExit(code)
