"""What a cell of the flight matrix says (``bench/wifi/flight_matrix.py``): the run files'
fields each measure reads, and the per-N tables (rows the scenarios, columns the
contenders). A cell is the median over that cell's **valid** runs with the range when there
are more than one (false losses, commands: their sum), "not run" without a run file,
"older runs only (n)" when its only run files are from before ``--since-commit`` (n of
them, which the matrix does not count: "not run" would read as never flown), "-" when no
valid run carries the measure (a stack without swarmd's commands or renewals).
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from bench.wifi.flight_measures import Q_MOVED_MIN, period_follows_q

Run = Mapping[str, Any]

SCENARIOS: Final = ("fly-out", "fade", "split", "reboot", "blackout")
SIZES: Final = (10, 20)
# (contender as the run files name it, column title): issue 20's contenders
COLUMNS: Final = (
    ("swarmd", "swarmd"),
    ("cyclonedds", "Cyclone DDS"),
    ("fastdds", "Fast DDS"),
    ("fastdds-server", "Discovery Server"),
    ("zenoh", "zenoh"),
    ("ros2", "ROS 2"),
    ("ros2-swarmd", "ROS 2 on swarmd"),  # the node's graph, its discovery from swarmd's relay
)
SWARMD: Final = "swarmd"


@dataclass(frozen=True, slots=True)
class RunFile:
    """One run record and where it was read from (the figure lies beside it)."""

    path: Path
    run: Run


@dataclass(frozen=True, slots=True)
class Measure:
    """A column of the issue's measures: how to read it from one run and how to show it."""

    title: str
    read: Callable[[Run], float | None]
    unit: str  # " s", " %", ""
    spec: str  # format of one value
    total: bool = False  # the sum over the valid runs, not their median
    note: Callable[[Sequence[Run]], str] | None = None  # after the value, from the runs
    # the cell's text from the valid runs that have the measure, instead of their median
    show: Callable[[Sequence[Run]], str] | None = None
    legend: str = ""  # after the table's title: what the cell holds, when it needs saying


def _m(run: Run) -> Mapping[str, Any]:
    measures: Mapping[str, Any] = run.get("measures") or {}
    return measures


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def _restarted(run: Run) -> bool:
    return bool(run.get("restarts"))


def loss_reported_p50(run: Run) -> float | None:
    return _num((_m(run).get("loss_latency_s") or {}).get("p50"))


def false_losses(run: Run) -> float | None:
    return _num(_m(run).get("false_losses"))


def rediscovery_p50(run: Run) -> float | None:
    """The p50 of the pairs found again after a reported loss; in a run without any and
    with a restart, of the peers' first sight of the new daemon life."""
    found = _m(run).get("rediscovery_s") or {}
    if found.get("count"):
        return _num(found.get("p50"))
    if _restarted(run):
        return _num((_m(run).get("reboot_seen_by_peers_s") or {}).get("p50"))
    return None


def rediscovery_max(run: Run) -> float | None:
    """The slowest pair found again: after a reported loss, and, in a run with a restart,
    either way after it (peers seeing the new life, the new life listing each peer);
    ``inf`` when a pair reported lost was never found again in the run."""
    if (_num(_m(run).get("not_rediscovered")) or 0) > 0:
        return math.inf
    keys = ["rediscovery_s"]
    if _restarted(run):
        keys += ["reboot_seen_by_peers_s", "reboot_finds_peers_s"]
    values = [_num((_m(run).get(k) or {}).get("max")) for k in keys]
    present = [v for v in values if v is not None]
    return max(present) if present else None


def frames_per_pair(run: Run) -> float | None:
    return _num((_m(run).get("frames_per_rejoining_pair") or {}).get("per_pair"))


