"""The flight matrix (issue 20, "Done when"): every scenario for every contender at N = 10
and 20, summarised from the run files alone, swarmd's targets judged, a figure per cell.

    .venv/bin/python -m bench.wifi.flight_report --matrix RUNS... [--since-commit C] \\
        [--write-docs docs/benchmarks.md]

``RUNS`` are run files (``flight_run``'s ``runs/*.json``) or directories holding them (a
directory's ``runs/`` when it has one). First every contender side by side against
swarmd's targets (``flight_verdicts.standings``: cells met / not met / not known, the
costs' medians over cells and their ratio to swarmd's). Then per N, one table per measure:
rows the scenarios, columns the contenders (``flight_cells.py``: the discovery measures, the
commands, the renewal period following Q); a cell is the median over that cell's **valid**
runs with the range when there are more than one (false losses, commands: their sum), "not
run" without a run file, "older runs only (n)" with only run files older than
``--since-commit``, and invalid runs are counted in the "runs" table but enter no median,
sum or verdict. Then swarmd's targets, judged (``flight_verdicts.py``), and the figures.

Which runs on swarmd count: ``--since-commit C`` keeps the runs of every contender whose
daemon is swarmd (swarmd, ROS 2 on swarmd: ``flight_cells.ON_SWARMD``) whose
``setup.commit`` is C or a descendant of it (the engine as shipped: name the last commit
that changed the engine, ``git log -1 --format=%h -- swarmd/discovery/``); older ones are
left out and listed with their commit and cells. ``--since-commit CONTENDER=C`` (again, once
per contender) gives one contender on swarmd its own C instead, for a change only its runs
go through: ``ros2-swarmd=C`` after a fix to the relay's graph writer. Without any, every
run passed counts (name the directories of the engine as shipped). The stock stacks' runs
are never filtered by commit: their stacks are the third-party packages, the harness the
same. The rule is ``flight_cells.current`` with ``Since`` (``since_counts``), which
``flight_campaign`` shares, so the campaign plans runs for the cells the matrix would leave
empty; it reads the since from the docs' block (``documented_since``).

``--write-docs FILE`` rewrites the lines between ``BEGIN`` and ``END`` in FILE (the
"Flight" section of docs/benchmarks.md), naming the command that generated them, and the
run files' commits and dates; nothing outside the markers changes. Without the markers, the
block is put after the "## Flight" heading's intro (before its first "###").
"""

from __future__ import annotations

import subprocess
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from bench.docblock import write_block

# the matrix is split by concern (cells and tables, the targets, this: which runs, the
# figures, the block); this module stays the one to import (flight_report, the tests)
from bench.wifi.flight_cells import (
    COLUMNS,
    MEASURES,
    ON_SWARMD,
    SCENARIOS,
    SIZES,
    SWARMD,
    Counts,
    Measure,
    Run,
    RunFile,
    Since,
    beside,
    cell,
    cell_runs,
    commit,
    current,
    dilation,
    is_valid,
    parse_since,
    read_run,
    rediscovery_max,
    rediscovery_p50,
    runs_cell,
    started,
    summary,
    tables,
    valid,
    validity,
)
from bench.wifi.flight_verdicts import (
    RULES,
    Verdict,
    standing_lines,
    standings,
    verdict_lines,
    verdicts,
)

__all__ = [
    "BEGIN", "COLUMNS", "END", "MEASURES", "RULES", "SCENARIOS", "SECTION", "SIZES", "SWARMD",
    "ON_SWARMD", "Counts", "Measure", "Run", "RunFile", "Selection", "Since", "Verdict",
    "beside", "block", "cell", "cell_runs", "commit", "commit_lines", "current", "dilation",
    "documented_since", "figure_lines", "figure_run", "git_descends", "is_valid", "load",
    "parse_since", "read_run", "rediscovery_max", "rediscovery_p50", "runs_cell", "select",
    "side_by_side", "since_args", "since_counts", "since_lines", "standings", "started",
    "summary", "tables", "valid", "validity", "verdict_lines", "verdicts", "write_docs",
]  # fmt: skip

BEGIN: Final = "<!-- flight-matrix:begin (python -m bench.wifi.flight_report --matrix) -->"
END: Final = "<!-- flight-matrix:end -->"
SECTION: Final = "## Flight (issue 20)"


