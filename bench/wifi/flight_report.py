"""The timeline figure of a flight run, from its run file alone (issue 20).

    .venv/bin/python -m bench.wifi.flight_report bench/results/flight/runs/*.json
    .venv/bin/python -m bench.wifi.flight_report --matrix RUNS... [--since-commit C] \
        [--since-commit CONTENDER=C] [--write-docs docs/benchmarks.md]
        # the matrix: bench/wifi/flight_matrix.py
    .venv/bin/python -m bench.wifi.flight_report --lag RUNS... [--flew-beside FILE...]
        # ns-3 lag of the dilated runs flown alone against those flown beside another

Top: who sees whom. One row per ordered pair (observer i, peer j), one column per 0.5 s:
green where i lists j as discovered and j is in i's range (ground truth), light grey where
j is in range but i does not list it (not yet discovered, or lost while reachable), red
where i still lists j although j is out of range or its stack is down (a loss not yet
noticed: at most a lease is expected), white where j is out of range and not listed.
Bottom: each drone's link quality as its radio saw it: the SNR of the frames it received
in each second (mean over the transmitters heard; ns-3's ``MonitorSnifferRx``, the same
frames its link file averages). The scenario's phases are shaded in both.
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
from collections.abc import Collection, Mapping, Sequence
from pathlib import Path
from typing import Any

from bench.wifi import flight_commands, flight_matrix, flight_measures
from swarmd.cli.pipes import reader_may_close_stdout

NOISE_DBM = -94.0
CONTENDER_ORDER = (
    "swarmd", "swarmd-paper", "swarmd-noaware", "swarmd-stock",
    "cyclonedds", "fastdds", "fastdds-server", "zenoh", "ros2",
)  # fmt: skip
UP = frozenset({"discovered", "regained", "restarted"})


def listed(changes: Sequence[Sequence[Any]], peer: int, t: float) -> bool:
    """Whether the observer lists ``peer`` at ``t`` by its changes (oldest first)."""
    state = False
    for ct, p, c in changes:
        if ct > t:
            break
        if p == peer:
            state = c in UP
    return state


def grid(run: Mapping[str, Any], step_s: float = 0.5) -> tuple[list[str], list[list[int]]]:
    """Row labels and the 0..3 cells of the who-sees-whom panel (module doc)."""
    from bench.wifi import flight  # the scenario rebuilds the truth from its seed

    scenario = flight.of_run(run)
    truth = scenario.truth(step_s)
    down = {int(i): [tuple(x) for x in v] for i, v in run.get("down", {}).items()}
    n = run["n"]
    labels, rows = [], []
    for i in range(n):
        ch = sorted(tuple(x) for x in run["changes"].get(str(i), []))
        for j in range(n):
            if i == j:
                continue
            reach = flight_measures.reachable(truth, down, i, j)
            row = []
            for t, up in reach:
                seen = listed(ch, j, t) and not any(a <= t < b for a, b in down.get(i, ()))
                row.append(2 if seen and up else 1 if up else 3 if seen else 0)
            labels.append(f"{i + 1}>{j + 1}")
            rows.append(row)
    return labels, rows


def timeline(run: Mapping[str, Any], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    labels, rows = grid(run)
    duration = run["duration_s"]
    fig, (top, bottom) = plt.subplots(
        2, 1, figsize=(11, 7.5), sharex=True, gridspec_kw={"height_ratios": [3, 1.4]}
    )
    cmap = ListedColormap(["#ffffff", "#d0d0d0", "#2e9b4f", "#d1352b"])
    top.imshow(
        rows, aspect="auto", interpolation="nearest", cmap=cmap, vmin=0, vmax=3,
        extent=(0, duration, len(rows), 0),
    )  # fmt: skip
    n = run["n"]
    step = max(1, len(labels) // 24)
    top.set_yticks([k + 0.5 for k in range(0, len(labels), step)])
    top.set_yticklabels(labels[::step], fontsize=6)
    top.set_ylabel("observer > peer")
    for k in range(1, n):
        top.axhline(k * (n - 1), color="#888", linewidth=0.3)
    m = run["measures"]
    top.set_title(
        f"{run['scenario']} ({run['description']}), {run['contender']}, N={n}, run {run['run']}, "
        f"loss timer {_v(run.get('lease_s'), ' s')}"
        f"{'' if run['valid'] else ' INVALID'}\n"
        f"green listed & in range, grey in range not listed, red listed but unreachable; "
        f"false losses {m['false_losses']}, rediscovery p50 {m['rediscovery_s']['p50']} s",
        fontsize=9,
    )
    series: dict[int, tuple[list[float], list[float]]] = {i: ([], []) for i in range(n)}
    for h in run.get("heard", []):
        for i, heard in enumerate(h["rx"]):
            if heard:
                mean = sum(heard.values()) / len(heard)
                series[i][0].append(h["t"])
                series[i][1].append(mean - NOISE_DBM)
    for i, (ts, snr) in series.items():
        bottom.plot(ts, snr, linewidth=0.8, label=f"uav{i + 1}")
    bottom.set_ylabel("SNR of frames heard (dB)")
    bottom.set_xlabel("seconds since the start release")
    bottom.legend(fontsize=6, ncol=min(n, 10), loc="lower left")
    for _, a, b in run.get("phases", []):
        for ax in (top, bottom):
            ax.axvspan(a, b, color="#3060c0", alpha=0.08)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _v(value: Any, unit: str = "") -> str:
    return "-" if value is None else f"{value:g}{unit}"


def _head(head: str) -> list[str]:
    """A markdown table's ``head`` row and the separator under its columns."""
    return [head, "|" + "---|" * (head.count("|") - 1)]


