"""PNG plots of simulator results (matplotlib, headless Agg backend)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend must be chosen first


def _mean_series(runs: list[dict[str, Any]]) -> list[float]:
    series = [
        [d + u for d, u in zip(r["series"]["discovery"], r["series"]["data"], strict=True)]
        for r in runs
    ]
    length = min(len(s) for s in series)
    return [sum(s[i] for s in series) / len(series) for i in range(length)]


def write_plots(
    results: list[dict[str, Any]], summary: list[dict[str, Any]], out: Path
) -> list[Path]:
    """Packet rate over time (one figure per N), success vs N, frames per node vs N."""
    written: list[Path] = []
    protocols = sorted({r["protocol"] for r in results})
    sizes = sorted({r["n"] for r in results})
    for n in sizes:
        fig, ax = plt.subplots(figsize=(7, 4))
        for proto in protocols:
            runs = [r for r in results if r["n"] == n and r["protocol"] == proto]
            if not runs:
                continue
            ys = _mean_series(runs)
            bin_s = runs[0]["series"]["bin_s"]
            ax.plot([i * bin_s for i in range(len(ys))], ys, label=proto, drawstyle="steps-post")
        ax.set_yscale("symlog", linthresh=10)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("PHY frames per second (incl. ACKs, 1 Hz data)")
        ax.set_title(f"Packet rate over time, N = {n} (mean of runs)")
        ax.legend()
        ax.grid(True, alpha=0.3)
        path = out / f"rate_over_time_n{n}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    for key, ylabel, name, log in (
        ("success_rate", "pairs discovered within the window", "success_vs_n.png", False),
        (
            "frames_per_node_60s",
            "discovery frames per node, first 60 s",
            "frames_per_node_vs_n.png",
            True,
        ),
    ):
        fig, ax = plt.subplots(figsize=(6, 4))
        for proto in protocols:
            rows = [r for r in summary if r["protocol"] == proto and r[key] is not None]
            ax.plot([r["n"] for r in rows], [r[key] for r in rows], marker="o", label=proto)
        ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
        ax.set_xlabel("swarm size N")
        ax.set_ylabel(ylabel)
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
