"""XRCE take-off latency against the PX4 stand-in's realistic climb (docs/benchmarks.md, "PX4
over uXRCE-DDS"), next to the MAVLink backend flying the same vehicle model.

    .venv/bin/python bench/xrce_takeoff.py [--runs 5] [--alt 5]
                                           [--out bench/results/xrce_takeoff.json]

Per run, a fresh vehicle and a fresh swarmd bridge on loopback:
- ``xrce``: ``swarmd-px4-xrce`` (PX4 1.16 session, PX4's time sync) with swarmd as its agent;
- ``mavlink``: ``swarmd-vehicle-sim`` (MAVLink 2) with swarmd's MAVLink backend.
Both vehicles are ``SimVehicle`` (COM_SPOOLUP_TIME 1 s, MPC_TKO_RAMP_T 3 s to MPC_TKO_SPEED
1.5 m/s, the land detector's LNDMC_Z_VEL_MAX / LNDMC_TRIG_TIME). Measured: vehicle start ->
swarmd "ready"; ``bridge.takeoff(alt)`` -> ``TakeoffSucceeded`` (ARM, NAV_TAKEOFF, lift-off
confirmed by state: landed_state TAKEOFF); the same request -> landed_state IN_AIR (``alt``
reached, back in Hold).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import socket
import statistics
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "lab"))

from swarmd.px4.bridge import Px4Bridge  # noqa: E402
from swarmd.px4.mavlink_backend import MavlinkBackend  # noqa: E402
from swarmd.px4.readiness import ReadinessConfig  # noqa: E402
from swarmd.px4.takeoff import TakeoffSucceeded  # noqa: E402
from swarmd.px4.xrce_backend import XrceBackend  # noqa: E402

READY = ReadinessConfig(require_home=False)  # the stand-in's core set has no home_position


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def one_run(kind: str, alt: float) -> dict[str, float]:
    port = free_port()
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT / 'lab'}")
    if kind == "xrce":
        bridge = Px4Bridge(XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1),
                           readiness_config=READY)  # fmt: skip
        argv = [sys.executable, "-m", "swarmd_lab.px4.xrce_vehicle", "-p", str(port), "-q"]
    else:
        bridge = Px4Bridge(MavlinkBackend(f"udpin:127.0.0.1:{port}", sysid=1),
                           readiness_config=READY)  # fmt: skip
        argv = [sys.executable, "-m", "swarmd_lab.px4.vehicle_sim", "--connect",
                f"udpout:127.0.0.1:{port}", "--gps-fix-after", "0"]  # fmt: skip
    await bridge.start()
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    proc = await asyncio.create_subprocess_exec(
        *argv, env=env, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL
    )
    try:
        while not bridge.readiness().ready:
            assert loop.time() - t0 < 60, "never ready"  # noqa: S101 - a bench's own bound
            await asyncio.sleep(0.01)
        ready_s = loop.time() - t0
        t1 = loop.time()
        outcome = await bridge.takeoff(alt)
        assert isinstance(outcome, TakeoffSucceeded), outcome  # noqa: S101
        liftoff_s = loop.time() - t1
        while bridge.readiness().landed_state != "IN_AIR":
            assert loop.time() - t1 < 30, "never IN_AIR"  # noqa: S101
            await asyncio.sleep(0.01)
        return {"ready_s": ready_s, "liftoff_s": liftoff_s, "in_air_s": loop.time() - t1,
                "elapsed_s": outcome.elapsed_s}  # fmt: skip
    finally:
        proc.terminate()
        await proc.wait()
        await bridge.close()


def summary(xs: list[float]) -> dict[str, Any]:
    return {"runs": [round(x, 3) for x in xs], "median": round(statistics.median(xs), 3),
            "min": round(min(xs), 3), "max": round(max(xs), 3)}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--alt", type=float, default=5.0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "xrce_takeoff.json")
    args = ap.parse_args()
    res: dict[str, Any] = {
        "host": platform.node(),
        "python": platform.python_version(),
        "load_1min": round(os.getloadavg()[0], 2),
        "alt_m": args.alt,
    }
    for kind in ("xrce", "mavlink"):
        runs = [asyncio.run(one_run(kind, args.alt)) for _ in range(args.runs)]
        res[kind] = {k: summary([r[k] for r in runs]) for k in runs[0]}
        print(kind, json.dumps(res[kind]), flush=True)
    res["load_1min_end"] = round(os.getloadavg()[0], 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print("wrote", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
