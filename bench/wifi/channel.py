"""The ns-3 channel process: N Wi-Fi nodes, one TapBridge each, in real time.

    python -m bench.wifi.channel --n 5 --out DIR --taps PREFIX [--spacing 1 --layout line]

Run as root in the root namespace by ``bench.wifi.testbed``; the taps ``PREFIX0..`` must
exist already (persistent, on the per-drone bridges). Writes into ``--out``:

- ``ready.json`` once the taps are open (wall time of sim time 0, the nodes' MACs);
- ``link-<i>.json`` every second (node i's received signal and noise, for swarmd's
  ``file`` link source);
- ``stats.json`` at the end: per-second frame counts by class, per-node Table 2
  counters, real-time lag samples.

Stops when the ``--stop-file`` appears (polled every 100 ms inside the simulation: Python
signal handlers do not run during ``Simulator::Run``, pitfall 9) or on SIGTERM/SIGKILL
from the harness as a last resort.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench.wifi.channel_cpp import SOURCE
from bench.wifi.ns3_loader import import_ns


@contextlib.contextmanager
def ns3_channel(*sources: str) -> Iterator[tuple[Any, float]]:
    """ns-3 imported (cppyy's patched TapBridge in a private temp dir) with the channel's
    C++ (``channel_cpp.SOURCE``) and ``sources`` defined: yields cppyy's global namespace
    (``swb``, the channel's C++) and the seconds the import took (10-25 s: every header)."""
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="swbtc-", dir="/tmp") as tmp:
        ns, cppyy = import_ns(Path(tmp))
        t_import = time.monotonic() - t0
        for source in (SOURCE, *sources):
            cppyy.cppdef(source)
        yield cppyy.gbl, t_import
    del ns


def setup(swb: Any, args: argparse.Namespace, *, layout: str, lag_tick_s: float) -> None:
    """Build the channel of ``args`` (``--n``, ``--spacing``, ``--standard``, ``--taps``,
    ``--out``, ``--stop-file``, ``--mcast-mode`` and the log-distance loss options)."""
    swb.Setup(
        args.n, args.spacing, layout, args.standard, args.taps, str(args.out),
        str(args.stop_file), args.mcast_mode, lag_tick_s, args.tx_power_dbm, args.exponent,
        args.reference_loss_db,
    )  # fmt: skip


def run_to_end(swb: Any, out: Path) -> None:
    """Simulate until the stop file appears, then write ``out/stats.json`` and free ns-3."""
    swb.Run()
    swb.WriteStats(str(out / "stats.json"))
    swb.Destroy()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, required=True)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--taps", required=True, help="tap name prefix; node i uses PREFIX<i>")
    p.add_argument("--stop-file", type=Path, required=True)
    p.add_argument("--spacing", type=float, default=1.0, help="metres between neighbours")
    p.add_argument("--layout", choices=("line", "grid"), default="line")
    p.add_argument("--standard", choices=("g", "n"), default="g")
    p.add_argument("--mcast-mode", default="", help="WifiMode for group frames ('' = default)")
    p.add_argument("--lag-tick-s", type=float, default=0.005)
    p.add_argument("--tx-power-dbm", type=float, default=16.0206)
    p.add_argument("--exponent", type=float, default=3.0)
    p.add_argument("--reference-loss-db", type=float, default=46.6777)
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    with ns3_channel() as (cpp, t_import):
        swb = cpp.swb
        setup(swb, args, layout=args.layout, lag_tick_s=args.lag_tick_s)
        print(
            f"channel: ns-3 imported in {t_import:.1f} s, set up in "
            f"{time.monotonic() - t0 - t_import:.1f} s; running",
            file=sys.stderr,
            flush=True,
        )
        run_to_end(swb, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
