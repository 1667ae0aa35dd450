"""``python -m swarmd_lab.sim.calibrate``: the simulator against the emulated testbed, N=5, 10, 20.

The testbed (issue 6: ns-3 802.11g, drones on a line 2 m apart, all in range, frames = PHY
transmissions including ACKs, 60 s window) writes one JSON object per run with at least
``protocol``, ``n``, ``peak_pps`` and ``discovery_frames`` (``success_rate`` optional).
``--testbed FILE`` compares against such a file (JSON lines or one JSON list). Without
it the comparison uses the sanity figures the issue-6 prototype reported (``SANITY``),
which is all that exists today: docs/simulator.md says what is and is not calibrated.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

from swarmd_lab.sim.protocols import PROTOCOLS
from swarmd_lab.sim.runner import Scenario, run

# issue 6 prototype, stock implementations, N = 10, line at 2 m, 60 s
SANITY: Final = (
    {"protocol": "cyclone-model", "n": 10, "peak_pps": 3500.0, "discovery_frames": 4900.0},
    {"protocol": "zenoh-model", "n": 10, "peak_pps": 3600.0},
)
# testbed protocol names -> simulator models
ALIASES: Final = {
    "cyclonedds": "cyclone-model",
    "cyclone": "cyclone-model",
    "fastdds": "fastdds-model",
    "fast-dds": "fastdds-model",
    "zenoh": "zenoh-model",
    "swarmd": "swarmd",
}
METRICS: Final = ("peak_pps", "discovery_frames", "success_rate")
TOLERANCE: Final = 0.30  # |sim - testbed| / testbed, per metric


# the testbed's run files (bench/wifi/run.py) name two fields differently
FIELD_ALIASES: Final = {"contender": "protocol", "discovery_frames_60s": "discovery_frames"}


def load_testbed(path: Path) -> list[dict[str, Any]]:
    """Testbed runs from ``path``: a JSON-lines file, a JSON list, or a directory of
    ``bench/wifi/run.py`` run files (``bench/results/wifi/runs``). Runs the testbed marked
    invalid (ns-3 fell behind real time) are left out. One clear line on bad input."""
    if path.is_dir():
        runs: list[Any] = []
        for f in sorted(path.glob("*.json")):
            try:
                runs.append(json.loads(f.read_text(encoding="utf-8")))
            except (OSError, json.JSONDecodeError) as exc:
                raise ValueError(f"{f}: unreadable run ({exc}); fix: rerun or remove it") from None
        return _normalise(path, runs)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(
            f"{path}: cannot read ({exc.strerror}); fix: pass an existing file"
        ) from None
    stripped = text.strip()
    rows: list[Any] = []
    if stripped.startswith("["):
        try:
            rows = json.loads(stripped)
        except json.JSONDecodeError as exc:
            raise ValueError(
                f"{path}: line {exc.lineno}: not JSON; fix: a valid JSON list"
            ) from None
    else:
        for lineno, line in enumerate(text.splitlines(), 1):
            if not line.strip():
                continue
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                raise ValueError(
                    f"{path}: line {lineno}: not JSON; fix: one JSON object per line"
                ) from None
    return _normalise(path, rows)


def _normalise(path: Path, rows: list[Any]) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    for i, raw in enumerate(rows, 1):
        if not isinstance(raw, dict):
            raise ValueError(f"{path}: run {i} is not a JSON object; fix: one object per run")
        row = {FIELD_ALIASES.get(str(k), str(k)): v for k, v in raw.items()}
        if row.get("valid") is False:
            continue
        if "protocol" not in row or "n" not in row:
            raise ValueError(f"{path}: run {i} lacks 'protocol'/'n'; fix: add both fields")
        row["protocol"] = ALIASES.get(str(row["protocol"]).lower(), str(row["protocol"]))
        out.append(row)
    return out


def _mean_by_cell(rows: list[dict[str, Any]]) -> dict[tuple[str, int], dict[str, float]]:
    cells: dict[tuple[str, int], dict[str, list[float]]] = {}
    for r in rows:
        cell = cells.setdefault((r["protocol"], int(r["n"])), {})
        for m in METRICS:
            if r.get(m) is not None:
                cell.setdefault(m, []).append(float(r[m]))
    return {k: {m: statistics.fmean(v) for m, v in c.items()} for k, c in cells.items()}


def compare(
    sim: list[dict[str, Any]], testbed: list[dict[str, Any]], tolerance: float = TOLERANCE
) -> list[dict[str, Any]]:
    """One row per (protocol, N, metric) present on both sides, with the relative error."""
    s, t = _mean_by_cell(sim), _mean_by_cell(testbed)
    rows = []
    for cell in sorted(set(s) & set(t)):
        for m in METRICS:
            if m in s[cell] and m in t[cell] and t[cell][m] != 0:
                err = (s[cell][m] - t[cell][m]) / t[cell][m]
                rows.append(
                    {
                        "protocol": cell[0],
                        "n": cell[1],
                        "metric": m,
                        "sim": round(s[cell][m], 3),
                        "testbed": round(t[cell][m], 3),
                        "rel_error": round(err, 3),
                        "within_tolerance": abs(err) <= tolerance,
                    }
                )
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m swarmd_lab.sim.calibrate")
    p.add_argument(
        "--testbed", type=Path, default=None, help="testbed runs: JSON lines, or a runs/ directory"
    )
    p.add_argument("--n", default="5,10,20")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--tolerance", type=float, default=TOLERANCE)
    p.add_argument("--spacing", type=float, default=2.0, help="metres between drones on the line")
    p.add_argument("--out", type=Path, default=None, help="write calibration.json here")
    args = p.parse_args(argv)
    try:
        sizes = [int(x) for x in args.n.split(",")]
        reference = list(SANITY) if args.testbed is None else load_testbed(args.testbed)
    except ValueError as exc:
        print(f"swarmd_lab.sim.calibrate: {exc}", file=sys.stderr)
        return 2
    # testbed-only contenders (swarmd-paper, ablations) have no simulator counterpart
    protocols = sorted({str(r["protocol"]) for r in reference} & set(PROTOCOLS))
    sim: list[dict[str, Any]] = []
    for proto in protocols:
        for n in sizes:
            for k in range(args.repeat):
                # the testbed's geometry: a line, all in range
                scenario = Scenario(
                    proto, n, args.seed + k, placement="line", spacing_m=args.spacing
                )
                sim.append(run(scenario))
    rows = compare(sim, reference, args.tolerance)
    source = str(args.testbed) if args.testbed else "issue-6 prototype sanity figures"
    print(f"reference: {source}; tolerance +-{args.tolerance:.0%}")
    print("| protocol | N | metric | sim | testbed | rel. error | ok |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        ok = "yes" if r["within_tolerance"] else "NO"
        print(
            f"| {r['protocol']} | {r['n']} | {r['metric']} | {r['sim']:.0f} | "
            f"{r['testbed']:.0f} | {r['rel_error']:+.0%} | {ok} |"
        )
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "calibration.json").write_text(
            json.dumps({"reference": source, "rows": rows}, indent=2) + "\n"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
