"""The flight matrix (issue 20, "Done when"): every scenario for every contender at N = 10
and 20, summarised from the run files alone, swarmd's targets judged, a figure per cell.

    .venv/bin/python -m bench.wifi.flight_report --matrix RUNS... [--since-commit C] \\
        [--write-docs docs/benchmarks.md]

``RUNS`` are run files (``flight_run``'s ``runs/*.json``) or directories holding them (a
directory's ``runs/`` when it has one). Per N, one table per measure: rows the scenarios,
columns the contenders; a cell is the median over that cell's **valid** runs with the range
when there are more than one (false losses: their sum), "not run" without a run file, and
invalid runs are counted in the "runs" table but enter no median, sum or verdict.

Which swarmd runs count: ``--since-commit C`` keeps the swarmd runs whose ``setup.commit``
is C or a descendant of it (the engine as shipped: name the last commit that changed
``swarmd/``, ``git log -1 --format=%h -- swarmd/``); older swarmd runs are left out and
listed by commit. Without it, every swarmd run passed counts (name the directories of the
engine as shipped). The stock stacks' runs are never filtered by commit: their stacks are
the third-party packages, the harness the same.

``--write-docs FILE`` rewrites the lines between ``BEGIN`` and ``END`` in FILE (the
"Flight" section of docs/benchmarks.md), naming the command that generated them, and the
run files' commits and dates; nothing outside the markers changes. Without the markers, the
block is put after the "## Flight" heading's intro (before its first "###").
"""

from __future__ import annotations

import math
import statistics
import subprocess
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from bench.docblock import write_block

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

# issue 20's targets for swarmd
FALSE_LOSSES_MAX: Final = 0
REDISCOVERY_MAX_S: Final = 2.0
FRAMES_PER_PAIR_MAX: Final = 4.0
READINESS_MIN: Final = 0.99
# the scenarios with a heal (a return after a gap every rejoining pair shares); fade's
# window runs from the drone's first return to its last re-discovery, the whole fade with
# every renewal in it, and reboot has no rejoining pairs: the frames target is not theirs
HEALS: Final = frozenset({"fly-out", "split", "blackout"})

BEGIN: Final = "<!-- flight-matrix:begin (python -m bench.wifi.flight_report --matrix) -->"
END: Final = "<!-- flight-matrix:end -->"
SECTION: Final = "## Flight (issue 20)"


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


@dataclass(frozen=True, slots=True)
class Verdict:
    """One of issue 20's targets for swarmd at one scenario and N: met (True), not met
    (False) or not known from these runs (None), and the sentence with the numbers."""

    target: str
    scenario: str
    n: int
    met: bool | None
    text: str
    reason: str = ""  # why not known: "no run", ...


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


MEASURES: Final = (
    Measure("loss reported, p50 of each run", loss_reported_p50, " s", ".1f", note=missed_note),
    Measure("false losses, sum over the valid runs", false_losses, "", ".0f", total=True),
    Measure("re-discovery p50", rediscovery_p50, " s", ".2f"),
    Measure("re-discovery max", rediscovery_max, " s", ".2f", note=never_note),
    Measure("discovery frames per rejoining pair", frames_per_pair, "", ".2f"),
    Measure("readiness delivery", readiness, " %", ".1f"),
)


# --- which runs ------------------------------------------------------------------------


def load(paths: Iterable[Path]) -> list[RunFile]:
    """Every run file named, or held in a named directory (its ``runs/`` if it has one)."""
    import json

    out: list[RunFile] = []
    for path in paths:
        if path.is_dir():
            folder = path / "runs" if (path / "runs").is_dir() else path
            files = sorted(folder.glob("*.json"))
        else:
            files = [path]
        out.extend(RunFile(f, json.loads(f.read_text())) for f in files)
    return out


def commit(run: Run) -> str:
    return str((run.get("setup") or {}).get("commit") or "unknown")


def dilation(run: Run) -> float:
    k = _num((run.get("setup") or {}).get("dilation"))
    return 1.0 if k is None else k


