"""A flight run's slow re-discoveries, read from its own records (issue 20;
docs/flight-history.md, "The fade's slow return at N = 20 (session 11)").

    .venv/bin/python -m bench.flight_slow_pair \
        bench/results/flight-stagger-c294800/runs/flight-fade-swarmd-n20-r2.json

For every re-discovery that came more than ``--over`` seconds (default 2) after the return
by the clock (``flight_measures.measure``'s return: the first truth sample in range after a
gap in which the observer reported the peer lost), it prints: the observer's loss and
re-discovery of the peer; the pair's in-range spans from the loss to the re-discovery, on the
truth's 0.5 s samples and on a 0.05 s grid (the scenario rebuilt from its seed), with the
time in range (the measure since session 11) against the clock; the other observers that
lost the same peer within 0.1 s (a vouched lease's end: docs/discovery.md, "Vouching") and
when they found it again; what each side decoded of the other per second (the channel's
``heard``: any MAC frame, discovery or not); the peer's renewals counted at each status poll
(the run records no per-frame sends). Nothing asserted: a reading.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from bench.wifi import flight, flight_measures

FINE_S = 0.05  # the grid the crossings are read on (the truth's own step is 0.5 s)
SAME_LOSS_S = 0.1  # losses this close are one lease's end


def slow_returns(run: Mapping[str, Any], over_s: float) -> list[dict[str, Any]]:
    """Each re-discovery slower than ``over_s`` by the clock: observer, peer, lost, back
    (the return's sample), found, and the pair's in-range time from back to found."""
    truth = flight.of_run(run).truth()
    out: list[dict[str, Any]] = []
    for key, changes in sorted(run["changes"].items(), key=lambda kv: int(kv[0])):
        i = int(key)
        for j in range(run["n"]):
            if j == i:
                continue
            mine = sorted((float(t), c) for t, p, c in changes if p == j)
            runs = flight_measures.spans(flight_measures.reachable(truth, {}, i, j))
            for k, (a, _, up) in enumerate(runs):
                if up or k + 1 >= len(runs):
                    continue
                back = runs[k + 1][0]
                lost = [t for t, c in mine if c == "lost" and a <= t <= back]
                found = [
                    t
                    for t, c in mine
                    if c in flight_measures.UP_KINDS and t >= back - flight_measures.TOLERANCE_S
                ]
                if lost and found and found[0] - back > over_s:
                    out.append(
                        {
                            "observer": i,
                            "peer": j,
                            "lost": lost[-1],
                            "back": back,
                            "found": found[0],
                            "in_range_s": flight_measures.in_range_time(runs, back, found[0]),
                            "spans": [r for r in runs if r[1] >= lost[-1] and r[0] <= found[0]],
                        }
                    )
    return out


def fine_crossings(run: Mapping[str, Any], i: int, j: int, t0: float, t1: float) -> list[float]:
    """The instants on a ``FINE_S`` grid in [t0, t1] where the pair's both-ways range flips."""
    scenario = flight.of_run(run)
    out: list[float] = []
    prev: bool | None = None
    for k in range(int(t0 / FINE_S), int(t1 / FINE_S) + 1):
        m = scenario.in_range(k * FINE_S)
        both = bool(m[i][j] and m[j][i])
        if prev is not None and both != prev:
            out.append(round(k * FINE_S, 2))
        prev = both
    return out


def co_losses(
    run: Mapping[str, Any], peer: int, at: float
) -> list[tuple[int, float, float | None]]:
    """(observer, lost, found again) for every observer that lost ``peer`` within
    ``SAME_LOSS_S`` of ``at``."""
    out: list[tuple[int, float, float | None]] = []
    for key, changes in run["changes"].items():
        mine = sorted((float(t), c) for t, p, c in changes if p == peer)
        for t, c in mine:
            if c == "lost" and abs(t - at) <= SAME_LOSS_S:
                again = [u for u, d in mine if u > t and d in flight_measures.UP_KINDS]
                out.append((int(key), t, again[0] if again else None))
    return sorted(out)


def heard(run: Mapping[str, Any], i: int, j: int, t0: float, t1: float) -> list[str]:
    """Per second of the channel's record in [t0, t1]: what i decoded of j and j of i (dBm)."""
    rows = []
    for h in run.get("heard", []):
        if t0 <= h["t"] <= t1:
            a, b = h["rx"][i].get(str(j)), h["rx"][j].get(str(i))
            if a is not None or b is not None:
                rows.append(f"{h['t']:.1f}: {_dbm(a)} / {_dbm(b)}")
    return rows


def _dbm(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def renewals(run: Mapping[str, Any], node: int, t0: float, t1: float) -> list[str]:
    """The node's status polls in [t0, t1]: renewals sent so far, Q, renewal period."""
    return [
        f"{p[0]:.2f}: {p[2]} (Q {p[3]}, period {p[4]} s)"
        for p in run.get("renewals", [])
        if p[1] == node and t0 <= p[0] <= t1
    ]


def report(path: Path, over_s: float) -> str:
    run = json.loads(path.read_text())
    rows = slow_returns(run, over_s)
    out = [f"{path.name}: {len(rows)} re-discoveries over {over_s:g} s by the clock"]
    for r in rows:
        i, j, lost, back, found = r["observer"], r["peer"], r["lost"], r["back"], r["found"]
        out += [
            f"uav{i + 1} of uav{j + 1}: lost {lost:.3f} s, back {back:.2f} s (0.5 s sample), "
            f"found {found:.3f} s: {found - back:.3f} s by the clock, "
            f"{r['in_range_s']:.3f} s in range",
            "  spans (0.5 s truth): "
            + ", ".join(f"{a:g}-{b:g} {'in' if up else 'out'}" for a, b, up in r["spans"]),
            "  crossings (0.05 s grid): "
            + ", ".join(f"{t:g}" for t in fine_crossings(run, i, j, lost - 1.0, found + 1.0)),
            f"  lost uav{j + 1} within {SAME_LOSS_S:g} s of it: "
            + ", ".join(
                f"uav{o + 1} {t:.3f} -> {'-' if g is None else f'{g:.3f}'}"
                for o, t, g in co_losses(run, j, lost)
            ),
            f"  decoded per second, uav{i + 1} of uav{j + 1} / uav{j + 1} of uav{i + 1} (dBm): "
            + "; ".join(heard(run, i, j, lost - 10.0, found + 1.0)),
            f"  uav{j + 1}'s renewals sent at its polls: "
            + "; ".join(renewals(run, j, lost - 3.0, found + 1.0)),
            f"  uav{i + 1}'s renewals sent at its polls: "
            + "; ".join(renewals(run, i, lost - 3.0, found + 1.0)),
        ]
    return "\n".join(out)


def main(argv: Sequence[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.flight_slow_pair",
        description="A flight run's slow re-discoveries, read from its own records.",
    )
    parser.add_argument("run", type=Path, help="a flight run file (*.json)")
    parser.add_argument(
        "--over", type=float, default=2.0, help="the clock time a re-discovery must pass (s)"
    )
    args = parser.parse_args(argv)
    if not args.run.is_file():
        print(f"{args.run}: no such run file", file=sys.stderr)
        return 66  # EX_NOINPUT
    print(report(args.run, args.over))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
