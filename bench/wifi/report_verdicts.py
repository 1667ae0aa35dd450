"""The verdicts on issue 13's targets, computed from the run files (met, not met, not known,
with the numbers and how many runs or pairs say so): the docs block's "Targets" list
(``bench/wifi/report.py``)."""

from __future__ import annotations

import statistics
import sys
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script, too

from bench.wifi.report_data import (  # noqa: E402
    COVERAGE_N,
    DISCOVERY_TARGET,
    DISCOVERY_TARGET_N,
    PEAK_TARGET,
    REPEATS_PLANNED,
    STOCK,
    SUCCESS_TARGET,
    _order,
    commit,
    dilation,
    main_k,
    main_rows,
    main_runs,
    summarise,
)


@dataclass(frozen=True, slots=True)
class Verdict:
    """One of issue 13's targets at one N (and contender): met (True), not met (False) or
    not known from these runs (None), and the sentence with the numbers behind it."""

    target: str  # "peak", "discovery", "success", "coverage"
    n: int | None
    contender: str | None
    met: bool | None
    text: str


def _word(met: bool | None) -> str:
    return {True: "**met**", False: "**not met**", None: "**not known**"}[met]


def _range(xs: Sequence[float], spec: str = ".0f", scale: float = 1.0, unit: str = "") -> str:
    """``median (min-max)``, or the one value."""
    med = statistics.median(xs) * scale
    if len(xs) == 1:
        return f"{med:{spec}}{unit}"
    return f"{med:{spec}}{unit} ({min(xs) * scale:{spec}}-{max(xs) * scale:{spec}})"


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def same_run_pairs(
    runs: Sequence[Mapping[str, Any]], other: str, n: int
) -> list[tuple[Mapping[str, Any], Mapping[str, Any]]]:
    """(swarmd, ``other``) run pairs at N: the same k, repeat and commit (one campaign step,
    back to back; as ``paired_ratios``), both valid. Any k: a pair at the dilation check's
    k (N = 5, k = 1 and 3) is as much one run as a pair at the main k."""
    valid = [r for r in runs if r.get("valid") and int(r["n"]) == n]
    by_key = {(r["contender"], dilation(r), int(r["run"]), commit(r)): r for r in valid}
    return [
        (r, by_key[(other, k, run, made_by)])
        for (c, k, run, made_by), r in sorted(by_key.items())
        if c == "swarmd" and (other, k, run, made_by) in by_key
    ]


def _main_k_text(runs: Sequence[Mapping[str, Any]], contender: str, n: int) -> str:
    rows = [r for r in summarise(runs) if r["contender"] == contender and r["n"] == n]
    if not rows:
        return f"{contender}: no run"
    k = main_k(rows)[(contender, n)]
    row = next(r for r in rows if r["k"] == k)
    made_by = sorted(
        {
            commit(r)
            for r in runs
            if r["contender"] == contender and int(r["n"]) == n and dilation(r) == k
        }
    )
    return (
        f"{contender}: {row['valid_runs']} valid of {row['runs']} at k = {k:g}, "
        f"made at {', '.join(made_by)}"
    )


def peak_verdicts(runs: Sequence[Mapping[str, Any]]) -> list[Verdict]:
    """swarmd's busiest second ≤ 5 % of each stock stack's, in same-run pairs, per N: met
    when every pair is within, not met when any is over, not known without a pair."""
    out = []
    for n in sorted({int(r["n"]) for r in runs} | set(COVERAGE_N)):
        for c in STOCK:
            # at N = 10 and 20 the target holds for every stock stack, run or not
            ran = any(r["contender"] == c and int(r["n"]) == n for r in runs)
            if not ran and n not in COVERAGE_N:
                continue
            pairs = same_run_pairs(runs, c, n)
            if not pairs:
                out.append(
                    Verdict(
                        "peak",
                        n,
                        c,
                        None,
                        f"N={n}, {c}: {_word(None)}: no same-run pair (valid, same k, "
                        f"repeat and commit): {_main_k_text(runs, 'swarmd', n)}; "
                        f"{_main_k_text(runs, c, n)}",
                    )
                )
                continue
            ratios = [float(s["peak_pps"]) / float(o["peak_pps"]) for s, o in pairs]
            over = sum(1 for x in ratios if x > PEAK_TARGET)
            ks = sorted({dilation(s) for s, _ in pairs})
            verdict = over == 0
            within = f"{len(pairs) - over} of {_count(len(pairs), 'pair', 'pairs')} within 5 %"
            out.append(
                Verdict(
                    "peak",
                    n,
                    c,
                    verdict,
                    f"N={n} (k = {'/'.join(f'{k:g}' for k in ks)}), {c}: {_word(verdict)}, "
                    f"{within}: swarmd / {c} {_range(ratios, '.1f', 100, ' %')}, "
                    f"swarmd {_range([float(s['peak_pps']) for s, _ in pairs])} against "
                    f"{_range([float(o['peak_pps']) for _, o in pairs])} frames/s",
                )
            )
    return out


def discovery_verdict(runs: Sequence[Mapping[str, Any]]) -> Verdict:
    """swarmd's discovery frames in the first 60 s at N = 10 ≤ 50, in every valid main run."""
    n = DISCOVERY_TARGET_N
    main = [
        r
        for r in main_runs(runs)
        if r["contender"] == "swarmd" and int(r["n"]) == n and r.get("valid")
    ]
    if not main:
        return Verdict(
            "discovery", n, "swarmd", None, f"{_word(None)}: no valid swarmd run at N={n}"
        )
    frames = [float(r["discovery_frames_60s"]) for r in main]
    over = sum(1 for x in frames if x > DISCOVERY_TARGET)
    met = over == 0
    how = (
        f"{len(frames) - over} of {_count(len(frames), 'valid run', 'valid runs')} "
        f"≤ {DISCOVERY_TARGET}"
    )
    return Verdict(
        "discovery",
        n,
        "swarmd",
        met,
        f"{_word(met)}, {how} (k = {dilation(main[0]):g}): {_range(frames)} discovery frames "
        f"in the first 60 s",
    )