def started(run: Run) -> float | None:
    go = run.get("go") or {}
    return _num(go.get("harness_launch")) or _num(go.get("wall"))


def git_descends(since: str, repo: Path) -> Callable[[str], bool]:
    """Whether a run file's commit (``+dirty`` dropped) is ``since`` or a descendant of it,
    by the repository's history; a commit the repository does not know does not count."""
    cache: dict[str, bool] = {}

    def check(made_by: str) -> bool:
        sha = made_by.split("+", 1)[0]
        if sha not in cache:
            done = subprocess.run(
                ["git", "-C", str(repo), "merge-base", "--is-ancestor", since, sha],
                capture_output=True,
                check=False,
            )
            cache[sha] = done.returncode == 0
        return cache[sha]

    return check


@dataclass(frozen=True, slots=True)
class Selection:
    """The runs the matrix reads, and those it leaves out (with why)."""

    runs: list[RunFile]
    older_swarmd: list[RunFile]  # swarmd runs before ``--since-commit``
    outside: list[RunFile]  # N or contender not in the matrix
    duplicates: int


def select(files: Sequence[RunFile], counts: Callable[[str], bool] | None) -> Selection:
    """The matrix's runs: N in ``SIZES``, a contender of ``COLUMNS``, swarmd's only if
    ``counts(commit)`` (when given); the same run read twice (same scenario, contender, N,
    k, repeat, commit and start) once."""
    names = {c for c, _ in COLUMNS}
    seen: set[tuple[Any, ...]] = set()
    runs, older, outside, dup = [], [], [], 0
    for f in files:
        r = f.run
        key = (r["scenario"], r["contender"], r["n"], dilation(r), r["run"], commit(r), started(r))
        if key in seen:
            dup += 1
            continue
        seen.add(key)
        if int(r["n"]) not in SIZES or r["contender"] not in names:
            outside.append(f)
        elif r["contender"] == SWARMD and counts is not None and not counts(commit(r)):
            older.append(f)
        else:
            runs.append(f)
    return Selection(runs, older, outside, dup)


def cell_runs(runs: Sequence[RunFile], scenario: str, contender: str, n: int) -> list[RunFile]:
    return [
        f
        for f in runs
        if f.run["scenario"] == scenario and f.run["contender"] == contender and f.run["n"] == n
    ]


def valid(files: Sequence[RunFile]) -> list[RunFile]:
    return [f for f in files if f.run.get("valid") is True]


# --- cells -----------------------------------------------------------------------------


def _fmt(x: float, spec: str) -> str:
    return "never" if math.isinf(x) else f"{x:{spec}}"


def summary(values: Sequence[float], spec: str, unit: str) -> str:
    """``median (min-max)``, or the one value."""
    mid = statistics.median(values)
    med = _fmt(mid, spec) + ("" if math.isinf(mid) else unit)
    low, high = _fmt(min(values), spec), _fmt(max(values), spec)
    if low == high:
        return med
    return f"{med} ({low}-{high})"


def cell(files: Sequence[RunFile], measure: Measure) -> str:
    """One measure over one cell's valid runs (module doc)."""
    if not files:
        return "not run"
    ok = valid(files)
    if not ok:
        return f"no valid run (0/{len(files)})"
    values = [v for v in (measure.read(f.run) for f in ok) if v is not None]
    if not values:
        return "-"
    text = (
        f"{_fmt(sum(values), measure.spec)}{measure.unit}"
        if measure.total
        else summary(values, measure.spec, measure.unit)
    )
    if measure.note is not None:
        text += measure.note([f.run for f in ok])
    return text if len(values) == len(ok) else f"{text} [{len(values)}/{len(ok)}]"


def runs_cell(files: Sequence[RunFile]) -> str:
    if not files:
        return "not run"
    ks = sorted({dilation(f.run) for f in files})
    return f"{len(valid(files))}/{len(files)} (k {'/'.join(f'{k:g}' for k in ks)})"


def _table(rows: Sequence[Sequence[str]]) -> list[str]:
    head = ["scenario", *(title for _, title in COLUMNS)]
    return [
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
        *("| " + " | ".join(row) + " |" for row in rows),
    ]