# issue 20's readiness target, in percent (``flight_verdicts`` judges it)
READINESS_MIN_PCT: Final = 99.0
# the readiness spec: ".1f", but a value under the target is never rounded up onto it, so
# a run at 98.95 % reads 98.9 %, not the 99.0 % its verdict refuses (ROS 2 on swarmd's
# blackout at N = 20, 1,195 of 1,208: docs/benchmarks.md)
PCT_DOWN: Final = "down.1f"
# issue 20's re-discovery target, in seconds (``flight_verdicts`` judges it)
REDISCOVERY_MAX_S: Final = 2.0
# the re-discovery spec: ".2f", but a value over the target is never rounded down onto it,
# so 2.004 s reads 2.01 s, not the 2.00 s its verdict refuses
S_UP: Final = "up.2f"


def readiness(run: Run) -> float | None:
    ratio = _num((_m(run).get("readiness_delivery") or {}).get("ratio"))
    return None if ratio is None else 100.0 * ratio


def missed_note(runs: Sequence[Run]) -> str:
    """Real losses (a gap of at least the lease) that no ``lost`` reported, summed."""
    missed = sum(int(_num(_m(r).get("missed_losses")) or 0) for r in runs)
    return f", {missed} missed" if missed else ""


def never_note(runs: Sequence[Run]) -> str:
    """Pairs reported lost and never found again in the run, summed."""
    never = sum(int(_num(_m(r).get("not_rediscovered")) or 0) for r in runs)
    return f", {never} never found" if never else ""


# the command measures of a run (bench/wifi/flight_commands.py, ``measure``): those that
# must be 0 (issue 20, "Command authority in flight"), as the commands table shows them
COMMAND_FAULTS: Final = (
    ("executed_twice", "twice"),
    ("executed_late", "late"),
    ("unreached_not_reported", "unreached, not reported"),
    ("reported_unreachable_but_reachable", "reported unreachable while reachable"),
)
# shown after them when not 0: the delivery gap, a report of a run that did not happen,
# and the copies a restart voided (by design: exactly once first; docs/dataplane.md)
COMMAND_OTHERS: Final = (
    ("reachable_not_executed", "reachable, not run"),
    ("reported_ran_not_executed", "reported ran, not run"),
    ("restarted_not_resent", "voided by a restart"),
)


def run_commands(run: Run) -> Mapping[str, Any] | None:
    found = _m(run).get("commands")
    return found if isinstance(found, Mapping) else None


def command_faults(run: Run) -> float | None:
    """The (command, member) pairs that broke exactly-once, validity or the report of the
    unreachable, summed; None for a run without commands (a stack without swarmd's)."""
    c = run_commands(run)
    if c is None:
        return None
    return float(sum(int(_num(c.get(key)) or 0) for key, _ in COMMAND_FAULTS))


def command_sum(runs: Sequence[Run], key: str) -> int:
    """One command measure summed over ``runs`` (0 where a run has none)."""
    return sum(int(_num((run_commands(r) or {}).get(key)) or 0) for r in runs)


def commands_text(runs: Sequence[Run]) -> str:
    """issued / pairs / each of ``COMMAND_FAULTS``, summed over ``runs``; then each of
    ``COMMAND_OTHERS`` that is not 0."""
    keys = ["commands", "pairs", *(key for key, _ in COMMAND_FAULTS)]
    text = " / ".join(str(command_sum(runs, key)) for key in keys)
    others = [(command_sum(runs, key), what) for key, what in COMMAND_OTHERS]
    return text + "".join(f"; {k} {what}" for k, what in others if k)


def run_follows(run: Run) -> Mapping[str, Any] | None:
    found = _m(run).get("renewal_follows_q")
    return found if isinstance(found, Mapping) and found else None


def renewal_daemons(run: Run) -> float | None:
    """How many daemons' renewal periods were polled; None without (a stock stack)."""
    found = run_follows(run)
    return None if found is None else float(len(found))


def renewal_lowest_r(run: Run) -> float | None:
    """The lowest correlation of Q with the renewal period over the daemons whose Q moved by
    ``Q_MOVED_MIN`` or more (``flight_measures.period_follows_q``); None without one."""
    judged, _ = period_follows_q(run_follows(run) or {})
    return min(judged) if judged else None