# --- which runs ------------------------------------------------------------------------


def load(paths: Iterable[Path]) -> list[RunFile]:
    """Every run file named, or held in a named directory (its ``runs/`` if it has one);
    ``ValueError`` naming the file when one cannot be read (``read_run``)."""
    out: list[RunFile] = []
    for path in paths:
        if path.is_dir():
            folder = path / "runs" if (path / "runs").is_dir() else path
            files = sorted(folder.glob("*.json"))
        else:
            files = [path]
        for f in files:
            try:
                out.append(RunFile(f, read_run(f)))
            except ValueError as exc:
                raise ValueError(f"{f}: {exc}") from exc
    return out


def git_descends(since: str, repo: Path) -> Callable[[str], bool]:
    """Whether a run file's commit (``+dirty`` dropped) is ``since`` or a descendant of it,
    by the repository's history; a commit the repository does not know does not count.
    ``ValueError`` when ``since`` itself is not a commit there: every run on swarmd would
    then read as older, and the campaign would plan all of them again."""
    known = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "--verify", "--quiet", f"{since}^{{commit}}"],
        capture_output=True,
        check=False,
    )
    if known.returncode != 0:
        raise ValueError(f"--since-commit {since}: not a commit of {repo}")
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


def since_counts(since: Since | None, repo: Path) -> Counts | None:
    """``current``'s rule for ``since`` by the repository's history: a contender's run
    counts when its commit is the contender's since (``Since.of``) or a descendant of it.
    ``ValueError`` when a commit named is not one of ``repo`` (``git_descends``), or when a
    contender's own since is not at or after the default: its daemon is still swarmd's
    engine, and runs of an engine older than the one shipped would count for it."""
    if since is None:
        return None
    checks = {at: git_descends(at, repo) for at in since.commits()}
    if since.default is not None:
        for contender, at in since.own:
            if not checks[since.default](at):
                raise ValueError(
                    f"--since-commit {contender}={at}: before the default {since.default}"
                )

    def counts(contender: str, made_by: str) -> bool:
        at = since.of(contender)
        return at is None or checks[at](made_by)

    return counts


@dataclass(frozen=True, slots=True)
class Selection:
    """The runs the matrix reads, and those it leaves out (with why)."""

    runs: list[RunFile]
    older: list[RunFile]  # runs on swarmd before their ``--since-commit`` (``current``)
    outside: list[RunFile]  # N or contender not in the matrix
    duplicates: int