def tables(runs: Sequence[RunFile], n: int) -> list[str]:
    """Markdown: the "runs" table and one table per measure at N (rows scenario, columns
    contender)."""
    out = [f"**runs, valid/total (time dilation k)**, N = {n}:", ""]
    out += _table(
        [
            [s, *(runs_cell(cell_runs(runs, s, c, n)) for c, _ in COLUMNS)]
            for s in SCENARIOS
        ]
    )  # fmt: skip
    for measure in MEASURES:
        out += ["", f"**{measure.title}**, N = {n}:", ""]
        out += _table(
            [[s, *(cell(cell_runs(runs, s, c, n), measure) for c, _ in COLUMNS)] for s in SCENARIOS]
        )
    return out


# --- figures ---------------------------------------------------------------------------


def figure_run(files: Sequence[RunFile]) -> RunFile | None:
    """The run whose timeline stands for the cell: of the valid runs (else all), the one
    with the median re-discovery max when every one has it, else the first by repeat."""
    pool = valid(files) or list(files)
    if not pool:
        return None
    pool = sorted(pool, key=lambda f: (int(f.run["run"]), commit(f.run)))
    slowest = [rediscovery_max(f.run) for f in pool]
    if len(pool) > 2 and all(v is not None for v in slowest):
        ranked = sorted(pool, key=lambda f: (rediscovery_max(f.run) or 0.0, int(f.run["run"])))
        return ranked[(len(ranked) - 1) // 2]
    return pool[0]


def figure_lines(runs: Sequence[RunFile], docs_dir: Path) -> list[str]:
    """A line per scenario: each (contender, N) cell's timeline, linked from ``docs_dir``."""
    out = []
    for s in SCENARIOS:
        parts = []
        for n in SIZES:
            links = []
            for c, title in COLUMNS:
                chosen = figure_run(cell_runs(runs, s, c, n))
                if chosen is None:
                    continue
                png = chosen.path.with_suffix(".png")
                name = f"{title} r{chosen.run['run']}"
                if png.exists():
                    rel = Path(_relpath(png.resolve(), docs_dir.resolve())).as_posix()
                    links.append(f"[{name}]({rel})")
                else:
                    links.append(f"{name} (no figure)")
            parts.append(f"N = {n}: " + (", ".join(links) if links else "no run"))
        out.append(f"- {s}: " + "; ".join(parts))
    return out


def _relpath(target: Path, start: Path) -> str:
    import os

    return os.path.relpath(target, start)


# --- verdicts --------------------------------------------------------------------------


def _word(met: bool | None) -> str:
    return {True: "**met**", False: "**not met**", None: "**not known**"}[met]


def _runs_word(k: int) -> str:
    return f"{k} valid run" + ("" if k == 1 else "s")


def _judge(
    target: str,
    scenario: str,
    n: int,
    files: Sequence[RunFile],
    read: Callable[[Run], float | None],
    passes: Callable[[float], bool],
    bound: str,
    spec: str,
    unit: str,
    extra: Callable[[Sequence[RunFile]], str] | None = None,
) -> Verdict:
    """Met when every valid run with the measure passes, not met when any fails, not known
    without a valid run that has it."""
    ok = valid(files)
    head = f"N={n}, {scenario}: "
    if not ok:
        why = "no run" if not files else f"no valid run (0 of {len(files)})"
        return Verdict(target, scenario, n, None, head + f"{_word(None)}: {why}", why)
    values = [v for v in (read(f.run) for f in ok) if v is not None]
    if not values:
        return Verdict(
            target,
            scenario,
            n,
            None,
            head + f"{_word(None)}: not measured in {_runs_word(len(ok))}",
        )
    within = sum(1 for v in values if passes(v))
    met = within == len(values)
    text = (
        f"{head}{_word(met)}, {within} of {_runs_word(len(values))} {bound}: "
        f"{summary(values, spec, unit)}"
    )
    if len(values) < len(ok):
        text += f" ({len(ok) - len(values)} valid run(s) without it)"
    if extra is not None:
        text += extra(ok)
    return Verdict(target, scenario, n, met, text)


def _p50_note(ok: Sequence[RunFile]) -> str:
    p50 = [v for v in (rediscovery_p50(f.run) for f in ok) if v is not None]
    return f"; p50 {summary(p50, '.2f', ' s')}" if p50 else ""


# each target: (name, the run's figure, passes, the bound as written, format, unit, note,
# the scenarios it judges: None for all)
_RULES: Final[
    tuple[
        tuple[
            str,
            Callable[[Run], float | None],
            Callable[[float], bool],
            str,
            str,
            str,
            Callable[[Sequence[RunFile]], str] | None,
            frozenset[str] | None,
        ],
        ...,
    ]
] = (
    ("false", false_losses, lambda v: v <= FALSE_LOSSES_MAX, "with none", ".0f", "", None, None),
    (
        "rediscovery", rediscovery_max, lambda v: v <= REDISCOVERY_MAX_S, "≤ 2 s", ".2f", " s",
        _p50_note, None,
    ),
    (
        "frames", frames_per_pair, lambda v: v <= FRAMES_PER_PAIR_MAX, "≤ 4", ".2f", "", None,
        frozenset(HEALS),
    ),
    (
        "readiness", readiness, lambda v: v >= 100.0 * READINESS_MIN, "≥ 99 %", ".1f", " %",
        None, None,
    ),
)  # fmt: skip


def verdicts(runs: Sequence[RunFile]) -> list[Verdict]:
    """issue 20's targets for swarmd, per N and scenario (``Verdict``)."""
    return [
        _judge(target, s, n, cell_runs(runs, s, SWARMD, n), read, passes, bound, spec, unit, extra)
        for n in SIZES
        for s in SCENARIOS
        for target, read, passes, bound, spec, unit, extra, only in _RULES
        if only is None or s in only
    ]


TARGETS: Final = (
    ("false", "no false losses of peers that stayed in range (0; the sum per run)"),
    (
        "rediscovery",
        "re-discovery ≤ 2 s (each valid run's slowest pair; reboot: either way after the "
        "restart too)",
    ),
    (
        "frames",
        "≤ 4 discovery frames per rejoining pair at the heal (fly-out, split, blackout: fade's "
        "window is the whole fade, reboot has no rejoining pair)",
    ),
    ("readiness", "readiness delivery among drones in range ≥ 99 %"),
)


def verdict_lines(vs: Sequence[Verdict]) -> list[str]:
    out = []
    for target, title in TARGETS:
        mine = [v for v in vs if v.target == target]
        tally = (
            f"met {sum(1 for v in mine if v.met is True)}, "
            f"not met {sum(1 for v in mine if v.met is False)}, "
            f"not known {sum(1 for v in mine if v.met is None)}"
        )
        out.append(f"- **{title}** ({tally}):")
        out += [f"  - {v.text}" for v in mine if v.reason != "no run"]
        unrun = [f"N={v.n} {v.scenario}" for v in mine if v.reason == "no run"]
        if unrun:
            out.append(f"  - {_word(None)}, no run: {', '.join(unrun)}")
    return out


# --- the block -------------------------------------------------------------------------


def _utc(at: float, spec: str) -> str:
    return time.strftime(spec, time.gmtime(at))


def commit_lines(files: Sequence[RunFile]) -> list[str]:
    """Which commit each run measured, when (UTC), and which cells."""
    groups: dict[str, list[RunFile]] = defaultdict(list)
    for f in files:
        groups[commit(f.run)].append(f)

    def first(item: tuple[str, list[RunFile]]) -> float:
        return min((started(f.run) or float("inf") for f in item[1]), default=float("inf"))

    out = []
    for made_by, group in sorted(groups.items(), key=first):
        starts = sorted(t for t in (started(f.run) for f in group) if t is not None)
        when = ""
        if starts:
            a, b = _utc(starts[0], "%Y-%m-%d %H:%M"), _utc(starts[-1], "%Y-%m-%d %H:%M")
            when = f", {a} UTC" if a == b else f", {a} to {b} UTC"
            if a[:10] == b[:10] and a != b:
                when = f", {a}-{b[11:]} UTC"
        cells: dict[tuple[str, int], list[str]] = defaultdict(list)
        for f in group:
            r = f.run
            cells[(r["contender"], int(r["n"]))].append(f"{r['scenario']} r{r['run']}")
        what = "; ".join(
            f"{c} N={n}: {', '.join(sorted(v))}" for (c, n), v in sorted(cells.items())
        )
        out.append(f"- `{made_by}`: {len(group)} run file(s){when} ({what})")
    return out


def block(
    files: Sequence[RunFile],
    *,
    command: str,
    docs_dir: Path,
    counts: Callable[[str], bool] | None,
    since: str | None,
) -> str:
    """The generated block, markers included."""
    sel = select(files, counts)
    runs = sel.runs
    lines = [
        BEGIN,
        f"Generated by `{command}`; everything down to the end marker is rewritten by it "
        "(change `bench/wifi/flight_matrix.py`, not this text). Cells: the median over the "
        "cell's valid runs, with the range when there are more than one (false losses: "
        "their sum); invalid runs are counted in the runs table and enter nothing else; "
        "`[a/b]`: only a of the b valid runs have the measure (nothing lost, no heal); "
        '"never": a pair reported lost was not found again in the run; '
        '"not run": no run file. The measures are each run file\'s `measures` '
        "(`bench/wifi/flight_measures.py`, definitions below); re-discovery in a reboot "
        "run is from the restart (p50: the peers' first sight of the new life; max: either "
        "way).",
        "",
        "Which code each run measured (`setup.commit`, start times UTC):",
        "",
        *commit_lines(runs),
    ]
    if since is not None:
        lines += [
            "",
            f"swarmd: only runs at `{since}` or after count (the engine as shipped)"
            + (
                f"; left out, older: {len(sel.older_swarmd)} run file(s) at "
                + ", ".join(f"`{c}`" for c in sorted({commit(f.run) for f in sel.older_swarmd}))
                if sel.older_swarmd
                else ""
            )
            + ".",
        ]
    if sel.outside:
        what = sorted({f"{f.run['contender']} N={f.run['n']}" for f in sel.outside})
        lines += ["", f"Not in the matrix (N or contender): {len(sel.outside)} run file(s): "
                  + ", ".join(what) + "."]  # fmt: skip
    lines += ["", "### The matrix, from the run files", ""]
    for n in SIZES:
        lines += [f"#### N = {n}", "", *tables(runs, n), ""]
    lines += [
        "### Targets (issue 20), swarmd, judged from the runs",
        "",
        "Valid runs only; met means in every valid run of the cell, however few.",
        "",
        *verdict_lines(verdicts(runs)),
        "",
        "### Figures",
        "",
        "A timeline per scenario, contender and N (the run with the median re-discovery max "
        "of three or more, else the first valid): who lists whom against the ground truth, "
        "each drone's received SNR under it (`bench/wifi/flight_report.py`).",
        "",
        *figure_lines(runs, docs_dir),
        END,
    ]
    return "\n".join(lines)


def write_docs(docs: Path, text: str) -> None:
    """Rewrite the block in ``docs``; without its markers, put it at the top of the Flight
    section (after the intro, before the first subsection), then rewrite it there."""
    current = docs.read_text()
    if BEGIN not in current or END not in current:
        start = current.find(SECTION)
        if start < 0:
            raise ValueError(f"{docs}: no {SECTION!r} heading and no {BEGIN} marker")
        sub = current.find("\n### ", start)
        nxt = current.find("\n## ", start + len(SECTION))
        at = sub if sub >= 0 and (nxt < 0 or sub < nxt) else nxt
        at = len(current) if at < 0 else at + 1
        docs.write_text(current[:at] + f"{BEGIN}\n{END}\n\n" + current[at:])
    write_block(docs, BEGIN, END, text)
