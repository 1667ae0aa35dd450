"""Aggregate runs into one row per (protocol, N) and print it as a table."""

from __future__ import annotations

import statistics
from typing import Any


def _mean(values: list[float]) -> float | None:
    return round(statistics.fmean(values), 4) if values else None


def summarise(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Means over repeats; ``runs_all_discovered`` is the paper's success rate (the share
    of runs in which every drone recognised every other, section 5.1)."""
    cells: dict[tuple[str, int], list[dict[str, Any]]] = {}
    for r in results:
        cells.setdefault((r["protocol"], r["n"]), []).append(r)
    rows = []
    for (proto, n), runs in sorted(cells.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        done = [r["all_discovered_s"] for r in runs if r["all_discovered_s"] is not None]
        walls = [r["wall_s"] for r in runs if r.get("wall_s") is not None]
        deliveries = [r["delivery_success"] for r in runs if r["delivery_success"] is not None]
        rows.append(
            {
                "protocol": proto,
                "n": n,
                "runs": len(runs),
                "success_rate": _mean([r["success_rate"] for r in runs]),
                "runs_all_discovered": round(len(done) / len(runs), 4),
                "all_discovered_s": _mean(done),
                "delivery_success": _mean(deliveries),
                "frames_per_node_60s": _mean([r["frames_per_node_60s"] for r in runs]),
                "peak_pps": _mean([r["peak_pps"] for r in runs]),
                "peak_discovery_pps": _mean([r["peak_discovery_pps"] for r in runs]),
                "discovery_frames": _mean([r["discovery_frames"] for r in runs]),
                "mac_drops": _mean(
                    [
                        r["counters"]["mac_drop_overflow"] + r["counters"]["mac_drop_expired"]
                        for r in runs
                    ]
                ),
                "wall_s": _mean(walls),
            }
        )
    return rows


COLUMNS = (
    ("protocol", "protocol", "{}"),
    ("n", "N", "{}"),
    ("runs", "runs", "{}"),
    ("success_rate", "pairs ok", "{:.4f}"),
    ("runs_all_discovered", "all-ok runs", "{:.2f}"),
    ("all_discovered_s", "t_all s", "{:.2f}"),
    ("delivery_success", "20th msg", "{:.3f}"),
    ("frames_per_node_60s", "disc fr/node", "{:.1f}"),
    ("peak_pps", "peak fr/s", "{:.0f}"),
    ("mac_drops", "MAC drops", "{:.0f}"),
    ("wall_s", "wall s", "{:.1f}"),
)


def summary_table(rows: list[dict[str, Any]]) -> str:
    """A Markdown table of ``summarise`` rows."""
    head = "| " + " | ".join(title for _, title, _ in COLUMNS) + " |"
    sep = "|" + "|".join("---" for _ in COLUMNS) + "|"
    lines = [head, sep]
    for row in rows:
        cells = []
        for key, _, fmt in COLUMNS:
            v = row.get(key)
            cells.append("-" if v is None else fmt.format(v))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
