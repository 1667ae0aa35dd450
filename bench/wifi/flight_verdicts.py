"""issue 20's targets judged from the flight runs (``bench/wifi/flight_matrix.py``'s
"Targets" list): one table of rules (``RULES``), each read per run, every verdict met / not
met / not known with the numbers. Then every contender side by side (``standings``): the
same rules as a yardstick for each, per N, with the two costs that matter most as medians
over the cells and their ratio to swarmd's.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final

from bench.wifi.flight_cells import (
    COLUMNS,
    COMMAND_FAULTS,
    COMMAND_OTHERS,
    PCT_DOWN,
    READINESS_MIN_PCT,
    REDISCOVERY_MAX_S,
    S_UP,
    SCENARIOS,
    SIZES,
    SWARMD,
    Run,
    RunFile,
    cell_runs,
    command_faults,
    command_sum,
    false_losses,
    fmt,
    frames_per_pair,
    readiness,
    rediscovery_max,
    rediscovery_p50,
    renewal_lowest_r,
    renewal_split,
    summary,
    valid,
)
from bench.wifi.flight_measures import Q_MOVED_MIN

# issue 20's targets for swarmd
FALSE_LOSSES_MAX: Final = 0
FRAMES_PER_PAIR_MAX: Final = 4.0
READINESS_MIN: Final = READINESS_MIN_PCT / 100.0
# the scenarios with a heal (a return after a gap every rejoining pair shares); fade's
# window runs from the drone's first return to its last re-discovery, the whole fade with
# every renewal in it, and reboot has no rejoining pairs: the frames target is not theirs
HEALS: Final = frozenset({"fly-out", "split", "blackout"})
# "the renewal/vouch rate following the link quality": at each daemon whose Q moved by
# ``Q_MOVED_MIN`` or more, the correlation of Q with its renewal period above this: the
# period rose and fell with Q. Not a bound on how tightly: the period is a step function of
# the advertised Q, which stays put until a reading is a step (0.1) away, so where Q moved
# by few steps and settled within one of where the period last moved, r is well below 1
# while the period did all the engine asks (blackout N = 20 in the staggered runs: r 0.47
# at a daemon whose Q moved 0.22, then sat 0.09 above its advertised Q for 30 s)
FOLLOWS_R_ABOVE: Final = 0.0
# the contenders judged besides swarmd where one of their valid runs has the figure
ON_SWARMD: Final = ("ros2-swarmd",)


@dataclass(frozen=True, slots=True)
class Verdict:
    """One of issue 20's targets for one contender (swarmd unless the rule says) at one
    scenario and N: met (True), not met (False) or not known from these runs (None), and
    the sentence with the numbers."""

    target: str
    scenario: str
    n: int
    met: bool | None
    text: str
    reason: str = ""  # why not known: "no run", ...
    contender: str = SWARMD


@dataclass(frozen=True, slots=True)
class Rule:
    """One target: what it reads from a run, when a run passes, and how it is written."""

    target: str  # the key
    title: str  # the target as the "Targets" list writes it
    read: Callable[[Run], float | None]  # the run's figure; None: the run does not have it
    passes: Callable[[float], bool]
    bound: str  # the bound as written after "k of n valid runs"
    spec: str  # format of one figure
    unit: str
    note: Callable[[Sequence[RunFile]], str] | None = None  # after the figures (valid runs)
    scenarios: frozenset[str] | None = None  # those it judges; None: every one
    # contenders judged besides swarmd, only where one of their valid runs has the figure
    also: tuple[str, ...] = ()
    # why no valid run has the figure, when "not measured" would not say it (valid runs)
    unmeasured: Callable[[Sequence[RunFile]], str] | None = None


def _word(met: bool | None) -> str:
    return {True: "**met**", False: "**not met**", None: "**not known**"}[met]


def _runs_word(k: int) -> str:
    return f"{k} valid run" + ("" if k == 1 else "s")


def _title(contender: str) -> str:
    return next((title for c, title in COLUMNS if c == contender), contender)


def _judge(rule: Rule, scenario: str, n: int, files: Sequence[RunFile], contender: str) -> Verdict:
    """Met when every valid run with the figure passes, not met when any fails, not known
    without a valid run that has it."""
    ok = valid(files)
    who = "" if contender == SWARMD else f"{_title(contender)}, "
    head = f"{who}N={n}, {scenario}: "

    def verdict(met: bool | None, text: str, reason: str = "") -> Verdict:
        return Verdict(rule.target, scenario, n, met, text, reason, contender)

    if not ok:
        why = "no run" if not files else f"no valid run (0 of {len(files)})"
        return verdict(None, head + f"{_word(None)}: {why}", why)
    values = [v for v in (rule.read(f.run) for f in ok) if v is not None]
    if not values:
        why = f"not measured in {_runs_word(len(ok))}"
        if rule.unmeasured is not None:
            why = rule.unmeasured(ok) or why
        return verdict(None, head + f"{_word(None)}: {why}")
    within = sum(1 for v in values if rule.passes(v))
    met = within == len(values)
    text = (
        f"{head}{_word(met)}, {within} of {_runs_word(len(values))} {rule.bound}: "
        f"{summary(values, rule.spec, rule.unit)}"
    )
    if len(values) < len(ok):
        text += f" ({len(ok) - len(values)} valid run(s) without it)"
    if rule.note is not None:
        text += rule.note(ok)
    return verdict(met, text)


def _p50_note(ok: Sequence[RunFile]) -> str:
    p50 = [v for v in (rediscovery_p50(f.run) for f in ok) if v is not None]
    return f"; p50 {summary(p50, '.2f', ' s')}" if p50 else ""


def _commands_note(ok: Sequence[RunFile]) -> str:
    runs = [f.run for f in ok]
    parts = [f"{what} {command_sum(runs, key)}" for key, what in COMMAND_FAULTS]
    parts += [f"{what} {k}" for key, what in COMMAND_OTHERS if (k := command_sum(runs, key))]
    issued, pairs = command_sum(runs, "commands"), command_sum(runs, "pairs")
    return f"; {issued} commands, {pairs} pairs: " + ", ".join(parts)


def _renewal_note(ok: Sequence[RunFile]) -> str:
    judged, others = renewal_split([f.run for f in ok])
    within = sum(1 for r in judged if r > FOLLOWS_R_ABOVE)
    text = (
        f"; {within} of {len(judged)} daemons with Q moved ≥ {Q_MOVED_MIN:g} at "
        f"r > {FOLLOWS_R_ABOVE:g}, r {summary(judged, '.2f', '')}"
    )
    if others:
        text += f"; {len(others)} with Q moved less (≤ {max(others):.2f}) not judged"
    return text


def _renewal_unmeasured(ok: Sequence[RunFile]) -> str:
    """Why no run judges the period: Q moved too little everywhere (or no polls: "")."""
    judged, others = renewal_split([f.run for f in ok])
    if judged or not others:
        return ""
    return (
        f"Q moved by less than {Q_MOVED_MIN:g} at each of the {len(others)} daemons polled "
        f"in {_runs_word(len(ok))} (at most {max(others):.2f})"
    )


RULES: Final = (
    Rule(
        "false", "no false losses of peers that stayed in range (0; the sum per run)",
        false_losses, lambda v: v <= FALSE_LOSSES_MAX, "with none", ".0f", "",
    ),
    Rule(
        "rediscovery",
        "re-discovery ≤ 2 s (each valid run's slowest pair; reboot: either way after the "
        "restart too)",
        rediscovery_max, lambda v: v <= REDISCOVERY_MAX_S, "≤ 2 s", S_UP, " s", _p50_note,
    ),
    Rule(
        "frames",
        "≤ 4 discovery frames per rejoining pair at the heal (fly-out, split, blackout: fade's "
        "window is the whole fade, reboot has no rejoining pair)",
        frames_per_pair, lambda v: v <= FRAMES_PER_PAIR_MAX, "≤ 4", ".2f", "",
        scenarios=HEALS,
    ),
    Rule(
        "readiness", "readiness delivery among drones in range ≥ 99 %",
        readiness, lambda v: v >= 100.0 * READINESS_MIN, "≥ 99 %", PCT_DOWN, " %",
    ),
    Rule(
        "commands",
        "commands: none twice, none late, every unreached member reported (and none reported "
        "unreachable while it was reachable): the (command, member) pairs that broke one, "
        "0 per run (issue 20, \"Command authority in flight\"; a restart's voided copy is "
        "by design, counted apart)",
        command_faults, lambda v: v == 0, "with none", ".0f", "", _commands_note,
        also=ON_SWARMD,
    ),
    Rule(
        "renewal",
        f"the renewal period follows the link quality: at every daemon whose Q moved by "
        f"≥ {Q_MOVED_MIN:g} after the first move, its renewal period rose and fell with Q "
        f"(Pearson r of Q with the period > {FOLLOWS_R_ABOVE:g}; the period moves in steps, "
        f"held within a step of Q by the engine's hysteresis, so r is not expected near 1). "
        f"Daemons whose Q moved less are not judged, nor are the 60 s renewal and vouch "
        f"rates (their window lags Q)",
        renewal_lowest_r, lambda v: v > FOLLOWS_R_ABOVE, f"with r > {FOLLOWS_R_ABOVE:g} at "
        "each such daemon (the run's lowest r)", ".2f", "", _renewal_note,
        also=ON_SWARMD, unmeasured=_renewal_unmeasured,
    ),
)  # fmt: skip


def _judged(rule: Rule, runs: Sequence[RunFile]) -> list[str]:
    """swarmd, and each of ``rule.also`` that has the figure in one of its valid runs."""
    extra = [
        c
        for c in rule.also
        if any(f.run["contender"] == c and rule.read(f.run) is not None for f in valid(runs))
    ]
    return [SWARMD, *extra]


def verdicts(runs: Sequence[RunFile]) -> list[Verdict]:
    """issue 20's targets, per N and scenario (``Verdict``), from ``RULES``."""
    judged = {rule.target: _judged(rule, runs) for rule in RULES}
    return [
        _judge(rule, s, n, cell_runs(runs, s, c, n), c)
        for n in SIZES
        for s in SCENARIOS
        for rule in RULES
        if rule.scenarios is None or s in rule.scenarios
        for c in judged[rule.target]
    ]


