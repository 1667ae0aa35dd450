"""Where a flight run's missing readiness goes, per member, span and phase (issue 20).

``flight_measures.readiness_delivery`` gives one ratio per run; this splits its missing
samples by where they fall, from the run file alone (docs/flight-history.md, "The stock
stacks' readiness in the blackout at N = 20 (session 11)"):

- per *span* (a member's time in the commander's range, bounded exactly as
  ``readiness_delivery`` bounds it): ``start`` (the member's first, from the commander's
  discovery of it: the swarm's start-up) or ``return after PHASE`` (a later one: from the
  member's return into range);
- its *onset*: from the span's start (the commander's discovery of the member, or the
  return into range) to the first poll whose count moved: nothing of the member arrived
  in between, whatever the reason (the stack's endpoint matching, its re-discovery, the
  channel); ``onset_missing`` is the samples that time should have held;
- its *steady* part: the samples missing after that poll (lost in a running stream).

And the run's readiness over time: per poll interval, the samples the commander counted
from all members and the samples expected of the members then in a span (the figure's
bars and line). Times are the run's: seconds since go, on the experiment clock.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from bench.wifi.flight_measures import (
    READINESS_HZ,
    Timeline,
    count_at,
    counted_spans,
    timeline,
)

Polls = Sequence[tuple[float, Mapping[int, int]]]


def _phase_of(t: float, first: bool, phases: Sequence[tuple[str, float, float]]) -> str:
    """``start`` for a member's first span (from the commander's discovery of it), else
    ``return`` with the phase it ends or follows (``return after blackout``): the truth
    brings a drone back into range before its phase's end (the commander flies back)."""
    if first:
        return "start"
    ended = [name for name, a, b in sorted(phases, key=lambda p: p[1]) if a < t]
    return f"return after {ended[-1]}" if ended else "return"


def readiness_spans(
    tl: Timeline, phases: Sequence[tuple[str, float, float]] = ()
) -> list[dict[str, Any]]:
    """One row per member and counted span (module doc); the rows' ``expected`` and
    ``delivered`` sum to ``readiness_delivery``'s."""
    readiness = tl.readiness
    rows: list[dict[str, Any]] = []
    previous_member = 0
    for span in counted_spans(tl):
        m, a, b, ca = span.member, span.start_s, span.end_s, span.count_start
        first, previous_member = m != previous_member, m
        expected, delivered = span.expected, span.delivered
        moved = next((t for t, table in readiness if a < t <= b and table.get(m, 0) != ca), None)
        if moved is None:
            onset_s, onset_missing = b - a, expected
        else:
            got = (count_at(readiness, m, moved) or 0) - ca
            onset_s = moved - a
            onset_missing = max(0.0, min(onset_s * READINESS_HZ, expected) - got)
        missing = expected - delivered
        onset_missing = min(onset_missing, missing)
        rows.append(
            {
                "member": m,
                "phase": _phase_of(a, first, phases),
                "from_s": round(a, 3),
                "to_s": round(b, 3),
                "expected": round(expected, 3),
                "delivered": round(delivered, 3),
                "missing": round(missing, 3),
                "onset_s": round(onset_s, 3),
                "onset_missing": round(onset_missing, 3),
                "steady_missing": round(missing - onset_missing, 3),
            }
        )
    return rows


