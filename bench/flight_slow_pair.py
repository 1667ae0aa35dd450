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

    .venv/bin/python -m bench.flight_slow_pair --parts RUN.json [RUN.json ...]

``--parts`` splits every re-discovery of each run into its stages instead: the return (the
truth's sample), the first frame decoded each way (the channel's 1 s ``heard`` records: "by
t" is the end of the first record, at or after the return less the truth's 0.5 s step, that
holds one), the observer's re-discovery, and what lies between the last two. In a swarmd run
the re-discovery is swarmd's own PeerDiscovered/PeerRegained (dated by ``ago_s``); in a ROS 2
on swarmd run it is the node's graph listing the drone (polled every 0.25 s), and swarmd's
own event under it is not in the run file. One line per run (the distributions), one per
pair slower than ``--over``, and with several runs one line per cell (contender, scenario,
N) over them all: whether the channel's side has the same shape in two contenders' runs.
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
                            "early": flight_measures.listed_before_return(mine, lost, a, back),
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


def first_heard(run: Mapping[str, Any], i: int, j: int, t0: float) -> float | None:
    """The end of the first 1 s ``heard`` record at or after ``t0`` in which i decoded a
    frame of j (any MAC frame: discovery, user data, the relay's traffic), or None."""
    for h in run.get("heard", []):
        if h["t"] >= t0 and str(j) in h["rx"][i]:
            return float(h["t"])
    return None


def stages(run: Mapping[str, Any], over_s: float) -> list[dict[str, Any]]:
    """``slow_returns`` (re-listed before the return left out: the measure counts those 0 s)
    with ``heard_ij`` (i decoded j by), ``heard_ji`` and ``both`` (the later of the two;
    None where a side decoded nothing in the run), and ``swarmd_found``: in a ROS 2 on
    swarmd run that has them (``swarmd_changes``, since this tool's session), swarmd's own
    re-discovery of the peer under the graph's (None where the file has none)."""
    under = run.get("swarmd_changes") or {}
    out = []
    for r in slow_returns(run, over_s):
        if r["early"]:
            continue
        i, j, t0 = r["observer"], r["peer"], r["back"] - flight_measures.TOLERANCE_S
        ij, ji = first_heard(run, i, j, t0), first_heard(run, j, i, t0)
        both = None if ij is None or ji is None else max(ij, ji)
        ups = [
            float(t)
            for t, p, c in under.get(str(i), ())
            if p == j and c in flight_measures.UP_KINDS and float(t) >= t0
        ]
        found = min(ups, default=None)
        out.append({**r, "heard_ij": ij, "heard_ji": ji, "both": both, "swarmd_found": found})
    return out


def observed(run: Mapping[str, Any]) -> str:
    """What a run's re-discovery times are the times of."""
    if run.get("contender") == "ros2-swarmd" and "swarmd_changes" in run:
        return "the ROS 2 graph, swarmd's own PeerDiscovered/PeerRegained under it"
    if run.get("contender") == "ros2-swarmd":
        return "the ROS 2 graph (swarmd's own PeerDiscovered: not in the run file)"
    if (run.get("observer") or {}).get("source") == "peer event lines":
        return "the stack's own API"
    return "swarmd's own PeerDiscovered/PeerRegained"


def _q(values: Sequence[float]) -> str:
    if not values:
        return "-"
    s = sorted(values)
    pick = [s[min(len(s) - 1, round(q * (len(s) - 1)))] for q in (0.5, 0.9)]
    return "/".join(f"{v:.2f}" for v in (*pick, s[-1]))


def stage_summary(rows: Sequence[Mapping[str, Any]]) -> str:
    """The distributions over ``stages`` rows (p50/p90/max, seconds after the return)."""
    seen = [r for r in rows if r["both"] is not None]
    both = [r["both"] - r["back"] for r in seen]
    first = [min(r["heard_ij"], r["heard_ji"]) - r["back"] for r in seen]
    one_way = sum(abs(r["heard_ij"] - r["heard_ji"]) >= 1.0 for r in seen)
    found = [max(0.0, r["found"] - r["back"]) for r in rows]
    after = [r["found"] - r["both"] for r in seen]
    under = [r for r in rows if r["swarmd_found"] is not None]
    return (
        f"{len(rows)} re-discoveries; first frame one way by {_q(first)}, both ways by "
        f"{_q(both)} (p50/p90/max s after the return), one way only for a record or more at "
        f"{one_way}; re-discovered {_q(found)}; re-discovery minus both ways {_q(after)}"
    ) + (
        ""
        if not under
        else f"; swarmd's own {_q([max(0.0, r['swarmd_found'] - r['back']) for r in under])}"
        f", the graph after it {_q([r['found'] - r['swarmd_found'] for r in under])}"
    )


def parts_report(paths: Sequence[Path], over_s: float) -> str:
    """``--parts`` (module doc): per run its distributions and its pairs over ``over_s``,
    then per cell over the runs given."""
    out: list[str] = []
    cells: dict[tuple[str, str, int], list[dict[str, Any]]] = {}
    for path in paths:
        run = json.loads(path.read_text())
        rows = stages(run, -1.0)
        key = (str(run.get("contender")), str(run["scenario"]), int(run["n"]))
        cells.setdefault(key, []).extend(rows)
        out.append(f"{path.name}: re-discovery is {observed(run)}")
        out.append(f"  {stage_summary(rows)}")
        for r in rows:
            if r["found"] - r["back"] <= over_s:
                continue
            i, j = r["observer"], r["peer"]
            out.append(
                f"  uav{i + 1} of uav{j + 1}: back {r['back']:.2f} s; uav{i + 1} decoded "
                f"uav{j + 1} by {_by(r['heard_ij'], r['back'])}, uav{j + 1} decoded uav{i + 1} "
                f"by {_by(r['heard_ji'], r['back'])}; re-discovered {r['found']:.3f} s "
                f"(+{r['found'] - r['back']:.3f} s"
                + ("" if r["both"] is None else f", {r['found'] - r['both']:+.3f} s after both")
                + ")"
                + _swarmd_part(r)
            )
    if len(paths) > 1:
        for (contender, scenario, n), rows in sorted(cells.items()):
            out.append(f"{contender} {scenario} N = {n}, all runs: {stage_summary(rows)}")
    return "\n".join(out)


def _swarmd_part(r: Mapping[str, Any]) -> str:
    t = r["swarmd_found"]
    return "" if t is None else f"; swarmd's own {t:.3f} s, the graph {r['found'] - t:+.3f} s after"


def _by(t: float | None, back: float) -> str:
    return "never" if t is None else f"{t:.1f} s (+{t - back:.1f})"


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
    parser.add_argument("run", type=Path, nargs="+", help="flight run files (*.json)")
    parser.add_argument(
        "--over", type=float, default=2.0, help="the clock time a re-discovery must pass (s)"
    )
    parser.add_argument(
        "--parts",
        action="store_true",
        help="every re-discovery split into return, first frames each way and the report",
    )
    args = parser.parse_args(argv)
    for path in args.run:
        if not path.is_file():
            print(f"{path}: no such run file", file=sys.stderr)
            return 66  # EX_NOINPUT
    if args.parts:
        print(parts_report(args.run, args.over))
    else:
        print("\n".join(report(path, args.over) for path in args.run))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
