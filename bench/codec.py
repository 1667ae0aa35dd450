"""Micro-benchmark of the SPDP codec: microseconds per encode and per decode.

    .venv/bin/python bench/codec.py [--repeat 7] [--number 2000] [--json]

Reports the median of ``--repeat`` timeit runs of ``--number`` calls each, for swarmd's own
DATA(p) (encode and decode), a directed DATA(p), the DATA(p[UD]) dispose, and stock Cyclone DDS
0.10.2's DATA(p) from the golden capture (decode). Target (issue 2): each <= 50 us in CPython 3.11.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import timeit
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.rtps import decode_spdp, encode_spdp, encode_spdp_dispose  # noqa: E402
from tests import golden_swarmd  # noqa: E402

TARGET_US = 50.0


def cases() -> dict[str, Callable[[], object]]:
    p = golden_swarmd.PARTICIPANT
    ts = golden_swarmd.TIMESTAMP
    ours = encode_spdp(p, sequence_number=1, timestamp=ts)
    cyclone = (ROOT / "tests/fixtures/cyclone-0.10.2/spdp-alive.bin").read_bytes()
    return {
        "encode swarmd DATA(p)": lambda: encode_spdp(p, sequence_number=1, timestamp=ts),
        "encode swarmd directed DATA(p)": lambda: encode_spdp(
            p, sequence_number=2, timestamp=ts, destination=golden_swarmd.PEER
        ),
        "encode swarmd DATA(p[UD])": lambda: encode_spdp_dispose(
            p.guid_prefix, sequence_number=3, timestamp=ts
        ),
        "decode swarmd DATA(p)": lambda: decode_spdp(ours),
        "decode Cyclone 0.10.2 DATA(p)": lambda: decode_spdp(cyclone),
    }


def measure(fn: Callable[[], object], repeat: int, number: int) -> float:
    runs = timeit.repeat(fn, repeat=repeat, number=number)
    return statistics.median(runs) / number * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7, help="timeit runs; the median is reported")
    ap.add_argument("--number", type=int, default=2000, help="calls per run")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = ap.parse_args()
    results = {name: measure(fn, args.repeat, args.number) for name, fn in cases().items()}
    machine = {
        "python": platform.python_version(),
        "implementation": platform.python_implementation(),
        "machine": platform.machine(),
        "processor": _cpu_model(),
    }
    if args.json:
        print(json.dumps({"machine": machine, "us_per_op": results, "target_us": TARGET_US}))
    else:
        print(f"{machine['implementation']} {machine['python']} on {machine['processor']}")
        print(f"{'case':34} {'us/op':>8}  target <= {TARGET_US:.0f} us")
        for name, us in results.items():
            verdict = "ok" if us <= TARGET_US else "OVER"
            print(f"{name:34} {us:8.1f}  {verdict}")
    return 0


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


if __name__ == "__main__":
    sys.exit(main())
