"""Lockstep in a flight run file: when, modulo a stack's announcement period, its drones
found each other, and (for a fade) when anyone heard the fading drone (docs/testbed.md,
"Staggered start" and "An irregular fade").

    .venv/bin/python bench/flight_lockstep.py RUN.json --period 8 [--fade-from 37 --fade-to 151]

A stack without jitter on its periodic announcements, started on every drone at one
instant, keeps its drones' schedules aligned: each ``discovered``/``regained`` then falls
near one phase of the period (Cyclone DDS: SPDP every lease - 2 s = 8 s). Printed: how many
of those changes lie within ``--near`` of ``--phase`` (0) and in the densest 0.5 s bin;
for a fade, the seconds of ``heard`` (the channel's own record: who received whom, per
second) in which any drone heard the fading one, and the phases of the seconds in which the
fading drone heard anyone.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

UP: frozenset[str] = frozenset({"discovered", "regained"})
BIN_S = 0.5


def phases(run: Mapping[str, Any], period_s: float, kinds: frozenset[str] = UP) -> list[float]:
    """``t mod period_s`` of every change of ``kinds`` by any drone."""
    return [
        t % period_s for changes in run["changes"].values() for t, _, c in changes if c in kinds
    ]


def near_phase(values: Sequence[float], period_s: float, phase: float, within: float) -> int:
    """How many of ``values`` (phases) lie within ``within`` of ``phase``, circularly."""
    return sum(1 for v in values if min(abs(v - phase), period_s - abs(v - phase)) <= within + 1e-9)


def densest_bin(values: Sequence[float]) -> tuple[float, int]:
    """The ``BIN_S`` phase bin holding most values: (its start, its count)."""
    counts = Counter(int(v // BIN_S) for v in values)
    k, c = max(counts.items(), key=lambda kc: (kc[1], -kc[0]))
    return k * BIN_S, c


def fade_hearing(
    run: Mapping[str, Any], node: int, t0: float, t1: float, period_s: float
) -> tuple[list[float], list[float]]:
    """Seconds in [t0, t1] of ``heard`` in which any other drone heard ``node``, and the
    phases (mod ``period_s``) of those in which ``node`` heard anyone."""
    others_hear, node_hears = [], set()
    for h in run["heard"]:
        t, rx = h["t"], h["rx"]
        if not t0 <= t <= t1:
            continue
        if any(str(node) in heard for i, heard in enumerate(rx) if i != node):
            others_hear.append(t)
        if rx[node]:
            node_hears.add(round(t % period_s, 2))
    return others_hear, sorted(node_hears)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--period", type=float, required=True, help="the stack's period, s")
    p.add_argument("--phase", type=float, default=0.0, help="the phase to count near, s")
    p.add_argument("--near", type=float, default=0.25, help="s either side of --phase")
    p.add_argument("--kinds", default="discovered,regained")
    p.add_argument("--fade-from", type=float, default=None)
    p.add_argument("--fade-to", type=float, default=None)
    args = p.parse_args(argv)
    kinds = frozenset(k.strip() for k in args.kinds.split(",") if k.strip())
    for path in args.runs:
        run = json.loads(path.read_text())
        ph = phases(run, args.period, kinds)
        line = f"{path.name}: {len(ph)} {'/'.join(sorted(kinds))}"
        if ph:
            start, count = densest_bin(ph)
            near = near_phase(ph, args.period, args.phase, args.near)
            line += (
                f", {near} within {args.near:g} s of {args.phase:g} mod {args.period:g} s; densest "
                f"{BIN_S:g} s bin [{start:g}, {start + BIN_S:g}) mod {args.period:g}: {count}"
            )
        print(line)
        if run.get("scenario") == "fade" and args.fade_from is not None:
            node = int(run["n"]) - 1
            t1 = args.fade_to if args.fade_to is not None else float(run["duration_s"])
            heard, hears = fade_hearing(run, node, args.fade_from, t1, args.period)
            print(
                f"  fade: seconds in [{args.fade_from:g}, {t1:g}] in which anyone heard "
                f"node {node}: {heard}; phases (mod {args.period:g}) of the seconds in which "
                f"node {node} heard anyone: {hears}"
            )
            print(f"  node {node}'s changes: {run['changes'].get(str(node))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
