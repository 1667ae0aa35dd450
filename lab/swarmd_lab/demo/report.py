"""The demo's results: a summary table, ``summary.json`` and a timeline PNG.

Per drone (``summary.json`` ``nodes``; names stable for scripts):

- ``discovered_all_s``: from its daemon's first log line (engine and sockets up) to the
  moment it had discovered every other drone, both from its own log; null if it never did;
- ``frames_sent``: discovery datagrams (SPDP) it sent, the paper's measure;
  ``userdata_frames_sent`` the data plane's (readiness, outcomes, acks);
- ``ready``: it was ready when the commander sent the take-off;
- ``airborne``: its take-off completed and it reported IN_AIR;
- ``command_latency_s``: take-off sent by the commander -> the drone's ACCEPTED received by
  the commander (one round trip over the swarm's Wi-Fi, plus the readiness check).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from swarmd.cli.status_cmd import table
from swarmd_lab.demo.observe import NodeLog

PHASE_COLOURS = {
    "boot": "#bbbbbb",
    "passive": "#9ecae1",
    "announce": "#fdae6b",
    "steady": "#74c476",
    "stopped": "#eeeeee",
}


def summary_rows(nodes: dict[str, dict[str, Any]]) -> list[str]:
    rows = []
    for name, n in nodes.items():
        latency = n.get("command_latency_s")
        found = n.get("discovered_all_s")
        rows.append(
            [
                name,
                str(n.get("role", "-")),
                f"{n.get('snr_db', 0):.1f}",
                "-" if found is None else f"{found:.2f}",
                str(n.get("frames_sent", "-")),
                "yes" if n.get("ready") else "no",
                "yes" if n.get("airborne") else "no",
                "-" if latency is None else f"{latency * 1000:.1f}",
            ]
        )
    return table(
        [
            "DRONE",
            "ROLE",
            "SNR dB",
            "DISCOVERED ALL (s)",
            "FRAMES SENT",
            "READY",
            "AIRBORNE",
            "CMD LATENCY (ms)",
        ],
        rows,
    )


def write_json(path: Path, body: dict[str, Any]) -> None:
    path.write_text(json.dumps(body, indent=2) + "\n")


def write_timeline(
    path: Path,
    names: list[str],
    logs: dict[str, NodeLog],
    in_air_at: dict[str, float],
    end_s: float,
    title: str,
) -> None:
    """One row per drone: discovery phases as coloured bars, readiness and take-off marks."""
    import matplotlib

    matplotlib.use("Agg")  # no display: a file only
    import matplotlib.pyplot as plt
    from matplotlib.artist import Artist
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    height = max(3.0, 0.32 * len(names) + 1.6)
    fig, ax = plt.subplots(figsize=(11, height))
    sent = sorted({t for log in logs.values() for t in log.command_sent})
    for row, name in enumerate(reversed(names)):
        log = logs.get(name, NodeLog())
        phases = sorted(log.phases)
        for i, (start, phase) in enumerate(phases):
            stop = phases[i + 1][0] if i + 1 < len(phases) else end_s
            ax.barh(row, max(0.0, stop - start), left=start, height=0.6,
                    color=PHASE_COLOURS.get(phase, "#dddddd"), edgecolor="none")  # fmt: skip
        first_ready = next((t for t, ok in log.ready if ok), None)
        if first_ready is not None:
            ax.plot(first_ready, row, marker="o", color="#238b45", markersize=5)
        if log.completed is not None:
            ax.plot(log.completed, row, marker="^", color="#08519c", markersize=6)
        if name in in_air_at:
            ax.plot(in_air_at[name], row, marker="*", color="#cb181d", markersize=9)
    for t in sent:
        ax.axvline(t, color="#08519c", linestyle="--", linewidth=1)
    ax.set_yticks(range(len(names)), list(reversed(names)), fontsize=8)
    ax.set_xlabel("seconds since the demo started")
    ax.set_xlim(0, max(end_s, 1.0))
    ax.set_title(title, fontsize=10)
    handles: list[Artist] = [
        Patch(color=c, label=p) for p, c in PHASE_COLOURS.items() if p != "stopped"
    ]
    handles += [
        Line2D([], [], marker="o", color="#238b45", linestyle="none", label="PX4 ready"),
        Line2D([], [], color="#08519c", linestyle="--", label="take-off sent"),
        Line2D([], [], marker="^", color="#08519c", linestyle="none", label="take-off done"),
        Line2D([], [], marker="*", color="#cb181d", linestyle="none", label="IN_AIR seen"),
    ]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=4,
              fontsize=8, frameon=False)  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