def select(files: Sequence[RunFile], counts: Counts | None) -> Selection:
    """The matrix's runs: N in ``SIZES``, a contender of ``COLUMNS``, a contender on swarmd's
    only at a commit ``counts`` (``current``, when given); the same run read twice (same
    scenario, contender, N, k, repeat, commit and start) once."""
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
        elif not current(r, counts):
            older.append(f)
        else:
            runs.append(f)
    return Selection(runs, older, outside, dup)


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
    counts: Counts | None,
    since: Since | None,
) -> str:
    """The generated block, markers included."""
    sel = select(files, counts)
    runs = sel.runs
    lines = [
        BEGIN,
        f"Generated by `{command}`; everything down to the end marker is rewritten by it "
        "(change `bench/wifi/flight_matrix.py`, `flight_cells.py` or `flight_verdicts.py`, "
        "not this text). Cells: the median over the cell's valid runs, with the range when "
        "there are more than one (false losses, commands: their sum); invalid runs are "
        "counted in the runs table and enter nothing else; "
        "`[a/b]`: only a of the b valid runs have the measure (nothing lost, no heal); "
        '"never": a pair reported lost was not found again in the run; '
        '"not run": no run file. The measures are each run file\'s `measures` '
        "(`bench/wifi/flight_measures.py`, definitions below); re-discovery in a reboot "
        "run is from the restart (p50: the peers' first sight of the new life; max: either "
        "way).",
        "",
        *side_by_side(runs),
        "",
        "### Which code each run measured",
        "",
        "`setup.commit` of each run file read, start times UTC:",
        "",
        *commit_lines(runs),
    ]
    if since is not None:
        lines += ["", *since_lines(since, sel.older)]
    if sel.outside:
        what = sorted({f"{f.run['contender']} N={f.run['n']}" for f in sel.outside})
        lines += ["", f"Not in the matrix (N or contender): {len(sel.outside)} run file(s): "
                  + ", ".join(what) + "."]  # fmt: skip
    lines += ["", "### The matrix, from the run files", ""]
    for n in SIZES:
        lines += [f"#### N = {n}", "", *tables(runs, n, sel.older), ""]
    lines += [
        "### Targets (issue 20), swarmd, judged from the runs",
        "",
        "Valid runs only; met means in every valid run of the cell, however few. The "
        "commands and renewal targets judge ROS 2 on swarmd too where its runs carry them.",
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


def since_lines(since: Since, older: Sequence[RunFile]) -> list[str]:
    """Which runs of each contender on swarmd in the matrix count (``Since``), how many
    older run files each leaves out, and those files by commit."""
    left: dict[str, int] = defaultdict(int)
    for f in older:
        left[str(f.run["contender"])] += 1
    spelled = " ".join(f"--since-commit {at}" for at in since.args())
    out = [
        f"Which runs on swarmd count (`{spelled}`; a stock stack's run counts at any commit):",
        "",
    ]
    for c, title in COLUMNS:
        if c not in ON_SWARMD:
            continue
        at = since.of(c)
        which = "at any commit" if at is None else f"at `{at}` or after"
        why = (
            "" if at is None
            else f" (its own, `{c}={at}`)" if c in dict(since.own)
            else " (the engine as shipped)"
        )  # fmt: skip
        out.append(f"- {title}: runs {which}{why}; left out, older: {left[c]} run file(s)")
    if older:
        out += [
            "",
            'A cell that has only older runs says "older runs only (n)", not "not run". '
            f"The {len(older)} older run file(s) left out:",
            "",
            *commit_lines(older),
        ]
    return out


def side_by_side(runs: Sequence[RunFile]) -> list[str]:
    """Every contender against swarmd's targets (``flight_verdicts.standings``): the
    heading, a one-line header saying the targets are swarmd's, the legend, a table per N."""
    return [
        "### Every contender against swarmd's targets, side by side",
        "",
        "issue 20's targets are swarmd's, set for a swarm that must notice a loss and a "
        "return within seconds; the stock stacks were not built for them (each keeps its own "
        'default lease and announcement period: docs/flight-history.md, "The stock '
        "contenders\"), so here they are a yardstick, not a verdict on a stack's design.",
        "",
        "Valid runs only, judged as swarmd's targets below are (a cell is met when every "
        "valid run of it is). Per target: cells met / not met / not known (no valid run, or "
        "none with the figure); re-discovery counts the five scenarios, frames the three "
        "heals (fly-out, split, blackout). The costs: the median over the cells of each "
        "cell's median over its valid runs, with how many cells and valid runs it stands on "
        '(a stock cell has fewer runs than swarmd\'s: compare the counts); "never": a pair '
        'reported lost was not found again; "× swarmd": that median over swarmd\'s, both '
        "over the cells both have.",
        "",
        *standing_lines(standings(runs)),
    ]


def since_args(raw: Sequence[str]) -> list[str]:
    """The ``--since-commit`` values of a command line (``--since-commit X`` and
    ``--since-commit=X``, as argparse takes them), in order."""
    out: list[str] = []
    for k, arg in enumerate(raw):
        if arg == "--since-commit" and k + 1 < len(raw):
            out.append(raw[k + 1])
        elif arg.startswith("--since-commit="):
            out.append(arg.partition("=")[2])
    return out


def documented_since(docs: Path) -> Since | None:
    """The ``--since-commit`` values that the block in ``docs`` names in its "Generated by"
    command, default and per contender (``parse_since``): which runs on swarmd the
    documented matrix counts (None: no block, no file, or a block made without it).
    ``ValueError`` when the command names them wrongly."""
    import re
    import shlex

    try:
        text = docs.read_text()
    except OSError:
        return None
    start, end = text.find(BEGIN), text.find(END)
    found = re.search(r"Generated by `([^`]*)`", text[start:end]) if 0 <= start < end else None
    return parse_since(since_args(shlex.split(found.group(1)) if found else []))


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
