"""uXRCE-DDS figures for docs/benchmarks.md (issue 12), against the real third-party peers
(``XRCE_PEERS``: px4_like_client and MicroXRCEAgent built elsewhere; see lab/swarmd_lab/xrce.py).

    .venv/bin/python bench/xrce.py [--runs 3] [--pairs 20] [--cpu-s 30] [--wifi-s 30]
                                   [--out bench/results/xrce.json]

1. ready: px4_like_client (PX4 1.16 stand-in, PX4's time sync on) started -> swarmd's bridge
   says "ready", swarmd as the agent (loopback), ``--runs`` times.
2. command latency: ARM sent -> its ack observed by swarmd, ``--pairs`` ARM/DISARM pairs, over
   XRCE (swarmd as agent; and as a second client through MicroXRCEAgent) and over MAVLink
   (swarmd's MAVLink backend and the lab's MAVLink vehicle simulator).
3. CPU of swarmd's XRCE agent (its own process) serving ``px4_like_client -a`` (every topic of
   PX4's dds_topics.yaml at PX4's rates) for ``--cpu-s``.
4. Wi-Fi side (root; two drones, each a network namespace on one bridge, each with its PX4
   stand-in and its agent): UDP frames on drone 0's eth0 during ``--wifi-s`` with swarmd as
   the agent, against MicroXRCEAgent with UXRCE_DDS_PTCFG=0 (PX4's default participant: SPDP,
   and SEDP once the other drone's participant is found) and =1 (localhost-only).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd_lab.netns import Lan, unavailable_reason  # noqa: E402
from swarmd_lab.px4.sim_model import SimConfig  # noqa: E402
from swarmd_lab.px4.vehicle_sim import start_sim  # noqa: E402
from swarmd_lab.xrce import ETH_P_ALL, count_udp, peer_bin, peer_env  # noqa: E402

from swarmd.px4.backend import VehicleBackend  # noqa: E402
from swarmd.px4.bridge import Px4Bridge  # noqa: E402
from swarmd.px4.constants import MavCmd  # noqa: E402
from swarmd.px4.mavlink_backend import MavlinkBackend  # noqa: E402
from swarmd.px4.messages import CommandAck, Heartbeat, Observation, VehicleCommand  # noqa: E402
from swarmd.px4.readiness import ReadinessConfig  # noqa: E402
from swarmd.px4.transport import parse_connection  # noqa: E402
from swarmd.px4.xrce_backend import XrceBackend  # noqa: E402


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def ready_time() -> float:
    port = free_port()
    bridge = Px4Bridge(XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}"),
                       readiness_config=ReadinessConfig(require_home=False))  # fmt: skip
    await bridge.start()
    loop = asyncio.get_running_loop()
    ready = asyncio.Event()
    bridge.on_readiness_change(lambda r: ready.set() if r.ready else None)
    t0 = loop.time()
    client = await asyncio.create_subprocess_exec(
        str(peer_bin("px4_like_client")), "-p", str(port), "-V", "1.16", "-q"
    )
    try:
        await asyncio.wait_for(ready.wait(), 60)
        return loop.time() - t0
    finally:
        client.terminate()
        await client.wait()
        await bridge.close()


async def ack_latencies(backend: VehicleBackend, pairs: int) -> list[float]:
    """ARM -> its ack, ``pairs`` times (each followed by a DISARM and its ack)."""
    loop = asyncio.get_running_loop()
    acks: asyncio.Queue[tuple[int, float]] = asyncio.Queue()
    seen = asyncio.Event()

    def sink(obs: Observation, now: float) -> None:
        if isinstance(obs, Heartbeat):
            seen.set()
        elif isinstance(obs, CommandAck):
            acks.put_nowait((obs.command, now))

    await backend.start(sink)
    await asyncio.wait_for(seen.wait(), 60)
    out = []
    for _ in range(pairs):
        for arm in (1.0, 0.0):
            t0 = loop.time()
            backend.send(VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=arm))
            while True:
                command, t1 = await asyncio.wait_for(acks.get(), 5)
                if command == MavCmd.COMPONENT_ARM_DISARM:
                    break
            if arm:
                out.append(t1 - t0)
            await asyncio.sleep(0.2)
    await backend.close()
    return out


async def latency_xrce_agent(pairs: int) -> list[float]:
    port = free_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}")
    client = await asyncio.create_subprocess_exec(
        str(peer_bin("px4_like_client")), "-p", str(port), "-V", "1.16", "-q",
        stdout=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    try:
        return await ack_latencies(backend, pairs)
    finally:
        client.terminate()
        await client.wait()


async def latency_xrce_client(pairs: int) -> list[float]:
    port = free_port()
    agent = await asyncio.create_subprocess_exec(
        str(peer_bin("MicroXRCEAgent")), "udp4", "-p", str(port), env=peer_env(),
        stdout=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    client = await asyncio.create_subprocess_exec(
        str(peer_bin("px4_like_client")), "-p", str(port), "-V", "1.16", "-c", "1", "-q",
        stdout=asyncio.subprocess.DEVNULL,
    )  # fmt: skip
    try:
        return await ack_latencies(XrceBackend("xrce-client", f"udp:127.0.0.1:{port}"), pairs)
    finally:
        for p in (client, agent):
            p.terminate()
            await p.wait()


async def latency_mavlink(pairs: int) -> list[float]:
    port = free_port()
    backend = MavlinkBackend(f"udpin:127.0.0.1:{port}", sysid=1)
    sim = await start_sim(
        SimConfig(gps_fix_after_s=0.0), parse_connection(f"udpout:127.0.0.1:{port}")
    )
    try:
        return await ack_latencies(backend, pairs)
    finally:
        sim.close()


def cpu_full_topic_set(seconds: float) -> dict[str, Any]:
    port = free_port()
    serve = subprocess.Popen(  # noqa: S603
        [sys.executable, "-m", "swarmd_lab.xrce", "serve", "--port", str(port),
         "--seconds", str(seconds)],
        stdout=subprocess.PIPE, cwd=ROOT,
    )  # fmt: skip
    client = subprocess.Popen(  # noqa: S603
        [str(peer_bin("px4_like_client")), "-p", str(port), "-V", "1.16", "-a", "-q"],
        stdout=subprocess.DEVNULL,
    )
    try:
        out, _ = serve.communicate(timeout=seconds + 60)
    finally:
        client.terminate()
        client.wait()
    result: dict[str, Any] = json.loads(out)
    result["samples_per_s"] = round(result["samples"] / result["wall_s"], 1)
    return result


def wifi_side(seconds: float) -> dict[str, Any]:
    if (why := unavailable_reason()) is not None:
        return {"skipped": why}
    client = str(peer_bin("px4_like_client"))
    out: dict[str, Any] = {}
    with Lan(2) as lan:
        cases = {
            "swarmd_agent": ([sys.executable, "-m", "swarmd_lab.xrce", "serve", "--port",
                              "8888", "--seconds", str(seconds + 30)], ["-c", "0"]),
            "microxrceagent_ptcfg0": ([str(peer_bin("MicroXRCEAgent")), "udp4", "-p", "8888"],
                                      ["-c", "0"]),
            "microxrceagent_ptcfg1": ([str(peer_bin("MicroXRCEAgent")), "udp4", "-p", "8888"],
                                      ["-c", "1"]),
        }  # fmt: skip
        for name, (agent, ptcfg) in cases.items():
            sock = lan[0].socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
            sock.bind(("eth0", 0))
            for ns in lan:
                ns.popen(agent, env=peer_env(), stdout=subprocess.DEVNULL)
                ns.popen([client, "-p", "8888", "-a", "-q", *ptcfg], stdout=subprocess.DEVNULL)
            counts = count_udp(sock, seconds)
            sock.close()
            for ns in lan:
                ns.stop_children()
            out[name] = counts
    out["window_s"] = seconds
    return out


def summary(xs: list[float]) -> dict[str, float]:
    ms = sorted(x * 1000 for x in xs)
    return {
        "n": len(ms),
        "median_ms": round(statistics.median(ms), 3),
        "p90_ms": round(ms[int(0.9 * (len(ms) - 1))], 3),
        "max_ms": round(ms[-1], 3),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--pairs", type=int, default=20)
    ap.add_argument("--cpu-s", type=float, default=30.0)
    ap.add_argument("--wifi-s", type=float, default=30.0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "xrce.json")
    ap.add_argument("--only-wifi", action="store_true", help="only part 4, merged into --out")
    args = ap.parse_args()
    os.chdir(ROOT)
    res: dict[str, Any] = {
        "host": platform.node(),
        "python": platform.python_version(),
        "load_1min": round(os.getloadavg()[0], 2),
    }
    if args.only_wifi:
        res = json.loads(args.out.read_text()) if args.out.exists() else res
        res["wifi_side"] = wifi_side(args.wifi_s)
        print("Wi-Fi side UDP frames:", json.dumps(res["wifi_side"]), flush=True)
        args.out.write_text(json.dumps(res, indent=2) + "\n")
        return 0
    res["ready_s"] = [round(asyncio.run(ready_time()), 3) for _ in range(args.runs)]
    print("ready after client start (s):", res["ready_s"], flush=True)
    lat = {
        "xrce_agent": summary(asyncio.run(latency_xrce_agent(args.pairs))),
        "xrce_client_via_microxrceagent": summary(asyncio.run(latency_xrce_client(args.pairs))),
        "mavlink_simulator": summary(asyncio.run(latency_mavlink(args.pairs))),
    }
    res["arm_ack_latency"] = lat
    print("ARM -> ack latency:", json.dumps(lat), flush=True)
    res["cpu_full_topic_set"] = cpu_full_topic_set(args.cpu_s)
    print("swarmd XRCE agent CPU with -a:", json.dumps(res["cpu_full_topic_set"]), flush=True)
    res["wifi_side"] = wifi_side(args.wifi_s)
    print("Wi-Fi side UDP frames:", json.dumps(res["wifi_side"]), flush=True)
    res["load_1min_end"] = round(os.getloadavg()[0], 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2) + "\n")
    print("wrote", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
