"""The testbed report's figures: Fig. 10a (frames/s over the first 60 s per N) and Fig. 11
(success against N), valid runs only (``bench/wifi/report.py``)."""

from __future__ import annotations

import statistics
import sys
from collections import defaultdict
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run as a script, too

from bench.wifi.report_data import (  # noqa: E402
    _median_run,
    _order,
    dilation,
    main_runs,
)


def _fig10a(
    plt: Any, valid: Sequence[Mapping[str, Any]], n: int, out: Path, extra: list[str]
) -> list[Path]:
    """Frames/s over the first 60 s at one N, every contender on one log axis: each valid
    run thin, the repeat whose peak is the median thick (paper Fig. 10a plots one run)."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, contender in enumerate(sorted({r["contender"] for r in valid}, key=_order)):
        group = [r for r in valid if r["contender"] == contender]
        colour = colours[i % len(colours)]
        for r in group:
            series = r["pps"][:60]
            ax.plot(range(len(series)), series, color=colour, lw=0.7, alpha=0.35)
        med = _median_run(group)
        series = med["pps"][:60]
        ax.plot(
            range(len(series)),
            series,
            color=colour,
            lw=1.8,
            label=f"{contender} (k = {dilation(med):g}; r{med['run']}, "
            + (
                "the only valid run)"
                if len(group) == 1
                else f"median peak of {len(group)} valid runs)"
            ),
        )
    ax.set_yscale("symlog", linthresh=1)
    ax.set_xlabel("experiment time since the start release (s)")
    ax.set_ylabel("frames/s on the channel (PHY tx incl. ACKs)")
    ax.set_title(f"Channel load during discovery, N = {n} (cf. paper Fig. 10a)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    paths = [out / f"fig10a_pps_n{n}.png", *(out / name for name in extra)]
    for path in paths:
        fig.savefig(path, dpi=110)
    plt.close(fig)
    return paths


def plots(runs: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """Figure 10a (frames/s over time) and Figure 11 (success rate against N) as PNG, from
    the main runs (each contender and N at its main dilation; valid runs only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    valid = [r for r in main_runs(runs) if r.get("valid")]
    written: list[Path] = []
    if valid:
        sizes = sorted({int(r["n"]) for r in valid})
        # the paper's figure is N = 10; without N = 10, the N with the most contenders
        n_fig = max(
            sizes,
            key=lambda n: (n == 10, len({r["contender"] for r in valid if r["n"] == n}), n),
        )
        for n in sizes:
            names = ["fig10a_pps.png"] if n == n_fig else []
            written += _fig10a(plt, [r for r in valid if r["n"] == n], n, out, names)
    measured = [r for r in valid if r.get("success_rate") is not None]
    if measured:
        fig, ax = plt.subplots(figsize=(7, 4.2))
        names = sorted({r["contender"] for r in measured}, key=_order)
        for i, contender in enumerate(names):
            by_n: dict[int, list[Mapping[str, Any]]] = defaultdict(list)
            for r in measured:
                if r["contender"] == contender:
                    by_n[int(r["n"])].append(r)
            xs = sorted(by_n)
            rates = [[100 * float(r["success_rate"]) for r in by_n[n]] for n in xs]
            med = [statistics.median(v) for v in rates]
            ks = "/".join(f"{dilation(by_n[n][0]):g}" for n in xs)
            # a small sideways offset and a marker each: lines at 100 % would hide each other
            dx = 0.25 * (i - (len(names) - 1) / 2)
            ax.errorbar(
                [x + dx for x in xs],
                med,
                yerr=[[m - min(v) for m, v in zip(med, rates, strict=True)],
                      [max(v) - m for m, v in zip(med, rates, strict=True)]],
                marker="osD^vP*X"[i % 8],
                capsize=3,
                label=f"{contender} (k = {ks} at N = {'/'.join(str(x) for x in xs)})",
            )  # fmt: skip
        ax.set_xticks(sorted({int(r["n"]) for r in measured}))
        ax.set_xlabel("number of UAVs")
        ax.set_ylabel("members whose last message arrived (%)")
        ax.set_ylim(-5, 105)
        ax.set_title("Success rate vs swarm size, valid runs (cf. paper Fig. 11)")
        ax.legend(fontsize=8)
        ax.grid(True, alpha=0.3)
        path = out / "fig11_success.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
