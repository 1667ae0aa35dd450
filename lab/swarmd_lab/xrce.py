"""Lab tools for the uXRCE-DDS backends: a stand-alone agent, Wi-Fi-side capture, timings.

Used by ``bench/xrce.py`` (the figures in docs/benchmarks.md) and the netns test. The PX4
side is swarmd's own stand-in (``swarmd_lab.px4.xrce_vehicle``); the third-party peers
(``px4_like_client``, ``MicroXRCEAgent``) are optional, built elsewhere and found through
``XRCE_PEERS`` (a directory holding them, or their ``bin/``; their libraries in ``lib/``):
nothing here builds them.

    python -m swarmd_lab.xrce serve --port 8888 [--seconds S] [--client]
        swarmd's XRCE agent alone (or a client of the agent on PORT); one JSON line at exit:
        samples, sessions, its own CPU seconds and wall time
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import socket
import struct
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Final

from swarmd.px4.messages import Observation, StateReset
from swarmd.px4.xrce_backend import Mode, XrceBackend

ETH_P_ALL: Final = 0x0003
REPO: Final = Path(__file__).resolve().parents[2]


def peers_root() -> Path | None:
    env = os.environ.get("XRCE_PEERS")
    return Path(env) if env else None


def peer_bin(name: str) -> Path:
    """The third-party peer ``name`` under ``XRCE_PEERS`` (RuntimeError: one line saying so)."""
    root = peers_root()
    if root is None:
        raise RuntimeError(f"{name}: set XRCE_PEERS to a directory holding it (built elsewhere)")
    for path in (root / name, root / "bin" / name):
        if path.exists():
            return path
    raise RuntimeError(f"XRCE_PEERS={root}: no {name} in it (or in its bin/)")


def peer_env() -> dict[str, str]:
    root = peers_root()
    return dict(os.environ, LD_LIBRARY_PATH=str(root / "lib") if root is not None else "")


async def serve(port: int, seconds: float, mode: Mode = "xrce-agent") -> dict[str, Any]:
    """Run swarmd's XRCE backend (the agent on 127.0.0.1:``port``, or a client of the agent
    there); count what it decodes."""
    backend = XrceBackend(mode, f"udp:127.0.0.1:{port}")
    counts: dict[str, int] = {}
    first = asyncio.Event()

    def sink(obs: Observation, now: float) -> None:
        counts[type(obs).__name__] = counts.get(type(obs).__name__, 0) + 1
        # a new session's StateReset comes before PX4's time sync and first sample
        if not isinstance(obs, StateReset):
            first.set()

    await backend.start(sink)
    loop = asyncio.get_running_loop()
    await first.wait()  # the window starts with the first sample (after PX4's time sync)
    cpu0, t0 = _cpu(), loop.time()
    await asyncio.sleep(seconds)
    cpu, wall = _cpu() - cpu0, loop.time() - t0
    stats = backend.stats()
    await backend.close()
    return {
        "cpu_s": round(cpu, 3),
        "wall_s": round(wall, 3),
        "cpu_pct": round(100 * cpu / wall, 2),
        "datagrams_in": stats.get("datagrams_in", 0),
        "samples": stats.get("samples", 0),
        "observations": counts,
        "px4_version": stats.get("px4_version"),
        "sessions": stats.get("sessions", 0),
        "dropped": stats.get("dropped", {}),
    }


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def count_udp(
    sock: socket.socket, seconds: float, stop: Callable[[], bool] | None = None
) -> dict[str, int]:
    """Frames on an AF_PACKET socket for ``seconds`` (or until ``stop()``): every frame, the
    UDP ones (IPv4/IPv6), and the RTPS ones among them (DDS discovery and data)."""
    sock.settimeout(0.2)
    end = time.monotonic() + seconds
    out = {"frames": 0, "udp": 0, "udp_bytes": 0, "rtps": 0}
    while time.monotonic() < end and not (stop is not None and stop()):
        try:
            frame = sock.recv(65535)
        except TimeoutError:
            continue
        out["frames"] += 1
        ethertype = struct.unpack_from("!H", frame, 12)[0] if len(frame) >= 14 else 0
        payload: bytes | None = None
        if ethertype == 0x0800 and len(frame) >= 34 and frame[23] == 17:
            ihl = (frame[14] & 0x0F) * 4
            payload = frame[14 + ihl + 8 :]
        elif ethertype == 0x86DD and len(frame) >= 62 and frame[20] == 17:
            payload = frame[62:]
        if payload is not None:
            out["udp"] += 1
            out["udp_bytes"] += len(frame)
            if payload[:4] == b"RTPS":
                out["rtps"] += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m swarmd_lab.xrce")
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="swarmd's XRCE agent on 127.0.0.1:PORT, then a JSON line")
    s.add_argument("--port", type=int, default=8888)
    s.add_argument("--seconds", type=float, default=30.0)
    s.add_argument("--client", action="store_true", help="join the agent on PORT as a client")
    args = p.parse_args(argv)
    mode: Mode = "xrce-client" if args.client else "xrce-agent"
    result = asyncio.run(serve(args.port, args.seconds, mode))
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