def renewal_split(runs: Sequence[Run]) -> tuple[list[float], list[float]]:
    """Over ``runs``: the correlations of the daemons whose Q moved by ``Q_MOVED_MIN`` or
    more, and how far Q moved at the others (``flight_measures.period_follows_q``)."""
    judged: list[float] = []
    others: list[float] = []
    for r in runs:
        j, o = period_follows_q(run_follows(r) or {})
        judged += j
        others += o
    return judged, others


def renewal_text(runs: Sequence[Run]) -> str:
    """The correlations of the daemons whose Q moved (median and range), how many of the
    daemons polled; or that Q moved at none, and the largest move."""
    judged, others = renewal_split(runs)
    if not judged:
        return f"Q did not move (≤ {max(others, default=0.0):.2f})"
    return f"r {summary(judged, '.2f', '')}, {len(judged)} of {len(judged) + len(others)}"


MEASURES: Final = (
    Measure("loss reported, p50 of each run", loss_reported_p50, " s", ".1f", note=missed_note),
    Measure("false losses, sum over the valid runs", false_losses, "", ".0f", total=True),
    Measure("re-discovery p50", rediscovery_p50, " s", ".2f"),
    Measure("re-discovery max", rediscovery_max, " s", S_UP, note=never_note),
    Measure("discovery frames per rejoining pair", frames_per_pair, "", ".2f"),
    Measure("readiness delivery", readiness, " %", PCT_DOWN),
    Measure(
        "commands", command_faults, "", ".0f", show=commands_text,
        legend="issued / (command, member) pairs / run twice / run late / unreached, not "
        "reported / reported unreachable while reachable, summed over the valid runs; then, "
        "when not 0: reachable, not run; reported ran, not run; voided by a restart "
        "(`bench/wifi/flight_commands.py`); \"-\": the runs carry no commands (the stock "
        "stacks have no command path)",
    ),
    Measure(
        "renewal period follows Q", renewal_daemons, "", ".0f", show=renewal_text,
        legend=f"each daemon's Pearson r of its Q with its renewal period (status polls "
        f"after the first move): median (range) over the daemons whose Q moved by "
        f"≥ {Q_MOVED_MIN:g} (two of the engine's hysteresis steps; below, the period may "
        f"rightly stay put), of the daemons polled; \"Q did not move\": less at every "
        f"daemon (the largest move); \"-\": the runs have no renewal polls (a stock stack "
        f"has no renewal period to poll)",
    ),
)  # fmt: skip


# --- run files ------------------------------------------------------------------------


def read_run(path: Path) -> dict[str, Any]:
    """A run file's record; ``ValueError`` saying why when the file cannot be read or does
    not hold a JSON object (a file cut short, as a run being written is)."""
    try:
        run: object = json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # UnicodeDecodeError is a ValueError
        raise ValueError(f"cannot be read: {exc}") from exc
    if not isinstance(run, dict):
        raise ValueError(f"holds a JSON {type(run).__name__}, not a run record")
    return run


def commit(run: Run) -> str:
    return str((run.get("setup") or {}).get("commit") or "unknown")


# The contenders whose daemon is swarmd: its variants (bench/wifi/contenders.py,
# SWARMD_VARIANTS) and ROS 2 on swarmd (bench/wifi/flight_run.py, ROS2_ON_SWARMD: the rclpy
# node's discovery comes from swarmd's relay). Their runs measure swarmd's engine, so
# ``--since-commit`` applies to every one of them (tests/test_flight_campaign.py keeps this
# list equal to those two).
ON_SWARMD: Final = ("swarmd", "swarmd-paper", "swarmd-noaware", "swarmd-stock", "ros2-swarmd")

# (contender, the run file's commit) -> whether the run counts: ``Since`` by git history
# (flight_matrix.since_counts), or a stand-in in the tests
Counts = Callable[[str, str], bool]