def success_verdicts(runs: Sequence[Mapping[str, Any]]) -> list[Verdict]:
    """Success ≥ 99 % (the share of members whose last message arrived in the window) in
    every valid main run, per contender and N."""
    out = []
    groups: dict[tuple[int, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in main_runs(runs):
        groups[(int(r["n"]), r["contender"])].append(r)
    for (n, c), group in sorted(groups.items(), key=lambda kv: (kv[0][0], _order(kv[0][1]))):
        valid = [r for r in group if r.get("valid") and r.get("success_rate") is not None]
        if not valid:
            out.append(
                Verdict(
                    "success",
                    n,
                    c,
                    None,
                    f"N={n}, {c}: {_word(None)}: no valid run with a success measure "
                    f"({len(group)} run(s), {sum(1 for r in group if r.get('valid'))} valid)",
                )
            )
            continue
        rates = [float(r["success_rate"]) for r in valid]
        low = [r for r in valid if float(r["success_rate"]) < SUCCESS_TARGET]
        met = not low
        how = f"{len(valid) - len(low)} of {_count(len(valid), 'valid run', 'valid runs')} ≥ 99 %"
        if not met:
            worst = min(low, key=lambda r: float(r["success_rate"]))
            failed = len(worst.get("failed_members") or [])
            nth = (worst.get("setup") or {}).get("messages", "last")
            how += (
                f"; worst r{worst['run']}: {failed} of {int(worst['n']) - 1} members' message "
                f"{nth} never reached the commander in the window"
            )
        out.append(
            Verdict(
                "success",
                n,
                c,
                met,
                f"N={n}, {c}: {_word(met)}, {how} (members {_range(rates, '.0f', 100, ' %')})",
            )
        )
    return out


def coverage_verdicts(runs: Sequence[Mapping[str, Any]]) -> list[Verdict]:
    """Every stock contender has valid runs at N = 10 and 20 (at its main k)."""
    out = []
    main = main_runs(runs)
    for c in STOCK:
        counts = []
        for n in COVERAGE_N:
            group = [r for r in main if r["contender"] == c and int(r["n"]) == n]
            valid = sum(1 for r in group if r.get("valid"))
            text = (
                f"N={n}: {valid} valid of {len(group)} at k = {dilation(group[0]):g}"
                if group
                else f"N={n}: no run"
            )
            counts.append((n, valid, text))
        met = all(valid > 0 for _, valid, _ in counts)
        out.append(
            Verdict(
                "coverage", None, c, met, f"{c}: {_word(met)}; " + "; ".join(t for *_, t in counts)
            )
        )
    return out


def repeat_lines(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown list: each main (contender, N) with fewer valid repeats than planned."""
    lines = []
    for r in sorted(main_rows(rows), key=lambda r: (r["n"], _order(r["contender"]))):
        valid, total = r["valid_runs"], r["runs"]
        if valid >= REPEATS_PLANNED:
            continue
        if total == 1:
            what = "1 run only" + ("" if valid else ", invalid")
        else:
            what = f"{valid} of {total} repeats valid"
            if total < REPEATS_PLANNED:
                what += f", {REPEATS_PLANNED - total} not run"
        lines.append(f"- {r['contender']} N={r['n']} k={r['k']:g}: {what}\n")
    return "".join(lines) or f"none: every contender and N has {REPEATS_PLANNED} valid repeats\n"


def _nth(runs: Sequence[Mapping[str, Any]]) -> str:
    counts = sorted({int((r.get("setup") or {}).get("messages", 0)) for r in runs} - {0})
    return "last" if len(counts) != 1 else f"last ({counts[0]}th)"


def verdicts_markdown(runs: Sequence[Mapping[str, Any]]) -> str:
    """The "Against the targets" list, computed (issue 13, "Done when")."""
    peak = peak_verdicts(runs)
    disc = discovery_verdict(runs)
    succ = success_verdicts(runs)
    cover = coverage_verdicts(runs)

    def tally(vs: Sequence[Verdict]) -> str:
        met = sum(1 for v in vs if v.met is True)
        not_met = sum(1 for v in vs if v.met is False)
        unknown = sum(1 for v in vs if v.met is None)
        return f"met {met}, not met {not_met}, not known {unknown}"

    parts = [
        "- **swarmd's peak ≤ 5 % of each stock stack's in the same run** (busiest second of "
        "all frames on the channel, ACKs included; per N and stock stack; "
        f"{tally(peak)}):\n",
        *(f"  - {v.text}\n" for v in peak),
        f"- **≤ {DISCOVERY_TARGET} discovery frames in the first 60 s at N={DISCOVERY_TARGET_N}**"
        f" (swarmd): {disc.text}\n",
        f"- **success ≥ 99 %** (share of the members whose {_nth(runs)} message reached the "
        f"commander in the window, in every valid run; per contender and N; {tally(succ)}):\n",
        *(f"  - {v.text}\n" for v in succ),
        f"- **every stock contender has valid runs at N = 10 and 20** ({tally(cover)}):\n",
        *(f"  - {v.text}\n" for v in cover),
    ]
    return "".join(parts)
