"""Summary, plots and the markdown tables from the per-run JSON files of ``run.py``.

    .venv/bin/python bench/wifi/report.py [OUT] [--docs docs/benchmarks.md]

Reads ``OUT/runs/*.json`` only (runs set aside in ``OUT/superseded/`` are never read) and
writes ``OUT/summary.json``, ``OUT/table.md``, ``OUT/fig10a_pps.png`` (frames/s over the
first 60 s at N = 10, every contender on one axis; paper Figure 10a), the same at every N
(``fig10a_pps_n<N>.png``) and ``OUT/fig11_success.png`` (success against N; paper Figure
11). Invalid runs (real-time lag over the bound, in experiment time) are counted and listed
but left out of every figure and median.

``--docs FILE`` also rewrites the block between ``<!-- wifi:begin ...-->`` and
``<!-- wifi:end -->`` in FILE: the tables, and the verdicts on issue 13's targets computed
from the runs (met, not met, or not known, with the numbers and how many runs or pairs
say so). Everything outside the markers is left byte for byte.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script, too

from bench.wifi.report_data import (  # noqa: E402
    CLASSES,
    PAPER_PEAK,
    PAPER_TABLE4,
    PEAK_TARGET,
    REPEATS_PLANNED,
    SESSION2,
    STOCK,
    _fmt,
    _median_run,
    _order,
    _ratio,
    _spread,
    _success_cell,
    commit,
    dilation,
    load_runs,
    main_k,
    main_rows,
    main_runs,
    paired_ratios,
    summarise,
)
from bench.wifi.report_plots import (  # noqa: E402
    plots,
)
from bench.wifi.report_ros2 import ros2_markdown  # noqa: E402
from bench.wifi.report_verdicts import (  # noqa: E402
    Verdict,
    coverage_verdicts,
    discovery_verdict,
    peak_verdicts,
    repeat_lines,
    success_verdicts,
    verdicts_markdown,
)

# The docs block (docs/benchmarks.md, "Wireless testbed"): ``--docs`` rewrites what lies
# between these two markers and nothing else (the flood section's pattern, bench/flood.py).
DOCS_BEGIN: Final = "<!-- wifi:begin"
DOCS_END: Final = "<!-- wifi:end -->"


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: per (contender, N) over valid runs, medians (range), and swarmd's ratios
    to each stock stack with the paper's beside."""
    lines = [
        "| contender | N | k | valid/runs | peak frames/s median (range) "
        "| discovery frames 60 s median (range) "
        "| success | all discovered s (median / max) | MAC drop % | PHY drop % | retx % "
        "| lag p99 max ms (valid) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['contender']} | {r['n']} | {r['k']:g} | {r['valid_runs']}/{r['runs']} "
            f"| {_spread(r, 'peak_pps')} | {_spread(r, 'discovery_frames_60s')} "
            f"| {_success_cell(r)} "
            f"| {_fmt(r.get('all_discovered_s_median'), '.2f')} "
            f"/ {_fmt(r['all_discovered_s_max'], '.2f')} "
            f"| {_fmt(r['mac_drop_ratio'], '.1f', 100)} "
            f"| {_fmt(r['phy_drop_density'], '.1f', 100)} "
            f"| {_fmt(r['retx_ratio'], '.1f', 100)} "
            f"| {_fmt(r.get('rt_lag_p99_ms_valid_max'), '.1f')} |"
        )
    stock = [c for c in STOCK if any(r["contender"] == c for r in rows)]
    head = " | ".join(f"peak swarmd / {c}" for c in stock)
    head2 = " | ".join(f"discovery 60 s swarmd / {c}" for c in stock)
    paper = " / ".join(
        f"{_ratio(PAPER_PEAK['swarmd'][0], PAPER_PEAK[c][0])} ({c})"
        for c in ("fastdds", "cyclonedds")
    )
    ratio_lines = [
        "",
        f"| N | k (swarmd) | {head} | {head2} |",
        "|---:|---:|" + "---:|" * (2 * len(stock)),
    ]
    main = {(r["contender"], r["n"]): r for r in main_rows(rows)}
    for n in sorted({r["n"] for r in rows}):
        s = main.get(("swarmd", n))
        if s is None:
            continue
        cells = []
        for key in ("peak_pps_median", "discovery_frames_60s_median"):
            for c in stock:
                o = main.get((c, n))
                cell = _ratio(s.get(key), None if o is None else o.get(key))
                if o is not None and o["k"] != s["k"] and cell != "-":
                    cell += f" (k {o['k']:g})"
                cells.append(cell)
        ratio_lines.append(f"| {n} | {s['k']:g} | " + " | ".join(cells) + " |")
    ratio_lines.append("")
    ratio_lines.append(
        "Ratios of medians over each contender's valid runs at its main k: across runs and "
        "campaigns, not pairs (the same-run pairs are the next table). "
        "The paper (Table 5, 10 real UAVs, mean peak): "
        f"swarmd / Fast DDS, swarmd / Cyclone = {paper}."
    )
    return "\n".join(lines + ratio_lines) + "\n"