@dataclass(frozen=True, slots=True)
class Since:
    """``--since-commit``: from which commit on the runs of each contender on swarmd count.

    ``default`` (``--since-commit C``) holds for every contender on swarmd: the engine as
    shipped. ``own`` (``--since-commit CONTENDER=C``) replaces it for that contender, for a
    change that only its runs go through: ROS 2 on swarmd after a fix to the relay's graph
    writer (swarmd/ros2/graph.py), which swarmd's own runs never touch. Name a commit at or
    after ``default``: the contender's daemon is still swarmd's engine. A stock stack has no
    since (``current``: its runs count at any commit)."""

    default: str | None = None
    own: tuple[tuple[str, str], ...] = ()  # (contender, commit), in ON_SWARMD's order

    def of(self, contender: str) -> str | None:
        """The commit from which ``contender``'s runs count; None: at any commit."""
        if contender not in ON_SWARMD:
            return None
        return dict(self.own).get(contender, self.default)

    def commits(self) -> list[str]:
        """Every commit named, each once, ``default`` first."""
        return list(dict.fromkeys(at for at in (self.default, *dict(self.own).values()) if at))

    def args(self) -> list[str]:
        """The ``--since-commit`` values that spell it (``parse_since`` reads them back)."""
        head = [] if self.default is None else [self.default]
        return head + [f"{c}={at}" for c, at in self.own]

    def __str__(self) -> str:
        return ", ".join(self.args())


def parse_since(values: Sequence[str]) -> Since | None:
    """``--since-commit`` values (repeatable) as one ``Since``: ``C`` at most once (every
    contender on swarmd), ``CONTENDER=C`` at most once per contender (that one); None when
    there are none. ``ValueError`` naming the value when a value names no commit, two
    defaults or a contender twice (which would hold?), or a contender not on swarmd (a stock
    stack's runs count at any commit: a since for it would be silently ignored)."""
    default: str | None = None
    own: dict[str, str] = {}
    for value in values:
        contender, named, at = value.rpartition("=")
        if not at or any(ch.isspace() for ch in at) or (named and not contender):
            raise ValueError(f"--since-commit {value!r}: not C or CONTENDER=C")
        if not named:
            if default is not None:
                raise ValueError(f"--since-commit {value}: a second default (also {default})")
            default = at
        elif contender not in ON_SWARMD:
            raise ValueError(
                f"--since-commit {value}: {contender!r} is not a contender on swarmd "
                f"({', '.join(ON_SWARMD)}); a stock stack's runs count at any commit"
            )
        elif contender in own:
            raise ValueError(f"--since-commit {value}: {contender} named twice")
        else:
            own[contender] = at
    if default is None and not own:
        return None
    return Since(default, tuple((c, own[c]) for c in ON_SWARMD if c in own))


def current(run: Run, counts: Counts | None) -> bool:
    """Whether the matrix reads ``run`` under ``--since-commit`` (``counts``: whether the
    run's contender counts at the run's commit, ``Since``; None: every run counts). A
    contender on swarmd counts only at such a commit; a stock stack always (its stack is the
    third-party package, the harness the same). The matrix and the campaign's plan share
    this rule."""
    contender = str(run.get("contender"))
    return counts is None or contender not in ON_SWARMD or counts(contender, commit(run))


def is_valid(run: Run) -> bool:
    """The run's own verdict (``valid``: flight_run's lag rule, ns-3's lag p99 within
    ``--max-lag-ms``): the one judge of validity, for the matrix and the campaign."""
    return run.get("valid") is True


def validity(run: Run) -> str:
    """``valid`` or ``INVALID (why)`` (the file's ``invalid_reason``), with its lag p99."""
    verdict = "valid" if is_valid(run) else f"INVALID ({run.get('invalid_reason')})"
    lag = _num(run.get("rt_lag_p99_ms"))
    return verdict if lag is None else f"{verdict}, lag p99 {lag:.2f} ms"


def dilation(run: Run) -> float:
    k = _num((run.get("setup") or {}).get("dilation"))
    return 1.0 if k is None else k


def beside(run: Run) -> int:
    """How many other testbed runs flew beside this one (``concurrent_runs``: flight_campaign
    --parallel); files from before the field, and solo runs, 0."""
    n = _num(run.get("concurrent_runs"))
    return 0 if n is None else int(n)


def started(run: Run) -> float | None:
    go = run.get("go") or {}
    return _num(go.get("harness_launch")) or _num(go.get("wall"))