def by_phase(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    """The rows summed per phase: spans, expected, missing, onset and steady missing, and
    the mean and largest onset."""
    out: dict[str, dict[str, float]] = {}
    for r in rows:
        d = out.setdefault(
            str(r["phase"]),
            {
                "spans": 0,
                "expected": 0.0,
                "missing": 0.0,
                "onset_missing": 0.0,
                "steady_missing": 0.0,
                "onset_s_sum": 0.0,
                "onset_s_max": 0.0,
            },
        )
        d["spans"] += 1
        for k in ("expected", "missing", "onset_missing", "steady_missing"):
            d[k] += float(r[k])
        d["onset_s_sum"] += float(r["onset_s"])
        d["onset_s_max"] = max(d["onset_s_max"], float(r["onset_s"]))
    return out


def readings(rows: Sequence[Mapping[str, Any]]) -> dict[str, float | None]:
    """The run's readiness as measured, and two other readings of the same rows (the
    workload's fairness, docs/flight-history.md, session 11): ``one_back``, had every
    onset brought one sample back (what a reliable, transient-local reader of a keep-last-1
    writer gets at the match, at most); ``no_start_onsets``, had the start-up spans' onsets
    missed nothing (as if each were counted from its first sample, not from the
    commander's discovery of the member)."""
    expected = sum(float(r["expected"]) for r in rows)
    delivered = sum(float(r["delivered"]) for r in rows)
    if expected <= 0:
        return {"measured": None, "one_back": None, "no_start_onsets": None}
    back = sum(min(1.0, float(r["onset_missing"])) for r in rows)
    start_onsets = sum(float(r["onset_missing"]) for r in rows if r["phase"] == "start")
    return {
        "measured": round(delivered / expected, 4),
        "one_back": round(min(1.0, (delivered + back) / expected), 4),
        "no_start_onsets": round(min(1.0, (delivered + start_onsets) / expected), 4),
    }


def per_second(
    rows: Sequence[Mapping[str, Any]], readiness: Polls
) -> list[tuple[int, float, float]]:
    """Per second of the run ``(second, samples counted in it from members in a span,
    samples expected in it)``, every second from the first span's to the last's: a poll
    interval's count (and its expected time) is shared over the seconds it covers, in
    proportion (swarmd's commander is polled every 0.25 s, the stock tallies every 1 s,
    at any phase)."""
    got: dict[int, float] = {}
    expected: dict[int, float] = {}
    for (t0, before), (t1, after) in zip(readiness, readiness[1:], strict=False):
        if t1 <= t0:
            continue
        for r in rows:
            a, b = float(r["from_s"]), float(r["to_s"])
            lo, hi = max(a, t0), min(b, t1)
            if hi <= lo:
                continue
            m = int(r["member"])
            rate = max(0, after.get(m, 0) - before.get(m, 0)) / (t1 - t0)
            t = t0
            while t < t1:  # the interval's count over the seconds it covers
                step = min(t1, float(int(t) + 1)) - t
                got[int(t)] = got.get(int(t), 0.0) + rate * step
                t += step
            t = lo
            while t < hi:  # the span's time in the interval, likewise
                step = min(hi, float(int(t) + 1)) - t
                expected[int(t)] = expected.get(int(t), 0.0) + step * READINESS_HZ
                t += step
    if not expected:
        return []
    first, last = min(expected), max(expected)
    return [(s_, got.get(s_, 0.0), expected.get(s_, 0.0)) for s_ in range(first, last + 1)]


def _pct(ratio: float | None) -> str:
    return "-" if ratio is None else f"{ratio:.1%}"


def _load(path: Any) -> dict[str, Any]:
    import json

    from bench.wifi import flight

    run: dict[str, Any] = json.loads(path.read_text())
    tl = timeline(run, flight.of_run(run).truth())
    phases = [(str(p), float(a), float(b)) for p, a, b in run.get("phases", ())]
    rows = readiness_spans(tl, phases)
    return {"run": run, "rows": rows, "polls": tl.readiness, "phases": phases}


def _figure(loaded: Sequence[tuple[str, dict[str, Any]]], out: Any) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(loaded), 1, figsize=(9, 1.6 * len(loaded) + 0.6), sharex=True)
    axes_list = list(axes) if len(loaded) > 1 else [axes]
    for ax, (name, d) in zip(axes_list, loaded, strict=True):
        series = per_second(d["rows"], d["polls"])
        ts = [t for t, _, _ in series]
        ax.step(ts, [e for _, _, e in series], where="post", color="0.3", lw=1, label="expected")
        ax.bar(
            ts,
            [g for _, g, _ in series],
            width=0.9,
            align="edge",
            color="tab:blue",
            label="counted",
        )
        for p, a, b in d["phases"]:
            ax.axvspan(a, b, color="tab:red", alpha=0.12)
            ax.text(a + 0.5, 0.5, p, fontsize=7, color="tab:red")
        expected = sum(float(r["expected"]) for r in d["rows"])
        ratio = sum(float(r["delivered"]) for r in d["rows"]) / expected if expected else None
        ax.set_title(
            f"{name}: readiness {ratio:.1%}" if ratio is not None else name, fontsize=8, loc="left"
        )
        ax.set_ylabel("samples/s", fontsize=7)
        ax.tick_params(labelsize=7)
    axes_list[0].legend(fontsize=7, loc="upper right")
    axes_list[-1].set_xlabel("s since go (experiment clock)", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m bench.wifi.flight_readiness RUN.json ... [--verbose] [--figure PNG]``:
    per run, the missing readiness by phase, split into the spans' onsets and their steady
    parts; ``--figure``: the samples counted and expected per second, one panel a run,
    the scenario's phases shaded."""
    import argparse
    from pathlib import Path

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--verbose", action="store_true", help="one line per member and span")
    p.add_argument("--figure", type=Path, help="write the per-second figure here")
    args = p.parse_args(argv)
    loaded = []
    for path in args.runs:
        d = _load(path)
        loaded.append((path.stem, d))
        rows = d["rows"]
        expected = sum(r["expected"] for r in rows)
        missing = sum(r["missing"] for r in rows)
        other = readings(rows)
        print(
            f"{path.name}: expected {expected:.0f}, missing {missing:.1f} "
            f"({missing / expected if expected else 0:.1%}); had each onset one sample "
            f"back: {_pct(other['one_back'])}; without the start-up onsets: "
            f"{_pct(other['no_start_onsets'])}"
        )
        for phase, s in by_phase(rows).items():
            print(
                f"  {phase}: {s['spans']:.0f} spans, expected {s['expected']:.0f}, missing "
                f"{s['missing']:.1f} = onset {s['onset_missing']:.1f} (mean "
                f"{s['onset_s_sum'] / s['spans']:.2f} s, max {s['onset_s_max']:.2f} s) "
                f"+ steady {s['steady_missing']:.1f}"
            )
        if args.verbose:
            for r in rows:
                print("   ", r)
    if args.figure is not None:
        _figure(loaded, args.figure)
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
