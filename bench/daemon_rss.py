"""Daemon footprint at steady state: RSS and CPU of swarmd with 50 discovered peers.

    sudo .venv/bin/python bench/daemon_rss.py [--peers 50] [--measure-s 30] [--json]

Starts peers + 1 real ``swarmd run`` processes, one per network namespace on one bridge
(``swarmd_lab.netns.Lan``), waits until the first one (uav1) has discovered all its peers, lets
the swarm settle, then samples every daemon's ``/proc/PID`` over ``--measure-s`` seconds:
VmRSS at the end, VmHWM (peak RSS), and CPU = (utime + stime) delta / wall time, in percent
of one core. Reports uav1 and the median/max over all daemons. Targets (issue 4): RSS
<= 60 MB, CPU <= 3 % of one core. Exits 1 if uav1 misses either. Needs root.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd_lab.netns import Lan, unavailable_reason  # noqa: E402

from swarmd.control import DaemonUnreachable, request  # noqa: E402
from tests.daemon_support import write_bundle, write_config  # noqa: E402

RSS_TARGET_MB = 60.0
CPU_TARGET_PCT = 3.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def _proc_status(pid: int, key: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024  # kB -> MiB
    raise KeyError(key)


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK  # utime, stime (fields 14, 15)


def _discovered(sock: Path) -> int:
    try:
        st: dict[str, Any] = request(str(sock), "status")
    except DaemonUnreachable:
        return -1
    return int(st["peers_discovered"])


def run(peers: int, measure_s: float, settle_s: float) -> dict[str, Any]:
    n = peers + 1
    with tempfile.TemporaryDirectory(prefix="swb-") as tmp, Lan(n) as lan:
        work = Path(tmp)
        files = write_bundle(work, n, domain_id=0, ipv4=[h.address for h in lan.hosts])
        procs: list[subprocess.Popen[bytes]] = []
        socks = []
        for i, host in enumerate(lan.hosts):
            name = f"uav{i + 1}"
            sock = work / f"{name}.sock"
            cfg = write_config(
                work / f"{name}.yaml",
                files,
                node=name,
                interface=host.ifname,
                socket_path=str(sock),
                poll_s=1.0,
            )
            socks.append(sock)
            swarmd = str(Path(sys.executable).parent / "swarmd")
            procs.append(
                host.popen([swarmd, "run", "--config", str(cfg)], stderr=subprocess.DEVNULL)
            )
        t0 = time.monotonic()
        while _discovered(socks[0]) < peers:
            if time.monotonic() - t0 > 300:
                raise SystemExit("uav1 did not discover every peer within 300 s")
            time.sleep(0.5)
        discovery_s = time.monotonic() - t0
        time.sleep(settle_s)
        pids = [p.pid for p in procs]  # `ip netns exec` execs swarmd: same pid
        cpu0 = [_cpu_s(pid) for pid in pids]
        w0 = time.monotonic()
        time.sleep(measure_s)
        wall = time.monotonic() - w0
        cpu = [(_cpu_s(pid) - c) / wall * 100 for pid, c in zip(pids, cpu0, strict=True)]
        rss = [_proc_status(pid, "VmRSS") for pid in pids]
        hwm = [_proc_status(pid, "VmHWM") for pid in pids]
        all_found = sum(_discovered(s) == peers for s in socks)
    return {
        "peers": peers,
        "daemons": n,
        "measure_s": round(wall, 1),
        "discovery_wall_s": round(discovery_s, 1),
        "daemons_fully_discovered": all_found,
        "uav1": {
            "rss_mb": round(rss[0], 1),
            "peak_rss_mb": round(hwm[0], 1),
            "cpu_pct": round(cpu[0], 2),
        },
        "all": {
            "rss_mb_median": round(statistics.median(rss), 1),
            "rss_mb_max": round(max(rss), 1),
            "peak_rss_mb_max": round(max(hwm), 1),
            "cpu_pct_median": round(statistics.median(cpu), 2),
            "cpu_pct_max": round(max(cpu), 2),
        },
        "machine": (
            f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
        ),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--peers", type=int, default=50)
    parser.add_argument("--measure-s", type=float, default=30.0)
    parser.add_argument("--settle-s", type=float, default=10.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    reason = unavailable_reason()
    if reason is not None:
        print(f"daemon_rss: {reason}", file=sys.stderr)
        return 2
    r = run(args.peers, args.measure_s, args.settle_s)
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        u, a = r["uav1"], r["all"]
        print(f"{r['daemons']} daemons ({r['peers']} peers each), {r['machine']}")
        print("| daemon | RSS MB | peak RSS MB | CPU % of one core |")
        print("|---|---:|---:|---:|")
        print(f"| uav1 | {u['rss_mb']} | {u['peak_rss_mb']} | {u['cpu_pct']} |")
        print(
            f"| all {r['daemons']}: median / max | {a['rss_mb_median']} / {a['rss_mb_max']} "
            f"| - / {a['peak_rss_mb_max']} | {a['cpu_pct_median']} / {a['cpu_pct_max']} |"
        )
        print(
            f"uav1 discovered all {r['peers']} peers after {r['discovery_wall_s']} s wall "
            f"(all daemons started at once); {r['daemons_fully_discovered']}/{r['daemons']} "
            f"daemons saw every peer at the end; measured over {r['measure_s']} s"
        )
    ok = r["uav1"]["rss_mb"] <= RSS_TARGET_MB and r["uav1"]["cpu_pct"] <= CPU_TARGET_PCT
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
