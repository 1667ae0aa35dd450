"""The ns-3 channel process of a flight scenario: ``bench.wifi.channel`` plus mobility.

    python -m bench.wifi.flight_channel --n 10 --out DIR --taps PREFIX --stop-file F \\
        --waypoints W --flight-dir D --go-file G

The same channel as ``bench/wifi/channel.py`` (802.11g, YANS, log-distance loss, one
TapBridge per node, the stats file), with ``bench/wifi/flight_cpp.py`` installed on top:
the waypoints move the nodes from the go signal on, and ``D/link-<i>.json`` are windowed
link files for swarmd's ``file`` source (docs/testbed.md, "Flight scenarios").
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from bench.wifi import flight_cpp
from bench.wifi.channel import ns3_channel, run_to_end, setup


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--n", type=int, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--taps", required=True)
    p.add_argument("--stop-file", type=Path, required=True)
    p.add_argument("--waypoints", type=Path, required=True)
    p.add_argument("--flight-dir", type=Path, required=True)
    p.add_argument("--go-file", type=Path, required=True)
    p.add_argument("--spacing", type=float, default=1.0)
    p.add_argument("--standard", choices=("g", "n"), default="g")
    p.add_argument("--mcast-mode", default="")
    p.add_argument("--tx-power-dbm", type=float, default=16.0206)
    p.add_argument("--exponent", type=float, default=3.0)
    p.add_argument("--reference-loss-db", type=float, default=46.6777)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    args.flight_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with ns3_channel(flight_cpp.SOURCE) as (cpp, _):
        swb, swbf = cpp.swb, cpp.swbf
        setup(swb, args, layout="line", lag_tick_s=0.005)
        loaded = swbf.Install(
            args.n, str(args.waypoints), str(args.flight_dir), str(args.go_file),
            flight_cpp.WINDOW_S, -94.0,
        )  # fmt: skip
        if loaded < 0:
            print(f"flight channel: {args.waypoints}: a node index >= {args.n}", file=sys.stderr)
            return 2
        print(
            f"flight channel: ns-3 ready in {time.monotonic() - t0:.1f} s, {loaded} waypoints",
            file=sys.stderr,
            flush=True,
        )
        run_to_end(swb, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
