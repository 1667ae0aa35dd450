"""Which frame crossed first after a pair's link came back, from flight run files (issue 20).

    .venv/bin/python -m bench.flight_first_frame \
        bench/results/flight-rejoin/runs/flight-{split,fly-out}-swarmd-n*.json

For every re-discovery slower than 2 s (the testbed's measure, ``flight_measures``: from the
truth's return of the pair, rebuilt from ``bench/wifi/flight.py`` by the run's seed, to the
observer's next ``discovered``/``regained``): the first up-change of either side of the pair
after the return, i.e. whose frame crossed first, how long after the return, and how many
drones regained that sender within 60 ms of it (several: a multicast). Pairs whose first
frame crossed within 2 s are listed apart: their answer is what came late.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from bench.wifi import flight
from bench.wifi import flight_measures as fm

SLOW_S = 2.0
SAME_FRAME_S = 0.06


def report(path: Path) -> str:
    run = json.loads(path.read_text())
    n = run["n"]
    truth = flight.of_run(run).truth()
    changes = {int(i): sorted((t, p, c) for t, p, c in v) for i, v in run["changes"].items()}
    ups = [(t, i, p) for i, cs in changes.items() for t, p, c in cs if c in fm.UP_KINDS]
    slow: set[tuple[int, int, float]] = set()
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            runs = fm.spans(fm.reachable(truth, {}, i, j))
            lost = [t for t, p, c in changes.get(i, ()) if p == j and c == "lost"]
            for k, (a, _, up) in enumerate(runs):
                if up or k + 1 >= len(runs):
                    continue
                back = runs[k + 1][0]
                if not any(a <= t <= back for t in lost):
                    continue
                found = [
                    t
                    for t, p, c in changes[i]
                    if p == j and c in fm.UP_KINDS and t >= back - fm.TOLERANCE_S
                ]
                if found and found[0] - back > SLOW_S:
                    slow.add((min(i, j), max(i, j), back))
    first_late: list[str] = []
    answer_late: list[str] = []
    for i, j, back in sorted(slow):
        since = back - fm.TOLERANCE_S
        t_ij = min((t for t, a, p in ups if a == i and p == j and t >= since), default=1e9)
        t_ji = min((t for t, a, p in ups if a == j and p == i and t >= since), default=1e9)
        first, sender = (t_ij, j) if t_ij <= t_ji else (t_ji, i)
        seen_by = sum(1 for t, _, p in ups if p == sender and abs(t - first) <= SAME_FRAME_S)
        line = (
            f"uav{i + 1}-uav{j + 1} back {back:.1f} s: first uav{sender + 1}'s frame "
            f"+{first - back:.2f} s (regained by {seen_by} at once), both ways "
            f"+{max(t_ij, t_ji) - back:.2f} s"
        )
        (first_late if first - back > SLOW_S else answer_late).append(line)
    out = [f"{path.name}: {len(slow)} slow pairs; first frame after > 2 s: {len(first_late)}"]
    out += [f"  {line}" for line in first_late]
    out.append(f"  first frame within 2 s, the answer late: {len(answer_late)}")
    out += [f"  {line}" for line in answer_late]
    return "\n".join(out)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.flight_first_frame",
        description="For each re-discovery slower than 2 s in flight run files: whose frame "
        "crossed first after the pair's link came back, and how long after.",
    )
    parser.add_argument("runs", nargs="+", type=Path, help="flight run files (*.json)")
    args = parser.parse_args(argv)
    for path in args.runs:
        if not path.is_file():
            print(f"{path}: no such run file", file=sys.stderr)
            return 66  # EX_NOINPUT
        print(report(path))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
