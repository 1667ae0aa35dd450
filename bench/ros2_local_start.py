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
from swarmd_lab.ros2_lab import host_argv, write_machine_id  # noqa: E402

from swarmd.bundle.build import build_dev_bundle  # noqa: E402
from swarmd.bundle.keys import dev_signing_key, public_pem, raw_public  # noqa: E402
from swarmd.bundle.mission import parse_mission  # noqa: E402
from swarmd.cli.swarmctl import main as swarmctl  # noqa: E402
from tests.daemon_support import (  # noqa: E402
    BundleFiles,
    clean_env,
    daemon_status,
    until,
    write_config,
)

CONVERGE_S = 30.0
MISSION = """
swarm: ros2-local-start
domain_id: 3
discovery: {{t_min_s: 0.2, t_max_s: 0.5, lease_s: 4}}
participants:
  - {{name: lead, index: 0, role: commander, mavlink_sysid: 1, ipv4: {a0}}}
  - {{name: drone-1, index: 1, role: member, mavlink_sysid: 2, ipv4: {a1}}}
topics:
  - {{name: swarm/ready, type: "swarmd::Readiness", writers: member, readers: commander}}
ros2:
  domain_id: 7
  topics:
    - {{name: /chatter, type: std_msgs/msg/String, reliability: reliable, history_depth: 10}}
  services:
    - {{name: /trigger, type: std_srvs/srv/Trigger}}
  nodes:
    - {{name: talker, drones: member, publishes: [/chatter], serves: [/trigger]}}
    - {{name: monitor, drones: member, subscribes: [/chatter], calls: [/trigger]}}
    - {{name: listener, drones: commander, subscribes: [/chatter], calls: [/trigger]}}
"""


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
        text = MISSION.format(a0=lan[0].address, a1=lan[1].address)
        built = build_dev_bundle(parse_mission(text, "ros2-local-start.yaml"))
        bundle = work / "bundle.swb"
        bundle.write_bytes(built.data)
        key = work / "swarm.pub"
        key.write_bytes(public_pem(raw_public(dev_signing_key("ros2-local-start"))))
        files = BundleFiles(built.bundle, bundle, key)
        profiles = work / "profiles"
        argv = ["ros2", "profile", str(bundle), "--allow-dev", "--out", str(profiles)]
        if swarmctl([*argv, "--via-swarmd"]) != 0:
            raise RuntimeError("swarmctl ros2 profile failed")
        drones = ("lead", "drone-1")
        socks = [work / f"{d}.sock" for d in drones]
        daemons = []
        for i, d in enumerate(drones):
            config = write_config(
                work / f"{d}.yaml",
                files,
                node=d,
                interface=lan[i].ifname,
                socket_path=str(socks[i]),
                extra="ros2:\n  relay: true\n",
            )
            with (work / f"swarmd-{d}.log").open("wb") as err:
                daemons.append(
                    lan[i].popen(
                        [sys.executable, "-m", "swarmd.cli.swarmd_main", "run", "--config"]
                        + [str(config)],
                        env=clean_env(),
                        stderr=err,
                    )
                )
        until(
            lambda: all(
                s.exists()
                and sum(p["state"] == "discovered" for p in daemon_status(s)["peers"]) == 1
                for s in socks
            ),
            lambda: "swarmd",
            CONVERGE_S,
        )
        machine_ids = [write_machine_id(work, i) for i in range(2)]

        def node(i: int, name: str, role: str, secs: float, *extra: str) -> Any:
            node_argv = [sys.executable, "-m", "swarmd_lab.ros2_node", role, "--name", name]
            return lan[i].popen(
                host_argv([*node_argv, "--seconds", str(secs), *extra], machine_ids[i]),
                env=ros2_lab.node_env(profiles / drones[i] / f"{name}.env"),
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
        for daemon in daemons:
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
