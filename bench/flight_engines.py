"""swarmd's flight cells side by side across engines (issue 20): one run directory per engine.

    .venv/bin/python -m bench.flight_engines bench/results/flight-stagger-1e20f9e \\
        bench/results/flight-stagger-a2a86ac bench/results/flight-stagger

Prints a markdown table, one row per (scenario, N), each column the cell's measure in every
directory named, in order (``A → B → C``): re-discovery p50 / max (reboot: the peers' first
sight of the new life, max / the restarted drone's listing of its peers, max), discovery
frames per rejoining pair, the lost reports (real / intermittent / dropout / false) and
readiness delivery. Reads the run files' ``measures`` (``bench/wifi/flight_measures.py``);
run ``flight_report --remeasure`` on a directory first if its files predate a measure.
Only each cell's first run (``-r1``) is read: the table compares engines, not repeats.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

SCENARIOS = ("fly-out", "fade", "split", "reboot", "blackout")
SIZES = (10, 20)
NOT_RUN = "not run"


def _seconds(block: Mapping[str, Any], key: str) -> str:
    value = block.get(key)
    return "-" if value is None else f"{value:.2f}"


def cell(measures: Mapping[str, Any], scenario: str) -> tuple[str, str, str, str]:
    """The four columns of one run file's ``measures``."""
    if scenario == "reboot":
        seen, finds = measures["reboot_seen_by_peers_s"], measures["reboot_finds_peers_s"]
        timing = f"{_seconds(seen, 'max')} / {_seconds(finds, 'max')} s"
    else:
        found = measures["rediscovery_s"]
        timing = f"{_seconds(found, 'p50')} / {_seconds(found, 'max')} s"
    if timing == "- / - s":
        timing = "-"
    per_pair = measures["frames_per_rejoining_pair"].get("per_pair")
    frames = "-" if per_pair is None else f"{per_pair:.2f}"
    lost = measures["lost_reports"]
    losses = f"{lost['real']}/{lost['intermittent']}/{lost['dropout']}/{lost['false']}"
    ratio = measures["readiness_delivery"].get("ratio")
    readiness = "-" if ratio is None else f"{100 * ratio:.1f} %"
    return timing, frames, losses, readiness


def table(dirs: Sequence[Path]) -> list[str]:
    """The markdown lines: a header, then one row per (scenario, N)."""
    names = " → ".join(d.name for d in dirs)
    lines = [
        f"| cell ({names}) | re-discovery p50 / max (reboot: seen / finds, max) | "
        "frames per rejoining pair | lost: real/intermittent/dropout/false | readiness |",
        "|---|---|---|---|---|",
    ]
    for n in SIZES:
        for scenario in SCENARIOS:
            columns: list[tuple[str, ...]] = []
            for d in dirs:
                path = d / "runs" / f"flight-{scenario}-swarmd-n{n}-r1.json"
                if path.exists():
                    columns.append(cell(json.loads(path.read_text())["measures"], scenario))
                else:
                    columns.append((NOT_RUN,) * 4)
            row = [" → ".join(c[i] for c in columns) for i in range(4)]
            lines.append(f"| {scenario}, N = {n} | " + " | ".join(row) + " |")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("dirs", nargs="+", type=Path, help="run directories, one per engine")
    args = p.parse_args(argv)
    missing = [str(d) for d in args.dirs if not (d / "runs").is_dir()]
    if missing:
        p.error(f"no runs/ directory in: {', '.join(missing)}")
    print("\n".join(table(args.dirs)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
