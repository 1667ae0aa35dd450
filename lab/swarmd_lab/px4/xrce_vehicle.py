"""``swarmd-px4-xrce``: the PX4 stand-in over uXRCE-DDS on a UDP socket (a SIMULATOR, not PX4).

    swarmd-px4-xrce -p 8888                       # PX4 1.16, UXRCE_DDS_KEY 1, MAV_SYS_ID 1
    swarmd-px4-xrce -p 8888 -V 1.14 -k 2 -S 2    # another release, key and system id
    swarmd-px4-xrce -p 8888 -c 0 -d 3            # PTCFG=0 participant, DDS domain 3
      -n NS   UXRCE_DDS_NS     --gps-fix-after S  (0)    -D S  exit after S s
      --seed N                 -q  only warnings on stderr

Every command it receives is one JSON line on stdout (``{"event": "vehicle_command",
"via": "topic"|"service", "fields": {...}, "ack_result": N}``); session and set-up events
are JSON lines on stderr. The one asyncio adapter of ``Px4XrceStandin`` (style.md rule 11):
datagrams in, engine, datagrams out, one timer re-armed at ``get_timer()``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import random
import signal
import sys
from collections.abc import Sequence
from typing import Any

from swarmd.xrce.px4_layouts import LAYOUTS
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.xrce_standin import Px4XrceStandin, StandinConfig

NOTE = "PX4 stand-in over uXRCE-DDS: a SIMULATOR, not PX4"


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, run: StandinRun) -> None:
        self.run = run

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.run.received(data, addr)


class StandinRun:
    """The stand-in on a connected UDP socket to the agent at ``host:port``."""

    def __init__(self, standin: Px4XrceStandin, host: str, port: int, quiet: bool) -> None:
        self.standin = standin
        self.agent = (host, port)
        self.quiet = quiet
        self.loop = asyncio.get_running_loop()
        self.transport: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._phase = ""

    async def start(self) -> None:
        self.transport, _ = await self.loop.create_datagram_endpoint(
            lambda: _Protocol(self), remote_addr=self.agent
        )
        peer = self.transport.get_extra_info("peername")
        self.agent = (peer[0], peer[1])
        self.standin.connect(self.agent, self.loop.time())
        self._transmit()

    def received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.standin.receive_datagram(data, (addr[0], addr[1]), self.loop.time())
        self._transmit()

    def _on_timer(self) -> None:
        self._timer = None
        self.standin.handle_timer(self.loop.time())
        self._transmit()

    def _transmit(self) -> None:
        if self.transport is not None:
            for data, _addr in self.standin.datagrams_to_send():
                self.transport.sendto(data)
        self._logs()
        at = self.standin.get_timer()
        if self._timer is not None:
            self._timer.cancel()
        self._timer = None if at is None else self.loop.call_at(at, self._on_timer)

    def _logs(self) -> None:
        phase = self.standin.client.phase
        if phase != self._phase:
            self._phase = phase
            self._err({"event": "phase", "phase": phase,
                       "timesync_samples": self.standin.client.timesync_good})  # fmt: skip
        while (rec := self.standin.next_log()) is not None:
            if rec["event"] == "vehicle_command":
                print(json.dumps(rec), flush=True)
            else:
                self._err(rec)

    def _err(self, rec: dict[str, Any]) -> None:
        if not self.quiet or rec.get("event") in ("session",):
            print(json.dumps({**rec, "note": NOTE}), file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        if self.transport is not None:
            self.standin.client.disconnect(self.loop.time())
            for data, _addr in self.standin.datagrams_to_send():
                self.transport.sendto(data)
            self.transport.close()


async def run(args: argparse.Namespace) -> int:
    vehicle = SimConfig(sysid=args.sysid, gps_fix_after_s=args.gps_fix_after)
    config = StandinConfig(
        release=args.release, key=args.key, namespace=args.namespace,
        localhost_only=args.ptcfg == 1, domain_id=args.domain, vehicle=vehicle,
    )  # fmt: skip
    loop = asyncio.get_running_loop()
    rng = random.Random(args.seed)  # noqa: S311 - a simulation's seeded draws, not secrets
    standin = Px4XrceStandin(config, rng, loop.time())
    stop = asyncio.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    runner = StandinRun(standin, args.agent, args.port, args.quiet)
    await runner.start()
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), args.duration)
    finally:
        runner.close()
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="swarmd-px4-xrce", description=NOTE)
    p.add_argument("-p", "--port", type=int, default=8888, help="the agent's UDP port")
    p.add_argument("--agent", default="127.0.0.1", help="the agent's address")
    p.add_argument("-V", "--release", default="1.16", choices=list(LAYOUTS))
    p.add_argument("-k", "--key", type=int, default=1, help="UXRCE_DDS_KEY (1)")
    p.add_argument("-S", "--sysid", type=int, default=1, help="MAV_SYS_ID (1)")
    p.add_argument("-n", "--namespace", default=None, help="UXRCE_DDS_NS")
    p.add_argument(
        "-c",
        "--ptcfg",
        type=int,
        default=1,
        choices=(0, 1),
        help="UXRCE_DDS_PTCFG: 1 localhost-only participant (default), 0 default",
    )
    p.add_argument("-d", "--domain", type=int, default=0, help="UXRCE_DDS_DOM_ID")
    p.add_argument("-D", "--duration", type=float, default=None, help="exit after S s")
    p.add_argument("--gps-fix-after", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = parser().parse_args(argv)
    if not 1 <= args.sysid <= 255 or not 0 <= args.key <= 0xFFFFFFFF:
        print("swarmd-px4-xrce: --sysid is 1..255 and --key 0..2^32-1", file=sys.stderr)
        return 2
    return asyncio.run(run(args))


if __name__ == "__main__":
    sys.exit(main())
