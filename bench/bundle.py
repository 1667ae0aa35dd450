"""Firmware bundle benchmark: build and load time and file size for 10, 50 and 500
participants with 5 topics each (issue 3). Prints a markdown table and the machine.

    .venv/bin/python bench/bundle.py [--repeat 7]

Build = parse + check the mission YAML, derive identities, encode, hash, sign.
Load = what the daemon does at start: read the file, check framing, SHA-256, Ed25519
signature against the trusted key, decode the body and check it against the derivations.
Exits 1 if loading the 500-participant bundle takes more than 200 ms (median).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.build import build_bundle
from swarmd.bundle.keys import raw_public
from swarmd.bundle.loader import load_bundle
from swarmd.bundle.mission import parse_mission

SIZES = (10, 50, 500)
LOAD_BUDGET_S = 0.200

TOPICS = """\
topics:
  - {name: swarm/ready, type: "swarmd::Readiness", reliability: best_effort, history_depth: 1,
     writers: member, readers: commander}
  - {name: swarm/command, type: "swarmd::Command", reliability: reliable, history_depth: 8,
     writers: commander, readers: member}
  - {name: swarm/position, type: "swarmd::Position", liveliness_lease_s: 2.5,
     writers: all, readers: all}
  - {name: swarm/plan, type: "swarmd::MissionPlan", reliability: reliable,
     durability: transient_local, writers: commander, readers: member}
  - {name: rt/fmu/out/vehicle_status, type: "px4_msgs::msg::dds_::VehicleStatus_",
     writers: member, readers: commander}
"""


def mission_text(n: int) -> str:
    lines = [f"swarm: bench-{n}", "domain_id: 0", "participants:"]
    for i in range(n):
        role = "commander" if i == 0 else "member"
        # MAVLink has 254 vehicle ids; past that the mission check allows reuse
        lines.append(
            f"  - {{name: uav-{i:03d}, index: {i}, role: {role}, "
            f"mavlink_sysid: {1 + i % 254}, ipv4: 10.{i // 250}.{i % 250}.1}}"
        )
    return "\n".join(lines) + "\n" + TOPICS


def machine() -> str:
    def sh(*argv: str) -> str:
        try:
            return subprocess.run(argv, capture_output=True, text=True, check=False).stdout.strip()
        except FileNotFoundError:
            return "?"

    lscpu = "\n".join(sh("lscpu").splitlines()[:10])
    return (
        f"nproc: {sh('nproc')}\n{lscpu}\n"
        f"python: {sys.version.split()[0]} ({platform.python_implementation()})"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    signing = Ed25519PrivateKey.generate()
    trusted = raw_public(signing)
    rows = []
    load_500 = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for n in SIZES:
            text = mission_text(n)
            builds, loads = [], []
            data = b""
            path = Path(tmp) / f"bench-{n}.swb"
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                mission = parse_mission(text, f"bench-{n}.yaml")
                keys = {p.name: (trusted, trusted) for p in mission.participants}
                data = build_bundle(mission, signing, keys).data
                builds.append(time.perf_counter() - t0)
            path.write_bytes(data)
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                bundle = load_bundle(path, trusted)
                loads.append(time.perf_counter() - t0)
            assert bundle.size == n
            endpoints = sum(len(p.endpoints) for p in bundle.participants)
            load_med = statistics.median(loads)
            if n == 500:
                load_500 = load_med
            rows.append(
                f"| {n} | 5 | {endpoints} | {len(data):,} | "
                f"{statistics.median(builds) * 1000:.1f} | {load_med * 1000:.1f} | "
                f"{max(loads) * 1000:.1f} |"
            )
    print(machine())
    print()
    print(f"median of {args.repeat} runs")
    print()
    print("| participants | topics | endpoints | file bytes | build ms | load ms | load max ms |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    ok = load_500 <= LOAD_BUDGET_S
    verdict = "within" if ok else "OVER"
    print(
        f"\nload of the 500-participant bundle: {load_500 * 1000:.1f} ms, "
        f"{verdict} the 200 ms budget"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