def _cell(xs: list[float]) -> str:
    if not xs:
        return "-"
    return f"{100 * statistics.median(xs):.1f} % ({100 * min(xs):.1f}-{100 * max(xs):.1f})"


def paired_table(runs: Sequence[Mapping[str, Any]], *, include_invalid: bool = False) -> str:
    """Markdown: median (min-max) of the per-repeat ratios swarmd / each stock stack. The
    last ratio column, discovery frames alone in their busiest second, is a secondary view:
    the target is on all frames."""
    stock = [c for c in STOCK if any(r["contender"] == c for r in runs)]
    lines = [
        "| N | k | stock stack | pairs | peak swarmd / stock median (range) "
        "| discovery 60 s swarmd / stock | peak target ≤ 5 % "
        "| secondary: peak discovery frames/s swarmd / stock |",
        "|---:|---:|---|---:|---:|---:|---|---:|",
    ]
    keys = sorted({(int(r["n"]), dilation(r)) for r in runs if r["contender"] == "swarmd"})
    for n, k in keys:
        for c in stock:
            peak = paired_ratios(runs, c, "peak_pps", include_invalid=include_invalid)
            disc = paired_ratios(runs, c, "discovery_frames_60s", include_invalid=include_invalid)
            pdisc = paired_ratios(runs, c, "peak_discovery_pps", include_invalid=include_invalid)
            p, d = peak.get((n, k), []), disc.get((n, k), [])
            if not p:
                continue
            met = (
                "met in every pair"
                if max(p) <= PEAK_TARGET
                else (f"not met ({sum(1 for x in p if x > PEAK_TARGET)}/{len(p)} pairs over)")
            )
            lines.append(
                f"| {n} | {k:g} | {c} | {len(p)} | {_cell(p)} | {_cell(d)} | {met} "
                f"| {_cell(pdisc.get((n, k), []))} |"
            )
    return "\n".join(lines) + "\n"


