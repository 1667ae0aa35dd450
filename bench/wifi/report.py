"""Summary, plots and the markdown table from the per-run JSON files of ``run.py``.

    .venv/bin/python bench/wifi/report.py [OUT]      # default bench/results/wifi

Writes ``OUT/summary.json``, ``OUT/table.md``, ``OUT/fig10a_pps.png`` (frames/s over the
first 60 s, mean over valid runs; paper Figure 10a) and ``OUT/fig11_success.png``
(success rate against N; paper Figure 11). Invalid runs (real-time lag over the bound)
are counted but left out of every figure.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

# Paper Table 5 (peak discovery traffic, packets/s, real-world 10 UAVs) and Table 4.
PAPER_PEAK: Final = {"cyclonedds": (852.89, 1312.24), "swarmd": (61.11, 110.19)}
PAPER_TABLE4: Final = {  # N: (R_drop_PHY %, R_drop_MAC %, R_retx_PHY %)
    "cyclonedds": {5: (13.22, 1.98, 72.03), 10: (33.90, 17.07, 72.93), 15: (59.90, 39.70, 66.37),
                   20: (86.90, 55.40, 56.07)},
    "swarmd": {5: (5.17, 2.20, 71.63), 10: (10.07, 13.03, 76.67), 15: (16.33, 25.77, 76.90),
               20: (27.67, 36.70, 76.57)},
}  # fmt: skip


def load_runs(out: Path) -> list[dict[str, Any]]:
    runs = []
    for path in sorted((out / "runs").glob("*.json")):
        runs.append(json.loads(path.read_text()))
    return runs


def _mean(xs: Iterable[float | None]) -> float | None:
    vals = [float(x) for x in xs if isinstance(x, int | float) and not math.isnan(x)]
    return statistics.fmean(vals) if vals else None


def _std(xs: Iterable[float | None]) -> float | None:
    vals = [float(x) for x in xs if isinstance(x, int | float) and not math.isnan(x)]
    return statistics.stdev(vals) if len(vals) > 1 else (0.0 if vals else None)


def _median(xs: Iterable[float | None]) -> float | None:
    vals = [float(x) for x in xs if isinstance(x, int | float) and not math.isnan(x)]
    return statistics.median(vals) if vals else None


def _max(xs: Iterable[float | None]) -> float | None:
    vals = [float(x) for x in xs if isinstance(x, int | float) and not math.isnan(x)]
    return max(vals) if vals else None


def summarise(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (contender, N) over its valid runs."""
    groups: dict[tuple[str, int], list[Mapping[str, Any]]] = defaultdict(list)
    for r in runs:
        groups[(r["contender"], int(r["n"]))].append(r)
    rows = []
    for (contender, n), group in sorted(groups.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        valid = [r for r in group if r.get("valid")]
        succ = [r["success"] for r in valid if r.get("success") is not None]
        rows.append(
            {
                "contender": contender,
                "n": n,
                "runs": len(group),
                "valid_runs": len(valid),
                "peak_pps_mean": _mean(r["peak_pps"] for r in valid),
                "peak_pps_std": _std(r["peak_pps"] for r in valid),
                "peak_pps_median": _median(r["peak_pps"] for r in valid),
                "peak_discovery_pps_mean": _mean(r["peak_discovery_pps"] for r in valid),
                "discovery_frames_60s_mean": _mean(r["discovery_frames_60s"] for r in valid),
                "discovery_frames_60s_median": _median(r["discovery_frames_60s"] for r in valid),
                "success_rate": (sum(1 for s in succ if s) / len(succ)) if succ else None,
                "member_success_mean": _mean(r.get("success_rate") for r in valid),
                "all_discovered_s_mean": _mean(r.get("all_discovered_s") for r in valid),
                "all_discovered_s_max": _max(r.get("all_discovered_s") for r in valid),
                "all_discovered_s_median": _median(r.get("all_discovered_s") for r in valid),
                "mac_drop_ratio": _mean(r.get("mac_drop_ratio") for r in valid),
                "phy_drop_density": _mean(r.get("phy_drop_density") for r in valid),
                "retx_ratio": _mean(r.get("retx_ratio") for r in valid),
                "rt_lag_p99_ms_max": _max(r.get("rt_lag_p99_ms") for r in group),
                "invalid": [
                    f"r{r['run']}: {r.get('invalid_reason')}" for r in group if not r.get("valid")
                ],
                "notes": sorted({r["note"] for r in group if r.get("note")}),
            }
        )
    return rows


def _fmt(x: float | None, spec: str = ".0f", scale: float = 1.0) -> str:
    return "-" if x is None else f"{x * scale:{spec}}"


def _ratio(a: float | None, b: float | None) -> str:
    return "-" if a is None or not b else f"{100 * a / b:.1f} %"


def _success_cell(row: Mapping[str, Any]) -> str:
    if row["success_rate"] is not None:
        return f"{100 * row['success_rate']:.0f} %"
    return "pending workload" if row["valid_runs"] else "-"


def table(rows: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: the per-(contender, N) table and the swarmd ratios, paper beside."""
    lines = [
        "| contender | N | valid/runs | peak frames/s mean ± sd (median) "
        "| discovery frames 60 s mean (median) "
        "| success | all discovered s (median / max) | MAC drop % | PHY drop % | retx % "
        "| lag p99 max ms |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['contender']} | {r['n']} | {r['valid_runs']}/{r['runs']} "
            f"| {_fmt(r['peak_pps_mean'])} ± {_fmt(r['peak_pps_std'])} "
            f"({_fmt(r.get('peak_pps_median'))}) "
            f"| {_fmt(r['discovery_frames_60s_mean'])} "
            f"({_fmt(r.get('discovery_frames_60s_median'))}) "
            f"| {_success_cell(r)} "
            f"| {_fmt(r.get('all_discovered_s_median'), '.2f')} "
            f"/ {_fmt(r['all_discovered_s_max'], '.2f')} "
            f"| {_fmt(r['mac_drop_ratio'], '.1f', 100)} "
            f"| {_fmt(r['phy_drop_density'], '.1f', 100)} "
            f"| {_fmt(r['retx_ratio'], '.1f', 100)} | {_fmt(r['rt_lag_p99_ms_max'], '.1f')} |"
        )
    by = {(r["contender"], r["n"]): r for r in rows}
    ratio_lines = [
        "",
        "| N | peak frames/s swarmd / Cyclone | swarmd / zenoh | discovery frames 60 s "
        "swarmd / Cyclone | swarmd / zenoh | paper (Table 5, 10 UAVs, peak) swarmd / Cyclone |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    paper = _ratio(PAPER_PEAK["swarmd"][0], PAPER_PEAK["cyclonedds"][0])
    for n in sorted({r["n"] for r in rows}):
        s, c, z = by.get(("swarmd", n)), by.get(("cyclonedds", n)), by.get(("zenoh", n))
        if s is None:
            continue

        def get(row: Mapping[str, Any] | None, key: str) -> float | None:
            return None if row is None else row.get(key)

        ratio_lines.append(
            f"| {n} | {_ratio(get(s, 'peak_pps_mean'), get(c, 'peak_pps_mean'))} "
            f"| {_ratio(get(s, 'peak_pps_mean'), get(z, 'peak_pps_mean'))} "
            f"| {_ratio(get(s, 'discovery_frames_60s_mean'), get(c, 'discovery_frames_60s_mean'))} "
            f"| {_ratio(get(s, 'discovery_frames_60s_mean'), get(z, 'discovery_frames_60s_mean'))} "
            f"| {paper} |"
        )
    return "\n".join(lines + ratio_lines) + "\n"


def paired_ratios(
    runs: Sequence[Mapping[str, Any]], other: str, key: str, *, include_invalid: bool = False
) -> dict[int, list[float]]:
    """Per N, swarmd / ``other`` of ``key`` within each repeat where both runs are valid
    (the two ran back to back under the same machine load); ``include_invalid`` pairs
    lagging runs too (indicative only, never the headline)."""
    valid = {
        (r["contender"], int(r["n"]), int(r["run"])): r
        for r in runs
        if r.get("valid") or include_invalid
    }
    out: dict[int, list[float]] = defaultdict(list)
    for (contender, n, run), r in sorted(valid.items()):
        o = valid.get((other, n, run))
        if contender == "swarmd" and o is not None and o.get(key):
            out[n].append(float(r[key]) / float(o[key]))
    return dict(out)


def paired_table(runs: Sequence[Mapping[str, Any]], *, include_invalid: bool = False) -> str:
    """Markdown: median (min-max) of the per-repeat ratios swarmd / Cyclone and / zenoh."""
    lines = [
        "| N | pairs | peak swarmd / Cyclone median (range) | discovery 60 s swarmd / Cyclone "
        "| pairs | peak swarmd / zenoh | discovery 60 s swarmd / zenoh |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def cell(xs: list[float]) -> str:
        if not xs:
            return "-"
        return f"{100 * statistics.median(xs):.1f} % ({100 * min(xs):.1f}-{100 * max(xs):.1f})"

    sizes = sorted({int(r["n"]) for r in runs if r["contender"] == "swarmd"})
    for n in sizes:

        def pr(other: str, key: str, size: int = n) -> list[float]:
            found = paired_ratios(runs, other, key, include_invalid=include_invalid)
            return found.get(size, [])

        cp, cd = pr("cyclonedds", "peak_pps"), pr("cyclonedds", "discovery_frames_60s")
        zp, zd = pr("zenoh", "peak_pps"), pr("zenoh", "discovery_frames_60s")
        lines.append(
            f"| {n} | {len(cp)} | {cell(cp)} | {cell(cd)} | {len(zp)} | {cell(zp)} | {cell(zd)} |"
        )
    return "\n".join(lines) + "\n"


BREAKDOWN_KEYS: Final = ("announce", "reply", "renewal", "dispose", "tx_multicast", "tx_unicast")


def breakdown_table(runs: Sequence[Mapping[str, Any]]) -> str:
    """Markdown: where swarmd's discovery frames go (daemon send counters + channel ACKs)."""
    lines = [
        "| contender | N | run | discovery frames 60 s | data frames | ACKs | SPDP sent: "
        "announce | reply | renewal | dispose | multicast | unicast |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in sorted(runs, key=lambda r: (r["contender"], r["n"], r["run"])):
        tx = r.get("tx_counters") or {}
        split = r.get("discovery_breakdown_60s") or {}
        if not r.get("valid") or not tx:
            continue
        lines.append(
            f"| {r['contender']} | {r['n']} | {r['run']} | {r['discovery_frames_60s']} "
            f"| {split.get('data_frames', '-')} | {split.get('acks', '-')} | "
            + " | ".join(str(tx.get(k, "-")) for k in BREAKDOWN_KEYS)
            + " |"
        )
    return "\n".join(lines) + "\n"


def plots(runs: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """Figure 10a (frames/s over time) and Figure 11 (success rate against N) as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    valid = [r for r in runs if r.get("valid")]
    written = []
    if valid:
        sizes = sorted({int(r["n"]) for r in valid})
        # the N with the most contenders validly measured (the paper's figure is N = 10)
        n_fig = max(
            sizes,
            key=lambda n: (len({r["contender"] for r in valid if r["n"] == n}), n == 10, n),
        )
        fig, ax = plt.subplots(figsize=(7, 4))
        for contender in sorted({r["contender"] for r in valid}):
            series = [r["pps"] for r in valid if r["contender"] == contender and r["n"] == n_fig]
            if not series:
                continue
            length = min(len(s) for s in series)
            mean = [statistics.fmean(s[t] for s in series) for t in range(length)]
            ax.plot(range(length), mean, label=f"{contender} ({len(series)} runs)")
        ax.set_yscale("symlog", linthresh=10)
        ax.set_xlabel("time since the start release (s)")
        ax.set_ylabel("frames/s on the channel (PHY tx incl. ACKs)")
        ax.set_title(f"Channel load during discovery, N = {n_fig} (cf. paper Fig. 10a)")
        ax.legend()
        ax.grid(True, alpha=0.3)
        path = out / "fig10a_pps.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    rows = [r for r in summarise(runs) if r["success_rate"] is not None]
    if rows:
        fig, ax = plt.subplots(figsize=(6, 4))
        for contender in sorted({r["contender"] for r in rows}):
            pts = [(r["n"], 100 * r["success_rate"]) for r in rows if r["contender"] == contender]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=contender)
        ax.set_xlabel("number of UAVs")
        ax.set_ylabel("success rate (%)")
        ax.set_ylim(-5, 105)
        ax.set_title("Commander got the 20th message of every member (cf. paper Fig. 11)")
        ax.legend()
        ax.grid(True, alpha=0.3)
        path = out / "fig11_success.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def write_report(out: Path) -> list[Path]:
    """Summary JSON, markdown table and plots for every run under ``out/runs``."""
    runs = load_runs(out)
    rows = summarise(runs)
    (out / "summary.json").write_text(json.dumps(rows, indent=1) + "\n")
    (out / "table.md").write_text(
        table(rows)
        + "\nswarmd / stock stack within the same repeat (valid pairs only):\n\n"
        + paired_table(runs)
        + "\nThe same including runs over the lag bound (indicative only: ns-3 was behind"
        " real time during the stock stacks' bursts, so their per-second counts are"
        " distorted, in a direction not known):\n\n"
        + paired_table(runs, include_invalid=True)
        + "\nswarmd's discovery frames, per valid run:\n\n"
        + breakdown_table(runs)
    )
    return [out / "summary.json", out / "table.md", *plots(runs, out)]


def one_line(r: Mapping[str, Any]) -> str:
    """A run in one console line."""
    succ = r.get("success_rate")
    return (
        f"{r['contender']:>15} n={r['n']:<3} run {r['run']}: peak {r['peak_pps']} f/s, "
        f"discovery frames {r['discovery_frames_60s']}, "
        f"all discovered {r.get('all_discovered_s')} s, "
        f"success {'pending' if succ is None else f'{100 * succ:.0f} %'}, "
        f"lag p99 {r['rt_lag_p99_ms']:.1f} ms{'' if r['valid'] else ' INVALID'}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    out = Path(args[0]) if args else Path(__file__).resolve().parents[1] / "results" / "wifi"
    for path in write_report(out):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
