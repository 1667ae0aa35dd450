"""``python -m swarmd_lab.demo [--n N]`` (``make demo N=...``): see ``swarmd_lab.demo``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from swarmd_lab.demo.run import Options, run
from swarmd_lab.demo.scenario import LATE_GPS_S, VEHICLES


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m swarmd_lab.demo",
        description="Start an N-drone swarm on this machine (swarmd + a MAVLink vehicle "
        "SIMULATOR per drone), take it off, and report.",
    )
    p.add_argument("--n", type=int, default=10, help="number of drones (default 10)")
    p.add_argument("--out", type=Path, default=Path("demo-out"), help="output folder")
    p.add_argument("--loopback", action="store_true",
                   help="run on 127.0.0.1 even as root (the no-root mode)")  # fmt: skip
    p.add_argument("--keep", action="store_true", help="keep the run's keys, configs and logs")
    p.add_argument("--seed", type=int, default=1, help="scenario seed (SNRs, GPS fix times)")
    p.add_argument("--late-gps", type=float, default=LATE_GPS_S, metavar="S",
                   help=f"GPS fix time of the late drone (default {LATE_GPS_S:g})")  # fmt: skip
    p.add_argument("--vehicle", choices=VEHICLES, default="mavlink",
                   help="mavlink: the MAVLink vehicle simulator (default); xrce: the PX4 "
                        "stand-in over uXRCE-DDS (swarmd-px4-xrce) with swarmd as its agent; "
                        "xrce-client: the same through eProsima's MicroXRCEAgent (needs it on "
                        "PATH), swarmd its 2nd client"
                   )  # fmt: skip
    p.add_argument("--ros2", action="store_true",
                   help="also a real rclpy node per drone, its discovery served by swarmd "
                        "(docs/ros2.md; namespaces only)")  # fmt: skip
    args = p.parse_args(argv)
    opts = Options(
        n=args.n,
        out=args.out,
        loopback=args.loopback,
        keep=args.keep,
        seed=args.seed,
        late_gps_s=args.late_gps,
        vehicle=args.vehicle,
        ros2=args.ros2,
    )
    return run(opts)


if __name__ == "__main__":
    sys.exit(main())
