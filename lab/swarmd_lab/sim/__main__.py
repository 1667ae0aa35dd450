"""``python -m swarmd_lab.sim``: run the simulator over swarm sizes, protocols and seeds.

    python -m swarmd_lab.sim --n 50,100,500,1000 --protocol swarmd,fastdds-model,cyclone-model \\
        --seed 1 --repeat 10 --out bench/results/sim --plots

Run k of a (protocol, N) cell uses seed ``--seed + k``. ``--json`` prints one JSON object per
run on stdout (the ``series`` arrays stay in ``--out``'s runs.jsonl); the progress bar and
the summary table go to stderr. Bad options get one line naming the option and the fix.
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarmd.discovery.config import MODES
from swarmd_lab.sim.channel import ChannelConfig
from swarmd_lab.sim.placement import PLACEMENTS
from swarmd_lab.sim.progress import ProgressBar
from swarmd_lab.sim.protocols import PROTOCOLS
from swarmd_lab.sim.runner import WINDOW_S, Scenario, run
from swarmd_lab.sim.summary import summarise, summary_table


def _int_list(text: str) -> list[int]:
    try:
        values = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: use comma-separated integers") from None
    if not values:
        raise argparse.ArgumentTypeError("give at least one value")
    return values


def _name_list(text: str) -> list[str]:
    names = [x.strip() for x in text.split(",") if x.strip()]
    unknown = [x for x in names if x not in PROTOCOLS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown protocol {', '.join(unknown) or text!r}; use {','.join(PROTOCOLS)}"
        )
    return names


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m swarmd_lab.sim",
        description="Deterministic swarm discovery simulator (docs/simulator.md).",
    )
    p.add_argument("--n", type=_int_list, default=[10], help="swarm sizes, e.g. 50,100")
    p.add_argument("--protocol", type=_name_list, default=["swarmd"], help=",".join(PROTOCOLS))
    p.add_argument("--seed", type=int, default=1, help="seed of the first run (default 1)")
    p.add_argument("--repeat", type=int, default=1, help="runs per (protocol, N) cell")
    p.add_argument("--window", type=float, default=WINDOW_S, help="virtual seconds per run")
    p.add_argument("--placement", choices=PLACEMENTS, default="grid")
    p.add_argument("--spacing", type=float, default=2.0, help="metres between neighbours")
    p.add_argument("--start-spread", type=float, default=1.0, help="power-up within U(0, s)")
    p.add_argument("--swarmd-mode", choices=MODES, default="adaptive")
    p.add_argument("--unicast-rate", type=int, default=None, help="fixed Mb/s (default ideal)")
    p.add_argument("--no-workload", action="store_true", help="no 1 Hz member->commander data")
    p.add_argument(
        "--no-vouch", action="store_true", help="swarmd without vouching (plain renewals)"
    )
    p.add_argument("--json", action="store_true", help="one JSON object per run on stdout")
    p.add_argument("--no-wall", action="store_true", help="omit wall_s (byte-identical output)")
    p.add_argument("--out", type=Path, default=None, help="write runs.jsonl + summary.json")
    p.add_argument("--plots", action="store_true", help="also write PNG plots into --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.repeat < 1:
        print("swarmd_lab.sim: --repeat must be >= 1", file=sys.stderr)
        return 2
    if args.plots and args.out is None:
        print("swarmd_lab.sim: --plots needs --out DIR", file=sys.stderr)
        return 2
    channel = ChannelConfig(unicast_rate_mbps=args.unicast_rate)
    cells = [(proto, n) for proto in args.protocol for n in args.n]
    scenarios = [
        Scenario(
            protocol=proto,
            n=n,
            seed=args.seed + k,
            window_s=args.window,
            placement=args.placement,
            spacing_m=args.spacing,
            start_spread_s=args.start_spread,
            workload=not args.no_workload,
            swarmd_mode=args.swarmd_mode,
            vouch=not args.no_vouch,
            channel=channel,
        )
        for proto, n in cells
        for k in range(args.repeat)
    ]
    try:
        for s in scenarios:
            s.check()
    except ValueError as exc:
        print(f"swarmd_lab.sim: {exc}", file=sys.stderr)
        return 2
    results: list[dict[str, Any]] = []
    bar = None if args.quiet else ProgressBar(len(scenarios), sys.stderr)
    runs_file = None
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        runs_file = (args.out / "runs.jsonl").open("w", encoding="utf-8")
    try:
        for i, s in enumerate(scenarios):
            if i:
                # the previous run's engines (reference cycles) are freed here when the collector
                # is off for the command (below), so one run's memory is held at a time
                gc.collect()
            label = f"{s.protocol} n={s.n} seed={s.seed}"
            report = None if bar is None else bar.reporter(i, label)
            milestones: dict[str, float] = {}
            t0 = time.perf_counter()
            result = run(s, report, milestones=milestones, wall=time.perf_counter)
            if not args.no_wall:
                result["wall_s"] = round(time.perf_counter() - t0, 3)
                done = milestones.get("all_discovered")
                result["wall_to_all_discovered_s"] = None if done is None else round(done - t0, 3)
            results.append(result)
            if runs_file is not None:
                runs_file.write(json.dumps(result, sort_keys=True) + "\n")
                runs_file.flush()
            if args.json:
                brief = {k: v for k, v in result.items() if k != "series"}
                print(json.dumps(brief, sort_keys=True), flush=True)
    finally:
        if runs_file is not None:
            runs_file.close()
        if bar is not None:
            bar.close()
    summary = summarise(results)
    print(summary_table(summary), file=sys.stderr if args.json else sys.stdout)
    if args.out is not None:
        (args.out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
        if args.plots:
            from swarmd_lab.sim.plots import write_plots

            for path in write_plots(results, summary, args.out):
                print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    # The command runs with the cyclic collector off (each run's own policy: runner.py,
    # _collections_for) and collects between runs; at its end it freezes what is left, so
    # the interpreter's exit does not trace the last run's objects only to drop them: at
    # N = 1000 main's exit took 4.7 s of CPU after a ~62 s run, and collecting the 5.1 M
    # objects a run leaves 4.2 s (docs/simulator.md, "Session 18").
    gc.disable()
    code = main()
    gc.freeze()
    raise SystemExit(code)