def cell_runs(runs: Sequence[RunFile], scenario: str, contender: str, n: int) -> list[RunFile]:
    return [
        f
        for f in runs
        if f.run["scenario"] == scenario and f.run["contender"] == contender and f.run["n"] == n
    ]


def valid(files: Sequence[RunFile]) -> list[RunFile]:
    return [f for f in files if is_valid(f.run)]


# --- cells -----------------------------------------------------------------------------


def fmt(x: float, spec: str) -> str:
    if math.isinf(x):
        return "never"
    if spec == PCT_DOWN:
        text = f"{x:.1f}"
        return f"{math.floor(x * 10) / 10:.1f}" if x < READINESS_MIN_PCT <= float(text) else text
    if spec == S_UP:
        text = f"{x:.2f}"
        return f"{math.ceil(x * 100) / 100:.2f}" if x > REDISCOVERY_MAX_S >= float(text) else text
    return f"{x:{spec}}"


def summary(values: Sequence[float], spec: str, unit: str) -> str:
    """``median (min-max)``, or the one value."""
    mid = statistics.median(values)
    med = fmt(mid, spec) + ("" if math.isinf(mid) else unit)
    low, high = fmt(min(values), spec), fmt(max(values), spec)
    if low == high:
        return med
    return f"{med} ({low}-{high})"


def empty_cell(older: int) -> str:
    """A cell the matrix counts no run in: ``older`` run files of it left out as older than
    ``--since-commit`` (``current``), or none at all (module doc)."""
    return f"older runs only ({older})" if older else "not run"


def cell(files: Sequence[RunFile], measure: Measure, older: int = 0) -> str:
    """One measure over one cell's valid runs; ``older``: its run files left out as older
    (module doc)."""
    if not files:
        return empty_cell(older)
    ok = valid(files)
    if not ok:
        return f"no valid run (0/{len(files)})"
    values = [v for v in (measure.read(f.run) for f in ok) if v is not None]
    if not values:
        return "-"
    if measure.show is not None:
        text = measure.show([f.run for f in ok if measure.read(f.run) is not None])
    elif measure.total:
        text = f"{fmt(sum(values), measure.spec)}{measure.unit}"
    else:
        text = summary(values, measure.spec, measure.unit)
    if measure.note is not None:
        text += measure.note([f.run for f in ok])
    return text if len(values) == len(ok) else f"{text} [{len(values)}/{len(ok)}]"


def runs_cell(files: Sequence[RunFile], older: int = 0) -> str:
    if not files:
        return empty_cell(older)
    ks = sorted({dilation(f.run) for f in files})
    shared = sum(1 for f in files if beside(f.run) > 0)
    also = f"; {shared} beside another" if shared else ""
    return f"{len(valid(files))}/{len(files)} (k {'/'.join(f'{k:g}' for k in ks)}{also})"


def _table(rows: Sequence[Sequence[str]]) -> list[str]:
    head = ["scenario", *(title for _, title in COLUMNS)]
    return [
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
        *("| " + " | ".join(row) + " |" for row in rows),
    ]


def tables(runs: Sequence[RunFile], n: int, older: Sequence[RunFile] = ()) -> list[str]:
    """Markdown: the "runs" table and one table per measure at N (rows scenario, columns
    contender); ``older``: the run files left out as older than ``--since-commit``, which
    only name the cells they would fill (``empty_cell``)."""
    left = {(s, c): len(cell_runs(older, s, c, n)) for s in SCENARIOS for c, _ in COLUMNS}
    out = [f"**runs, valid/total (time dilation k)**, N = {n}:", ""]
    out += _table(
        [
            [s, *(runs_cell(cell_runs(runs, s, c, n), left[s, c]) for c, _ in COLUMNS)]
            for s in SCENARIOS
        ]
    )  # fmt: skip
    for measure in MEASURES:
        legend = f" {measure.legend}" if measure.legend else ""
        out += ["", f"**{measure.title}**, N = {n}:{legend}", ""]
        out += _table(
            [
                [s, *(cell(cell_runs(runs, s, c, n), measure, left[s, c]) for c, _ in COLUMNS)]
                for s in SCENARIOS
            ]
        )
    return out