def verdict_lines(vs: Sequence[Verdict]) -> list[str]:
    """The "Targets" list: per rule its tally, a line per verdict, the cells not run."""
    out = []
    for rule in RULES:
        mine = [v for v in vs if v.target == rule.target]
        tally = (
            f"met {sum(1 for v in mine if v.met is True)}, "
            f"not met {sum(1 for v in mine if v.met is False)}, "
            f"not known {sum(1 for v in mine if v.met is None)}"
        )
        out.append(f"- **{rule.title}** ({tally}):")
        out += [f"  - {v.text}" for v in mine if v.reason != "no run"]
        unrun = [
            ("" if v.contender == SWARMD else f"{_title(v.contender)} ") + f"N={v.n} {v.scenario}"
            for v in mine
            if v.reason == "no run"
        ]
        if unrun:
            out.append(f"  - {_word(None)}, no run: {', '.join(unrun)}")
    return out


# --- every contender, side by side -----------------------------------------------------

# the targets every contender is judged against, as a yardstick (issue 20 asks for "the
# targets judged from the runs"; commands and the renewal period are swarmd's own features,
# a stock stack has neither)
YARDSTICK: Final = ("false", "rediscovery", "frames", "readiness")
# the two costs compared as medians over the cells, each with its ratio to swarmd's
COSTS: Final = (
    ("rediscovery", "re-discovery max"),
    ("frames", "frames per rejoining pair"),
)
_SHORT: Final = {
    "false": "no false losses",
    "rediscovery": "re-discovery ≤ 2 s",
    "frames": "≤ 4 frames per rejoining pair",
    "readiness": "readiness ≥ 99 %",
}


