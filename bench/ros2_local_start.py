"""How quickly a node starting beside another node of its drone is matched by both, on the
relay route (docs/ros2.md, "Several nodes on one drone").

Two drones (``swarmd_lab.netns.Lan``), swarmd with ``ros2.relay: true`` on each (lease
20 s, the default: renewals and the nodes' own SPDP announcements every 5 s). The lead runs
a listener, drone-1 a monitor (a second subscriber), both for the whole bench; then drone-1's
talker is started ``--runs`` times, one after the other. Per run it prints when the talker's
publisher had matched the lead's listener (through swarmd's relay) and its own drone's
monitor (directly: the profile names each other's [::1] discovery port), in seconds after
the talker's node was created (``ros2_node --matched-log``). A match that waits for the
next periodic SPDP (seconds away) shows as late.

    PYTHONPATH=.:lab python bench/ros2_local_start.py --runs 10 --seconds 6   # as root
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path += [str(REPO), str(REPO / "lab")]  # after PYTHONPATH: it picks the checkout

from swarmd_lab import netns, ros2_lab  # noqa: E402

from tests.daemon_support import (  # noqa: E402
    Daemons,
    clean_env,
    relay_config,
    ros2_profiles,
    write_mission_bundle,
)

CONVERGE_S = 30.0
DRONES = ("lead", "drone-1")
NODES = (ros2_lab.TALKER_NODE, ros2_lab.MONITOR_NODE, ros2_lab.LISTENER_NODE)


def _matched_at(log: Path) -> dict[int, float]:
    """First time (s after the node's creation) each matched count was reached."""
    out: dict[int, float] = {}
    if log.exists():
        for line in log.read_text().splitlines():
            row = json.loads(line)
            out.setdefault(row["matched"], round(row["t"], 3))
    return out


def bench(runs: int, seconds: float, work: Path) -> list[dict[str, Any]]:
    results = []
    with netns.Lan(2) as lan:
        addresses = [lan[0].address, lan[1].address]
        text = ros2_lab.chatter_mission("ros2-local-start", 3, addresses, NODES)
        files = write_mission_bundle(work, text, "ros2-local-start", "ros2-local-start.yaml")
        profiles = work / "profiles"
        if ros2_profiles(files, profiles, "--via-swarmd") != 0:
            raise RuntimeError("swarmctl ros2 profile failed")
        swarmd = [sys.executable, "-m", "swarmd.cli.swarmd_main"]
        daemons = Daemons(
            lan, work, files, DRONES, extra=relay_config(), command=swarmd, env=clean_env()
        )
        daemons.start_all(CONVERGE_S)
        launcher = ros2_lab.NodeLauncher(lan, DRONES, profiles, work)

        def node(i: int, name: str, role: str, secs: float, *extra: str) -> Any:
            return launcher.start(
                i,
                name,
                ros2_lab.node_argv(role, secs, *extra, name=name),
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,  # rclpy's traceback when terminated at the end
            )

        total = runs * (seconds + 3) + 10
        listener = node(0, "listener", "listener", total)
        monitor = node(1, "monitor", "listener", total)
        for run in range(runs):
            log = work / f"talker-{run}.jsonl"
            talker = node(1, "talker", "talker", seconds, "--matched-log", str(log))
            talker.wait(timeout=seconds + 30)
            matched = _matched_at(log)
            results.append({"run": run, "matched_1_s": matched.get(1), "both_s": matched.get(2)})
            print(json.dumps(results[-1]), flush=True)
        for proc in (listener, monitor):
            proc.terminate()
            proc.wait(timeout=30)
        for daemon in daemons.procs:
            daemon.terminate()
            daemon.wait(timeout=20)
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else "")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=6.0, help="each talker's run")
    parser.add_argument("--late-s", type=float, default=1.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="ros2-local-start-") as tmp:
        results = bench(args.runs, args.seconds, Path(tmp))
    both = [r["both_s"] for r in results]
    late = [b for b in both if b is None or b > args.late_s]
    print(
        f"talker matched by both subscribers: {len(both) - len(late)}/{len(both)} within "
        f"{args.late_s} s; late or never: {late}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
