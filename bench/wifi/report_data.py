"""The testbed report's data side: run files loaded, summarised per contender, N and
dilation, the main dilation of each N, same-step ratios, and the paper's numbers the tables
quote (``bench/wifi/report.py`` writes the tables, ``report_verdicts.py`` judges the targets,
``report_plots.py`` draws the figures)."""

from __future__ import annotations

import json
import math
import statistics
import sys
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script, too

from bench.wifi.report_ros2 import ROS2  # noqa: E402

# Paper Table 5 (peak discovery traffic, packets/s, real-world 10 UAVs: mean, sd) and
# Table 4 (simulated, N: R_drop_PHY %, R_drop_MAC %, R_retx_PHY %).
PAPER_PEAK: Final = {
    "fastdds": (2593.56, 3948.21),
    "cyclonedds": (852.89, 1312.24),
    "swarmd": (61.11, 110.19),
}


PAPER_TABLE4: Final = {
    "fastdds": {5: (1.82, 30.42, 76.82), 10: (4.87, 86.47, 76.70), 15: (17.60, 91.43, 75.03),
                20: (49.10, 94.00, 72.30)},
    "cyclonedds": {5: (13.22, 1.98, 72.03), 10: (33.90, 17.07, 72.93), 15: (59.90, 39.70, 66.37),
                   20: (86.90, 55.40, 56.07)},
    "swarmd": {5: (5.17, 2.20, 71.63), 10: (10.07, 13.03, 76.67), 15: (16.33, 25.77, 76.90),
               20: (27.67, 36.70, 76.57)},
}  # fmt: skip


# the stock stacks swarmd is compared with, in the order of every table and plot
STOCK: Final = ("cyclonedds", "zenoh", "fastdds", "fastdds-server")


ORDER: Final = ("swarmd", "swarmd-paper", "swarmd-noaware", "swarmd-stock", *STOCK, *ROS2)


PEAK_TARGET: Final = 0.05  # swarmd's peak <= 5 % of each stock stack's, same run (issue 13)


SUCCESS_TARGET: Final = 0.99


DISCOVERY_TARGET: Final = 50  # swarmd's discovery frames in the first 60 s at N = 10


DISCOVERY_TARGET_N: Final = 10


COVERAGE_N: Final = (10, 20)  # every stock contender needs valid runs at these N


REPEATS_PLANNED: Final = 3


# the channel's frame classes (bench/wifi/channel_cpp.py kClsNames; ACKs folded into the
# class they acknowledge by metrics.class_series, so the classes of a second sum to pps)
CLASSES: Final = ("rtps_discovery", "rtps_user", "zenoh", "other", "ack")


SESSION2: Final = "session-2 campaign (or earlier), before commit stamps"


def load_runs(out: Path) -> list[dict[str, Any]]:
    """Every run file under ``out/runs`` (never ``out/superseded``: runs set aside)."""
    runs = []
    for path in sorted((out / "runs").glob("*.json")):
        try:
            runs.append(json.loads(path.read_text()))
        except json.JSONDecodeError as exc:  # a copy taken while run.py wrote it
            raise ValueError(f"{path}: not a complete run file ({exc})") from exc
    return runs


def dilation(r: Mapping[str, Any]) -> float:
    """The run's time-dilation factor (1: real time; runs before dilation existed too)."""
    return float((r.get("setup") or {}).get("dilation", 1.0))


def commit(r: Mapping[str, Any]) -> str:
    """The commit a run was made at (``run.py`` records it since session 3; the session-2
    campaign's runs have none and read as "session-2")."""
    return str((r.get("setup") or {}).get("commit", "session-2"))


def _order(contender: str) -> int:
    return ORDER.index(contender) if contender in ORDER else len(ORDER)


def _vals(xs: Iterable[float | None]) -> list[float]:
    return [float(x) for x in xs if isinstance(x, int | float) and not math.isnan(x)]


def _mean(xs: Iterable[float | None]) -> float | None:
    vals = _vals(xs)
    return statistics.fmean(vals) if vals else None


def _std(xs: Iterable[float | None]) -> float | None:
    vals = _vals(xs)
    return statistics.stdev(vals) if len(vals) > 1 else (0.0 if vals else None)


def _median(xs: Iterable[float | None]) -> float | None:
    vals = _vals(xs)
    return statistics.median(vals) if vals else None


def _min(xs: Iterable[float | None]) -> float | None:
    vals = _vals(xs)
    return min(vals) if vals else None


def _max(xs: Iterable[float | None]) -> float | None:
    vals = _vals(xs)
    return max(vals) if vals else None


