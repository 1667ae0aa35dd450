"""How often a starting ROS 2 node misses the relay's first answer (docs/ros2.md, "A late
publisher").

The testbed's ``ros2-swarmd`` route once showed a talker whose messages began one relay
renewal late. This harness repeats that start-up on wired namespaces, ``--runs`` times: N
drones (``swarmd_lab.netns.Lan``), swarmd with ``ros2.relay: true`` on each (the relay's
default lease, 20 s: renewals every 5 s), the testbed's workload node
(``bench/wifi/peers/ros2_peer.py``, read, not changed) on each, all started together through a
barrier once every swarmd has discovered every other drone, as the testbed does. Per run
and talker it prints when the talker's publisher matched the commander's subscription
(seconds after the barrier); a talker counts as *late* when that took longer than
``--late-s`` (a missed answer waits for the next renewal, seconds away; a taken one matches
within a few hundred ms here).

    PYTHONPATH=.:lab python bench/ros2_start_race.py --n 5 --runs 12 --seconds 8   # as root

``PYTHONPATH`` decides which ``swarmd`` runs (the daemons inherit it): put another checkout
there to measure that checkout.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
sys.path += [str(REPO), str(REPO / "lab")]  # after PYTHONPATH: it picks the checkout

from swarmd_lab import netns, ros2_lab  # noqa: E402

from bench.wifi.ros2_contenders import ros2_mission_text  # noqa: E402
from tests.daemon_support import (  # noqa: E402
    Daemons,
    clean_env,
    daemon_status,
    relay_config,
    ros2_profiles,
    write_mission_bundle,
)

PEER = REPO / "bench" / "wifi" / "peers" / "ros2_peer.py"
CONVERGE_S = 30.0
BARRIER_S = 60.0


def one_run(n: int, seconds: float, work: Path) -> dict[str, Any]:
    """One start-up: {"talker_matched_s": {member: s or None}, "relay_counters": [...]}."""
    with netns.Lan(n) as lan:
        # the testbed's mission with swarmd's own discovery quicker (t 0.5-2 s), so that a
        # run does not wait out the testbed's 8-20 s announcement schedule
        text = ros2_mission_text([lan[i].address for i in range(n)]).replace(
            "t_min_s: 8.0, t_max_s: 20.0", "t_min_s: 0.5, t_max_s: 2.0"
        )
        files = write_mission_bundle(work, text, "wifibench", "ros2-start-race.yaml")
        profiles = work / "profiles"
        if ros2_profiles(files, profiles, "--via-swarmd") != 0:
            raise RuntimeError("swarmctl ros2 profile failed")
        names = [f"uav{i + 1}" for i in range(n)]
        swarmd = [sys.executable, "-m", "swarmd.cli.swarmd_main"]
        daemons = Daemons(
            lan, work, files, names, extra=relay_config(), command=swarmd, env=clean_env()
        )
        daemons.start_all(CONVERGE_S)
        barrier = work / "barrier.sock"
        server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        server.bind(str(barrier))
        server.listen(n)
        server.settimeout(BARRIER_S)
        launcher = ros2_lab.NodeLauncher(lan, names, profiles, work)
        nodes = []
        for i in range(n):
            role = "listener" if i == 0 else "talker"
            peer_argv = [sys.executable, str(PEER), "--index", str(i), "--n", str(n)]
            peer_argv += ["--duration", str(seconds), "--messages", "1"]
            peer_argv += ["--out", str(work / f"r{i}.json"), "--barrier", str(barrier)]
            with (work / f"node{i}.log").open("wb") as log:
                nodes.append(
                    launcher.start(i, role, peer_argv, stdout=log, stderr=subprocess.STDOUT)
                )
        waiting = [server.accept()[0] for _ in range(n)]
        time.sleep(0.5)  # every node imported rclpy and waits on the barrier
        t0 = time.time()
        for conn in waiting:
            conn.send(b"x")
            conn.close()
        server.close()
        for node in nodes:
            node.wait(timeout=seconds + BARRIER_S)
        counters = [daemon_status(s)["ros2"]["counters"] for s in daemons.socks]
        for d in daemons.procs:
            d.terminate()
            d.wait(timeout=20)
    matched: dict[int, float | None] = {}
    for i in range(1, n):
        at = json.loads((work / f"r{i}.json").read_text()).get("commander_matched")
        matched[i] = None if at is None else round(at - t0, 3)
    return {"talker_matched_s": matched, "relay_counters": counters}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0] if __doc__ else "")
    parser.add_argument("--n", type=int, default=5, help="drones (one listener, N-1 talkers)")
    parser.add_argument("--runs", type=int, default=12)
    parser.add_argument("--seconds", type=float, default=8.0, help="each node's run")
    parser.add_argument("--late-s", type=float, default=1.0)
    args = parser.parse_args()
    late_runs = late_talkers = 0
    for k in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="ros2-start-race-") as tmp:
            run = one_run(args.n, args.seconds, Path(tmp))
        matched = run["talker_matched_s"]
        late = [m for m, s in matched.items() if s is None or s > args.late_s]
        late_talkers += len(late)
        late_runs += bool(late)
        answers = [c.get("tx_start_answers") for c in run["relay_counters"]]
        print(json.dumps({"run": k + 1, "talker_matched_s": matched, "late": late,
                          "tx_start_answers": answers}), flush=True)  # fmt: skip
    print(
        f"runs {args.runs}, N {args.n}: {late_runs} run(s) with a late talker, "
        f"{late_talkers} late talker(s) of {args.runs * (args.n - 1)}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