def _rule(target: str) -> Rule:
    return next(rule for rule in RULES if rule.target == target)


@dataclass(frozen=True, slots=True)
class Tally:
    """How many cells (scenarios) of one target one contender met, did not, or could not be
    judged in (no run, no valid run, the measure in none)."""

    met: int
    not_met: int
    not_known: int


@dataclass(frozen=True, slots=True)
class Cost:
    """One cost of one contender at one N: each cell's median over its valid runs that have
    the figure (``inf``: a pair never found again), and how many such runs there were."""

    cells: dict[str, float]  # scenario -> the cell's median
    runs: int

    def median(self, scenarios: Sequence[str] | None = None) -> float | None:
        """The median over the cells (those in ``scenarios`` only, when given)."""
        picked = [v for s, v in self.cells.items() if scenarios is None or s in scenarios]
        return statistics.median(picked) if picked else None


@dataclass(frozen=True, slots=True)
class Standing:
    """One contender at one N against the yardstick: a ``Tally`` per ``YARDSTICK`` target
    and a ``Cost`` per ``COSTS`` target."""

    contender: str
    n: int
    tallies: tuple[Tally, ...]
    costs: tuple[Cost, ...]


def _cost(rule: Rule, runs: Sequence[RunFile], contender: str, n: int) -> Cost:
    cells: dict[str, float] = {}
    count = 0
    for s in SCENARIOS:
        if rule.scenarios is not None and s not in rule.scenarios:
            continue
        values = [
            v for v in (rule.read(f.run) for f in valid(cell_runs(runs, s, contender, n)))
            if v is not None
        ]  # fmt: skip
        if values:
            cells[s] = statistics.median(values)
            count += len(values)
    return Cost(cells, count)