def table4(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: the paper's Table 4 (ns-3, its setup) beside ours (medians, valid runs)."""
    lines = [
        "| contender | N | PHY drop % ours / paper | MAC drop % ours / paper "
        "| retx % ours / paper |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        paper = PAPER_TABLE4.get(r["contender"], {}).get(r["n"])
        if r["valid_runs"] == 0:
            continue

        def both(
            key: str,
            i: int,
            row: Mapping[str, Any] = r,
            ref: tuple[float, float, float] | None = paper,
        ) -> str:
            ours = _fmt(row[key], ".1f", 100)
            return f"{ours} / {'-' if ref is None else f'{ref[i]:.1f}'}"

        lines.append(
            f"| {r['contender']} | {r['n']} | {both('phy_drop_density', 0)} "
            f"| {both('mac_drop_ratio', 1)} | {both('retx_ratio', 2)} |"
        )
    return "\n".join(lines) + "\n"


def table5(rows: Sequence[Mapping[str, Any]], n: int = 10) -> str:
    """Markdown: the paper's Table 5 (10 real UAVs, peak packets/s) beside ours at N."""
    lines = [
        f"| contender | peak frames/s ours, N = {n} (median, range) "
        "| peak discovery frames/s ours | paper Table 5 peak packets/s mean ± sd (10 UAVs) |",
        "|---|---:|---:|---:|",
    ]
    for r in rows:
        if r["n"] != n or r["valid_runs"] == 0:
            continue
        paper = PAPER_PEAK.get(r["contender"])
        cell = "-" if paper is None else f"{paper[0]:.1f} ± {paper[1]:.1f}"
        lines.append(
            f"| {r['contender']} | {_spread(r, 'peak_pps')} "
            f"| {_spread(r, 'peak_discovery_pps')} | {cell} |"
        )
    return "\n".join(lines) + "\n"


def validation_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: the dilation check, k = 1 against the main k at the same N (both valid)."""
    lines = [
        "| contender | N | k | valid/runs | peak frames/s | discovery frames 60 s "
        "| all discovered s | success | MAC drop % | retx % | lag p99 max ms |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    by_n: dict[tuple[str, int], list[Mapping[str, Any]]] = defaultdict(list)
    for r in rows:
        by_n[(r["contender"], r["n"])].append(r)
    for (_, _n), group in sorted(by_n.items(), key=lambda kv: (kv[0][1], _order(kv[0][0]))):
        if len({r["k"] for r in group}) < 2:
            continue
        for r in sorted(group, key=lambda r: r["k"]):
            lines.append(
                f"| {r['contender']} | {r['n']} | {r['k']:g} | {r['valid_runs']}/{r['runs']} "
                f"| {_spread(r, 'peak_pps')} | {_spread(r, 'discovery_frames_60s')} "
                f"| {_fmt(r.get('all_discovered_s_median'), '.2f')} | {_success_cell(r)} "
                f"| {_fmt(r['mac_drop_ratio'], '.1f', 100)} "
                f"| {_fmt(r['retx_ratio'], '.1f', 100)} "
                f"| {_fmt(r['rt_lag_p99_ms_max'], '.1f')} |"
            )
    return "\n".join(lines) + "\n"


def invalid_runs(runs: Sequence[Mapping[str, Any]]) -> str:
    """Markdown list of every run left out, and why."""
    bad = [r for r in runs if not r.get("valid")]
    if not bad:
        return "none\n"
    return "".join(
        f"- {r['contender']} N={r['n']} k={dilation(r):g} r{r['run']}: {r.get('invalid_reason')}\n"
        for r in sorted(bad, key=lambda r: (r["n"], dilation(r), _order(r["contender"])))
    )


BREAKDOWN_KEYS: Final = ("announce", "reply", "renewal", "dispose", "tx_multicast", "tx_unicast")


def breakdown_table(runs: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: where swarmd's discovery frames go (daemon send counters + channel ACKs)."""
    lines = [
        "| contender | N | k | run | discovery frames 60 s | data frames | ACKs | SPDP sent: "
        "announce | reply | renewal | dispose | multicast | unicast |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in sorted(runs, key=lambda r: (r["contender"], r["n"], dilation(r), r["run"])):
        tx = r.get("tx_counters") or {}
        split = r.get("discovery_breakdown_60s") or {}
        if not r.get("valid") or not tx:
            continue
        lines.append(
            f"| {r['contender']} | {r['n']} | {dilation(r):g} | {r['run']} "
            f"| {r['discovery_frames_60s']} "
            f"| {split.get('data_frames', '-')} | {split.get('acks', '-')} | "
            + " | ".join(str(tx.get(k, "-")) for k in BREAKDOWN_KEYS)
            + " |"
        )
    return "\n".join(lines) + "\n"


def _started(r: Mapping[str, Any]) -> float | None:
    at = (r.get("setup") or {}).get("started_at")
    return float(at) if isinstance(at, int | float) else None


def _utc(at: float, spec: str) -> str:
    return time.strftime(spec, time.gmtime(at))


def _repeats(nums: Sequence[int]) -> str:
    """``r1-3`` for a run of consecutive repeats, else ``r1, r3``."""
    ordered = sorted(set(nums))
    if len(ordered) > 1 and ordered == list(range(ordered[0], ordered[-1] + 1)):
        return f"r{ordered[0]}-{ordered[-1]}"
    return ", ".join(f"r{x}" for x in ordered)


def commit_lines(runs: Sequence[Mapping[str, Any]]) -> str:
    """Markdown list: which commit each run measured, with the runs' start times and what
    they were (per N and k, contender and repeats)."""
    by_commit: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
    for r in runs:
        by_commit[commit(r)].append(r)

    def first(item: tuple[str, list[Mapping[str, Any]]]) -> float:
        return min((_started(r) or math.inf for r in item[1]), default=math.inf)

    lines = []
    for made_by, group in sorted(by_commit.items(), key=first):
        starts = sorted(t for t in (_started(r) for r in group) if t is not None)
        when = ""
        if starts:
            last = _utc(starts[-1], "%H:%M")
            first_at = _utc(starts[0], "%Y-%m-%d %H:%M")
            when = f", {first_at} UTC" if first_at.endswith(last) else f", {first_at}-{last} UTC"
        cells: dict[tuple[int, float], dict[str, list[int]]] = defaultdict(
            lambda: defaultdict(list)
        )
        for r in group:
            cells[(int(r["n"]), dilation(r))][r["contender"]].append(int(r["run"]))
        what = "; ".join(
            f"N={n} k={k:g}: "
            + ", ".join(
                f"{c} {_repeats(reps)}"
                for c, reps in sorted(by_c.items(), key=lambda kv: _order(kv[0]))
            )
            for (n, k), by_c in sorted(cells.items())
        )
        name = SESSION2 if made_by == "session-2" else f"at `{made_by}`"
        runs_word = "run" if len(group) == 1 else "runs"
        loads = [float(r["load_avg_at_start"][0]) for r in group if r.get("load_avg_at_start")]
        load = (
            f", 1-min load average {min(loads):.1f}-{max(loads):.1f} when each run was assembled"
            if loads
            else ""
        )
        lines.append(f"- {name}: {len(group)} {runs_word}{when}{load} ({what})")
    return "\n".join(lines) + "\n"


def peak_composition(r: Mapping[str, Any]) -> tuple[int, dict[str, int]]:
    """The run's busiest second (its index in the window, the first if tied) and how its
    frames split over the channel's classes. ``peak_pps`` counts every PHY transmission in
    that second; ``class_pps`` has the same frames with each ACK in the class of the frame it
    answers, so the classes sum to the peak (a remainder, if any, is ``unclassified``)."""
    pps: list[int] = list(r["pps"])
    second = max(range(len(pps)), key=lambda t: (pps[t], -t))
    classes: Mapping[str, Sequence[int]] = r.get("class_pps") or {}
    split = {c: int(series[second]) for c, series in classes.items() if second < len(series)}
    rest = int(pps[second]) - sum(split.values())
    if rest:
        split["unclassified"] = rest
    return second, split


def class_table(runs: Sequence[Mapping[str, Any]], sizes: Sequence[int] = (10, 20)) -> str:
    """Markdown: the busiest second of each contender at N (main k, valid runs), split by
    frame class, from the repeat whose peak is the median."""
    main = [r for r in main_runs(runs) if r.get("valid") and int(r["n"]) in sizes]
    present = [c for c in CLASSES if any(c in (r.get("class_pps") or {}) for r in main)]
    if any("unclassified" in peak_composition(r)[1] for r in main):
        present.append("unclassified")
    lines = [
        "| contender | N | k | repeat shown (valid runs) | second | peak frames/s | "
        + " | ".join(present)
        + " |",
        "|---|---:|---:|---:|---:|---:|" + "---:|" * len(present),
    ]
    groups: dict[tuple[int, str], list[Mapping[str, Any]]] = defaultdict(list)
    for r in main:
        groups[(int(r["n"]), r["contender"])].append(r)
    for (n, c), group in sorted(groups.items(), key=lambda kv: (kv[0][0], _order(kv[0][1]))):
        r = _median_run(group)
        second, split = peak_composition(r)
        peak = max(1, int(r["pps"][second]))
        cells = " | ".join(
            f"{split[k]} ({100 * split[k] / peak:.0f} %)" if k in split else "-" for k in present
        )
        lines.append(
            f"| {c} | {n} | {dilation(r):g} | r{r['run']} ({len(group)}) | {second} "
            f"| {r['pps'][second]} | {cells} |"
        )
    return "\n".join(lines) + "\n"


def tables_markdown(runs: Sequence[Mapping[str, Any]]) -> str:
    """Every table of the report (``OUT/table.md``, and the docs block's tables)."""
    rows = summarise(runs)
    main = main_rows(rows)
    return (
        "Main table (each contender and N at its main dilation k; valid runs only):\n\n"
        + table(main)
        + "\nswarmd / stock stack within the same run (pairs: same N, k, repeat and commit, "
        "both valid; every k, so N=5 has its k = 1 and k = 3 pairs):\n\n"
        + paired_table(runs)
        + "\nBusiest second, by class (each contender at its main k; the repeat whose peak "
        "is the median of its valid runs; share of the peak in brackets):\n\n"
        + class_table(runs)
        + "\n`peak_pps` counts every PHY transmission in the second, ACKs included "
        "(bench/wifi/metrics.py `frame_series` with no class filter). The channel "
        "(bench/wifi/channel_cpp.py `Classify`) classes each data frame as RTPS discovery "
        "(a builtin SPDP/SEDP entity) or RTPS user data, zenoh (any TCP, or UDP 7446/7447) or "
        "other (ARP, IGMP, non-RTPS UDP); an ACK goes to the class of the last frame its sender "
        "received (`metrics.class_series`), so the classes sum to the peak. The target is "
        "on all frames; the last column of the pair table above, discovery frames alone, is "
        "a secondary view.\n"
        + "\nThe paper's Table 5 beside ours:\n\n"
        + table5(main)
        + "\nThe paper's Table 4 beside ours:\n\n"
        + table4(main)
        + "\nDilation check (the same contender and N at more than one k):\n\n"
        + validation_table(rows)
        + "\n### Runs left out\n\nLag bound exceeded, in experiment time; never averaged:\n\n"
        + invalid_runs(runs)
        + "\nswarmd's discovery frames, per valid run:\n\n"
        + breakdown_table(runs)
        + ros2_markdown(runs)
    )


def docs_block(runs: Sequence[Mapping[str, Any]], out_label: str) -> str:
    """The generated part of docs/benchmarks.md's "Wireless testbed" section."""
    rows = summarise(runs)
    command = f".venv/bin/python bench/wifi/report.py {out_label} --docs docs/benchmarks.md"
    return (
        f"Generated by `{command}` from the {len(runs)} run files in `{out_label}/runs/` "
        "(`superseded/` beside it is not read). Everything down to the end marker is "
        "rewritten by that command: change `bench/wifi/report.py`, not this text "
        "(`tests/test_wifi_report.py` fails when the text and the run files disagree).\n\n"
        "Which code each run measured (`setup.commit` in the run file; start times UTC):\n\n"
        + commit_lines(runs)
        + "\n### Against the targets (issue 13), computed from the runs\n\n"
        "Valid runs only. The peak target is judged on pairs: swarmd and a stock stack at "
        "the same N, k, repeat and commit, both valid (the two ran back to back in one "
        "campaign step), at any k (named); the other targets on each contender and N at its "
        "main k (the dilation with the most valid runs). Met means in every pair or run "
        "listed, however few.\n\n"
        + verdicts_markdown(runs)
        + f"\nFewer than {REPEATS_PLANNED} valid repeats (the plan is {REPEATS_PLANNED} per "
        "contender and N):\n\n"
        + repeat_lines(rows)
        + f"\n### Tables (`{out_label}/table.md` holds the same)\n\n"
        + tables_markdown(runs)
        + f"\nPlots: `{out_label}/fig10a_pps.png` (frames/s over the first 60 s at N=10, every "
        "contender on one axis, log scale, paper Fig. 10a; thin lines each valid run, thick "
        "the median repeat; `fig10a_pps_n<N>.png` the same at every N) and "
        f"`{out_label}/fig11_success.png` (share of members whose last message arrived, "
        "against N, median and range over valid runs; paper Fig. 11). Each contender and N "
        "at its main k, named in the legends.\n"
    )


def replace_block(text: str, block: str) -> str:
    """``text`` with what lies between the wifi markers replaced by ``block``; the marker
    lines and everything outside them are kept byte for byte."""
    start = text.find(DOCS_BEGIN)
    if start < 0:
        raise ValueError(f"no {DOCS_BEGIN} ... --> marker")
    body = text.find("-->", start) + len("-->")
    end = text.find(DOCS_END, body)
    if body < len("-->") or end < 0:
        raise ValueError(f"no {DOCS_END} after {DOCS_BEGIN}")
    if text.find(DOCS_BEGIN, body) >= 0:
        raise ValueError(f"more than one {DOCS_BEGIN} marker")
    return text[:body] + "\n" + block.strip("\n") + "\n" + text[end:]


def write_docs(docs: Path, runs: Sequence[Mapping[str, Any]], out_label: str) -> None:
    """Rewrite the wifi block of ``docs``; bytes, so line endings outside it stay as they are."""
    text = docs.read_bytes().decode("utf-8")
    docs.write_bytes(replace_block(text, docs_block(runs, out_label)).encode("utf-8"))


def write_report(out: Path) -> list[Path]:
    """Summary JSON, markdown tables and plots for every run under ``out/runs``."""
    runs = load_runs(out)
    (out / "summary.json").write_text(json.dumps(summarise(runs), indent=1) + "\n")
    (out / "table.md").write_text(tables_markdown(runs))
    return [out / "summary.json", out / "table.md", *plots(runs, out)]


def one_line(r: Mapping[str, Any]) -> str:
    """A run in one console line."""
    succ = r.get("success_rate")
    return (
        f"{r['contender']:>15} n={r['n']:<3} k={dilation(r):g} run {r['run']}: "
        f"peak {r['peak_pps']} f/s, "
        f"discovery frames {r['discovery_frames_60s']}, "
        f"all discovered {r.get('all_discovered_s')} s, "
        f"success {'pending' if succ is None else f'{100 * succ:.0f} %'}, "
        f"lag p99 {r['rt_lag_p99_ms']:.1f} ms{'' if r['valid'] else ' INVALID'}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "out",
        nargs="?",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "results" / "wifi",
        help="the run.py --out directory (its runs/ is read)",
    )
    p.add_argument(
        "--docs",
        type=Path,
        default=None,
        help="also rewrite the wifi:begin/wifi:end block of this markdown file",
    )
    args = p.parse_args(argv)
    try:
        for path in write_report(args.out):
            print(path)
        if args.docs is not None:
            write_docs(args.docs, load_runs(args.out), _label(args.out))
            print(args.docs)
    except ValueError as exc:
        print(f"report: {exc}", file=sys.stderr)
        return 2
    return 0


def _label(out: Path) -> str:
    """``out`` as the docs should name it: relative to the repository when inside it."""
    repo = Path(__file__).resolve().parents[2]
    try:
        return str(out.resolve().relative_to(repo))
    except ValueError:
        return str(out)


# callers (run.py, the tests) use one module: the report's names, wherever they are defined
__all__ = [
    "SESSION2",
    "Verdict",
    "class_table",
    "commit_lines",
    "coverage_verdicts",
    "discovery_verdict",
    "docs_block",
    "load_runs",
    "main_k",
    "main_rows",
    "one_line",
    "paired_ratios",
    "peak_composition",
    "peak_verdicts",
    "repeat_lines",
    "replace_block",
    "success_verdicts",
    "summarise",
    "write_docs",
    "write_report",
]


if __name__ == "__main__":
    sys.exit(main())