def summarise(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (contender, N, dilation k) over its valid runs."""
    groups: dict[tuple[str, int, float], list[Mapping[str, Any]]] = defaultdict(list)
    for r in runs:
        groups[(r["contender"], int(r["n"]), dilation(r))].append(r)
    rows = []
    for (contender, n, k), group in sorted(
        groups.items(), key=lambda kv: (kv[0][1], kv[0][2], _order(kv[0][0]), kv[0][0])
    ):
        valid = [r for r in group if r.get("valid")]
        succ = [r["success"] for r in valid if r.get("success") is not None]

        def col(key: str, rs: Sequence[Mapping[str, Any]] = valid) -> list[float | None]:
            return [r.get(key) for r in rs]

        rows.append(
            {
                "contender": contender,
                "n": n,
                "k": k,
                "runs": len(group),
                "valid_runs": len(valid),
                "peak_pps_mean": _mean(col("peak_pps")),
                "peak_pps_std": _std(col("peak_pps")),
                "peak_pps_median": _median(col("peak_pps")),
                "peak_pps_min": _min(col("peak_pps")),
                "peak_pps_max": _max(col("peak_pps")),
                "peak_discovery_pps_mean": _mean(col("peak_discovery_pps")),
                "peak_discovery_pps_median": _median(col("peak_discovery_pps")),
                "peak_discovery_pps_min": _min(col("peak_discovery_pps")),
                "peak_discovery_pps_max": _max(col("peak_discovery_pps")),
                "discovery_frames_60s_mean": _mean(col("discovery_frames_60s")),
                "discovery_frames_60s_median": _median(col("discovery_frames_60s")),
                "discovery_frames_60s_min": _min(col("discovery_frames_60s")),
                "discovery_frames_60s_max": _max(col("discovery_frames_60s")),
                "success_rate": (sum(1 for s in succ if s) / len(succ)) if succ else None,
                "member_success_mean": _mean(col("success_rate")),
                "member_success_min": _min(col("success_rate")),
                "all_discovered_s_mean": _mean(col("all_discovered_s")),
                "all_discovered_s_max": _max(col("all_discovered_s")),
                "all_discovered_s_median": _median(col("all_discovered_s")),
                "mac_drop_ratio": _median(col("mac_drop_ratio")),
                "phy_drop_density": _median(col("phy_drop_density")),
                "retx_ratio": _median(col("retx_ratio")),
                "rt_lag_p99_ms_max": _max(col("rt_lag_p99_ms", group)),
                "rt_lag_p99_ms_valid_max": _max(col("rt_lag_p99_ms")),
                "invalid": [
                    f"r{r['run']}: {r.get('invalid_reason')}" for r in group if not r.get("valid")
                ],
                "notes": sorted({r["note"] for r in group if r.get("note")}),
            }
        )
    return rows


def main_k(rows: Sequence[Mapping[str, Any]]) -> dict[tuple[str, int], float]:
    """Per (contender, N), the dilation of its main runs: the k with the most valid runs,
    ties to the larger k (else the largest k). At N = 5 that is the undilated repeats, with
    the single dilated run beside them as the method's check; at N = 20 the k every stack
    keeps up at. A k whose runs all lagged stays in the tables of checks and invalid runs,
    never in the main one."""
    out: dict[tuple[str, int], float] = {}
    for r in sorted(rows, key=lambda r: (r["valid_runs"], r["k"])):
        out[(r["contender"], r["n"])] = r["k"]
    return out


def main_rows(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    ks = main_k(rows)
    return [r for r in rows if r["k"] == ks[(r["contender"], r["n"])]]


def main_runs(runs: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The runs of the main rows (each contender and N at its main k)."""
    ks = main_k(summarise(runs))
    return [r for r in runs if dilation(r) == ks.get((r["contender"], int(r["n"])))]


def _fmt(x: float | None, spec: str = ".0f", scale: float = 1.0) -> str:
    return "-" if x is None else f"{x * scale:{spec}}"


def _ratio(a: float | None, b: float | None) -> str:
    return "-" if a is None or not b else f"{100 * a / b:.1f} %"


def _success_cell(row: Mapping[str, Any]) -> str:
    if row["success_rate"] is not None:
        low = row.get("member_success_min")
        members = "" if low is None else f" (members ≥ {100 * low:.0f} %)"
        return f"{100 * row['success_rate']:.0f} %{members}"
    return "pending workload" if row["valid_runs"] else "-"


def _spread(row: Mapping[str, Any], key: str) -> str:
    med = row.get(f"{key}_median")
    if med is None:
        return "-"
    return f"{med:.0f} ({row[f'{key}_min']:.0f}-{row[f'{key}_max']:.0f})"


def paired_ratios(
    runs: Sequence[Mapping[str, Any]], other: str, key: str, *, include_invalid: bool = False
) -> dict[tuple[int, float], list[float]]:
    """Per (N, k), swarmd / ``other`` of ``key`` within each repeat where both runs are
    valid and were made by the same code (``setup.commit``): the two ran back to back in
    one campaign step, under the same machine load. A repeat number alone does not make a
    pair: runs kept from an earlier campaign share numbers with today's. ``include_invalid``
    pairs lagging runs too (indicative only, never the headline)."""
    valid = {
        (r["contender"], int(r["n"]), dilation(r), int(r["run"]), commit(r)): r
        for r in runs
        if r.get("valid") or include_invalid
    }
    out: dict[tuple[int, float], list[float]] = defaultdict(list)
    for (contender, n, k, run, made_by), r in sorted(valid.items()):
        o = valid.get((other, n, k, run, made_by))
        if contender == "swarmd" and o is not None and o.get(key):
            out[(n, k)].append(float(r[key]) / float(o[key]))
    return dict(out)


def _median_run(group: Sequence[Mapping[str, Any]]) -> Mapping[str, Any]:
    """The repeat whose peak is the median (the lower middle one for an even count)."""
    ordered = sorted(group, key=lambda r: (r["peak_pps"], r["run"]))
    return ordered[(len(ordered) - 1) // 2]