def standings(runs: Sequence[RunFile]) -> list[Standing]:
    """Every contender of ``COLUMNS`` at every N, judged by the ``YARDSTICK`` rules as
    swarmd is (``_judge``: met only when every valid run of the cell is) and costed."""
    out = []
    for n in SIZES:
        for c, _ in COLUMNS:
            tallies = []
            for target in YARDSTICK:
                rule = _rule(target)
                mets = [
                    _judge(rule, s, n, cell_runs(runs, s, c, n), c).met
                    for s in SCENARIOS
                    if rule.scenarios is None or s in rule.scenarios
                ]
                tallies.append(
                    Tally(mets.count(True), mets.count(False), sum(m is None for m in mets))
                )
            costs = tuple(_cost(_rule(t), runs, c, n) for t, _ in COSTS)
            out.append(Standing(c, n, tuple(tallies), costs))
    return out


def ratio(mine: Cost, swarmd: Cost) -> float | None:
    """The median of ``mine`` over the cells both have, over swarmd's median over the same
    cells (so a cell only one has moves neither side); None without a shared cell or when
    swarmd's median is 0."""
    shared = [s for s in mine.cells if s in swarmd.cells]
    a, b = mine.median(shared), swarmd.median(shared)
    if a is None or b is None or b == 0:
        return None
    return a / b


def _cost_text(cost: Cost, rule: Rule) -> str:
    mid = cost.median()
    if mid is None:
        return "-"
    value = fmt(mid, rule.spec) + ("" if math.isinf(mid) else rule.unit)
    never = sum(1 for v in cost.cells.values() if math.isinf(v))
    also = f"; {never} never" if never else ""
    cells = len(cost.cells)
    return (
        f"{value} ({cells} cell{'' if cells == 1 else 's'}, "
        f"{cost.runs} run{'' if cost.runs == 1 else 's'}{also})"
    )


def _ratio_text(x: float | None) -> str:
    if x is None:
        return "-"
    if math.isinf(x):
        return "never"
    return f"{x:.1f}×" if x < 10 else f"{x:.0f}×"


def standing_lines(table: Sequence[Standing]) -> list[str]:
    """Per N, a row per contender: cells met / not met / not known per target, then each
    cost's median over the cells with its cells and valid runs, and its ratio to swarmd's."""
    out: list[str] = []
    for n in SIZES:
        rows = [st for st in table if st.n == n]
        ours = next((st for st in rows if st.contender == SWARMD), None)
        head = ["contender", *(_SHORT[t] for t in YARDSTICK), "all targets"]
        for _, title in COSTS:
            head += [f"{title}, median (cells, runs)", "× swarmd"]
        out += [f"**N = {n}**:", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for st in rows:
            total = Tally(*(sum(getattr(t, f) for t in st.tallies)
                            for f in ("met", "not_met", "not_known")))  # fmt: skip
            cells = [_title(st.contender)]
            cells += [f"{t.met} / {t.not_met} / {t.not_known}" for t in st.tallies]
            cells.append(f"{total.met} / {total.not_met} / {total.not_known}")
            for k, (t, _) in enumerate(COSTS):
                cost = st.costs[k]
                cells.append(_cost_text(cost, _rule(t)))
                cells.append(_ratio_text(None if ours is None else ratio(cost, ours.costs[k])))
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    return out[:-1]