def _scenario_rank(run: Mapping[str, Any]) -> int:
    """Where ``run``'s scenario stands in the tables (flight_matrix.SCENARIOS; others last)."""
    order = flight_matrix.SCENARIOS
    return order.index(run["scenario"]) if run["scenario"] in order else 9


def table(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """One markdown row per run: validity and every measure (docs/benchmarks.md "Flight")."""
    head = (
        "| scenario | contender | N | run | valid (lag p99) | k, loss timer | beside | "
        "loss latency p50 / max | "
        "missed | lost: real / intermittent / dropout / false | re-discovery p50 / max | "
        "not re-discovered | reboot seen by peers / finds peers (max) | "
        "frames per rejoining pair (above steady) | readiness delivery |"
    )
    lines = _head(head)
    # swarmd's rows first, the stock contenders beside them (same scenario and N)
    stacks = {name: k for k, name in enumerate(CONTENDER_ORDER)}

    def key(x: Mapping[str, Any]) -> tuple[int, int, int, str, int]:
        c = x["contender"]
        return (_scenario_rank(x), x["n"], stacks.get(c, 99), c, x["run"])

    for r in sorted(runs, key=key):
        m = r["measures"]
        lr = m["lost_reports"]
        fr = m["frames_per_rejoining_pair"]
        rd = m["readiness_delivery"]
        frames = (
            f"{fr['per_pair']:g} ({_v(fr.get('excess_per_pair'))})" if "per_pair" in fr else "-"
        )
        lines.append(
            f"| {r['scenario']} | {r['contender']} | {r['n']} | {r['run']} | "
            f"{'yes' if r['valid'] else 'NO'} ({r['rt_lag_p99_ms']:.2f} ms) | "
            f"{_v((r.get('setup') or {}).get('dilation'))}, {_v(r.get('lease_s'), ' s')} | "
            f"{flight_matrix.beside(r)} | "
            f"{_v(m['loss_latency_s']['p50'], ' s')} / {_v(m['loss_latency_s']['max'], ' s')} | "
            f"{m['missed_losses']} | {lr['real']} / {lr.get('intermittent', 0)} / "
            f"{lr['dropout']} / {lr['false']} | "
            f"{_v(m['rediscovery_s']['p50'], ' s')} / {_v(m['rediscovery_s']['max'], ' s')} | "
            f"{m['not_rediscovered']} | {_v(m['reboot_seen_by_peers_s']['max'], ' s')} / "
            f"{_v(m['reboot_finds_peers_s']['max'], ' s')} | {frames} | "
            f"{_v(None if rd['ratio'] is None else round(100 * rd['ratio'], 1), ' %')} "
            f"({rd['delivered']}/{rd['expected']}) |"
        )
    return lines


def _spread(values: Sequence[float]) -> str:
    if not values:
        return "-"
    mid = statistics.median(values)
    return f"{mid:.2f} ({min(values):.2f}-{max(values):.2f})" if len(values) > 1 else f"{mid:.2f}"


def lag_table(files: Sequence[flight_matrix.RunFile], flew_beside: Collection[Path]) -> list[str]:
    """The ns-3 lag of the dilated runs, per k and N, flown alone against beside another run
    (``concurrent_runs`` > 0, or a file in ``flew_beside``: runs started by hand before the
    field existed): the evidence for ``flight_campaign --parallel`` (docs/testbed.md)."""
    marked = {p.resolve() for p in flew_beside}
    groups: dict[tuple[float, int, bool], list[Mapping[str, Any]]] = {}
    for f in files:
        k = flight_matrix.dilation(f.run)
        if k > 1.0:
            shared = flight_matrix.beside(f.run) > 0 or f.path.resolve() in marked
            groups.setdefault((k, int(f.run["n"]), shared), []).append(f.run)
    lines = _head(
        "| k | N | flown | runs (valid) | lag p99 ms, median (range) | lag max ms, median "
        "(range) | load avg (1 min) at start, median |"
    )
    for (k, n, shared), runs in sorted(groups.items()):
        load = [float(r["load_avg_at_start"][0]) for r in runs if r.get("load_avg_at_start")]
        lines.append(
            f"| {k:g} | {n} | {'beside another' if shared else 'alone'} | {len(runs)} "
            f"({sum(1 for r in runs if flight_matrix.is_valid(r))}) | "
            f"{_spread([float(r['rt_lag_p99_ms']) for r in runs])} | "
            f"{_spread([float(r['rt_lag_max_ms']) for r in runs])} | "
            f"{f'{statistics.median(load):.2f}' if load else '-'} |"
        )
    return lines


def command_table(runs: Sequence[Mapping[str, Any]]) -> list[str]:
    """One markdown row per run that issued commands (``bench/wifi/flight_commands.py``):
    the targets of issue 20's "Command authority in flight" and the delivery latency."""
    head = (
        "| scenario | contender | N | run | commands (pairs: reachable / marginal / "
        "unreachable) | executed twice | executed late | reported unreachable, was reachable "
        "| unreached, not reported | reported ran, not executed | reachable, not executed | "
        "delivery latency p50 / max |"
    )
    lines = _head(head)
    with_commands = [r for r in runs if "commands" in r.get("measures", {})]
    for r in sorted(with_commands, key=lambda x: (_scenario_rank(x), x["n"], x["run"])):
        c = r["measures"]["commands"]
        reach, lat = c["reach"], c["delivery_latency_s"]
        lines.append(
            f"| {r['scenario']} | {r['contender']} | {r['n']} | {r['run']} | "
            f"{c['commands']} ({reach['reachable']} / {reach['marginal']} / "
            f"{reach['unreachable']}) | {c['executed_twice']} | {c['executed_late']} | "
            f"{c['reported_unreachable_but_reachable']} | {c['unreached_not_reported']} | "
            f"{c['reported_ran_not_executed']} | {c['reachable_not_executed']} | "
            f"{_v(lat['p50'], ' s')} / {_v(lat['max'], ' s')} |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument(
        "--remeasure",
        action="store_true",
        help="recompute each run file's measures from its own records and rewrite it",
    )
    p.add_argument(
        "--table", action="store_true", help="print the runs as a markdown table, draw nothing"
    )
    p.add_argument(
        "--matrix",
        action="store_true",
        help="print the flight matrix (every scenario, contender, N = 10 and 20) of the run "
        "files or directories named, with swarmd's targets judged; draw nothing",
    )
    p.add_argument(
        "--lag",
        action="store_true",
        help="print the ns-3 lag of the dilated runs (files or directories), alone against "
        "beside another run; draw nothing",
    )
    p.add_argument(
        "--flew-beside",
        type=Path,
        action="append",
        default=[],
        metavar="FILE",
        help="with --lag (repeatable): a run file that flew beside another but lacks "
        "concurrent_runs",
    )
    p.add_argument(
        "--since-commit",
        action="append",
        default=[],
        metavar="[CONTENDER=]C",
        help="with --matrix: count only the runs on swarmd (swarmd, ROS 2 on swarmd) made at "
        "C or a descendant of it; CONTENDER=C (repeatable, once per contender on swarmd): "
        "that contender's own C instead, e.g. ros2-swarmd=C after a change to the relay",
    )
    p.add_argument(
        "--write-docs",
        type=Path,
        default=None,
        metavar="FILE",
        help="with --matrix: rewrite the flight-matrix block of FILE instead of printing",
    )
    raw = list(sys.argv[1:] if argv is None else argv)
    args = p.parse_args(raw)
    if args.matrix:
        return matrix(args.runs, args.since_commit, args.write_docs, raw)
    if args.lag:
        print("\n".join(lag_table(flight_matrix.load(args.runs), args.flew_beside)))
        return 0
    if args.since_commit or args.write_docs is not None:
        p.error("--since-commit and --write-docs go with --matrix")
    if args.table:
        runs = [json.loads(path.read_text()) for path in args.runs]
        print("\n".join(table(runs)))
        commands = command_table(runs)
        if len(commands) > 2:
            print("\n" + "\n".join(commands))
        return 0
    for path in args.runs:
        run = json.loads(path.read_text())
        if args.remeasure:
            run["measures"] = remeasure(run)
            run["heard"] = compact_heard(run.get("heard", []))
            path.write_text(json.dumps(run) + "\n")
        print(timeline(run, path.with_suffix(".png")))
    return 0


def matrix(
    paths: Sequence[Path], since_values: Sequence[str], docs: Path | None, raw: list[str]
) -> int:
    """``--matrix``: the block of ``bench/wifi/flight_matrix.py``, printed or written."""
    repo = Path(__file__).resolve().parents[2]
    command = ".venv/bin/python -m bench.wifi.flight_report " + shlex.join(raw)
    docs_dir = (docs if docs is not None else repo / "docs" / "x.md").resolve().parent
    try:
        since = flight_matrix.parse_since(since_values)
        counts = flight_matrix.since_counts(since, repo)
        files = flight_matrix.load(paths)
    except ValueError as exc:  # a since misnamed, or a run file cut short: judge nothing
        print(f"flight_report: {exc}", file=sys.stderr)
        return 2
    text = flight_matrix.block(
        files, command=command, docs_dir=docs_dir, counts=counts, since=since
    )
    if docs is None:
        print(text)
        return 0
    try:
        flight_matrix.write_docs(docs, text)
    except ValueError as exc:
        print(f"flight_report: {exc}", file=sys.stderr)
        return 2
    print(docs)
    return 0


def compact_heard(heard: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """``heard`` records with signals rounded to 0.1 dB (a run file of N=20 stays small)."""
    return [
        {"t": round(h["t"], 3), "rx": [{k: round(v, 1) for k, v in rx.items()} for rx in h["rx"]]}
        for h in heard
    ]


def remeasure(run: Mapping[str, Any]) -> dict[str, Any]:
    """The measures of a run file from its records alone (the scenario from its seed)."""
    from bench.wifi import flight

    scenario = flight.of_run(run)
    tl = flight_measures.timeline(run, scenario.truth())
    first_move = min((w[0] for w in run["waypoints"] if w[0] > 0), default=None)
    if first_move is None and run.get("events"):
        first_move = min(e[0] for e in run["events"])
    measures = flight_measures.measure(
        tl.truth, tl.changes, tl.down, n=run["n"], lease_s=run["lease_s"],
        restarts=[(t, node) for t, node in run.get("restarts", [])], readiness=tl.readiness,
        discovery_fps=run["discovery_fps"], first_move_s=first_move,
        started=tl.started,
    )  # fmt: skip
    measures["renewal_follows_q"] = flight_measures.renewal_follows_q(
        run.get("renewals", []), first_move or 0.0
    )
    if "commands" in run:
        measures["commands"] = flight_commands.measure(run["commands"], tl.truth, tl.down)
    return measures


if __name__ == "__main__":
    with reader_may_close_stdout():
        code = main()
    sys.exit(code)
