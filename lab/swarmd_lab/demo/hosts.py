"""Where the demo's drones run: one network namespace each, or all on the loopback.

Namespaces (root): ``swarmd_lab.netns.Lan`` puts drone i in its own namespace with ``eth0`` =
10.77.X.(i+1) on one bridge; its daemon and vehicle simulator talk MAVLink over the
namespace's own loopback on PX4 SITL's port 14540, exactly like a companion computer and its
flight controller.

Loopback (no root): every drone shares 127.0.0.1. Discovery still separates them — the RTPS
port mapping gives each participant index its own metatraffic and user ports, and the SPDP
multicast group is joined on ``lo`` with ``IP_MULTICAST_LOOP`` — and drone i's simulator uses
MAVLink port 14540 + i, as PX4 SITL instance i does.

Both stop every process they started on ``close()`` (SIGTERM, then SIGKILL), and the
namespaces go with it; ``close()`` is idempotent and runs on every exit path of the demo.
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from dataclasses import replace
from typing import IO, Final

from swarmd_lab.demo.scenario import PX4_PORT, Drone
from swarmd_lab.netns import Lan, stop_processes

STOP_TIMEOUT_S: Final = 5.0


class Hosts:
    """The loopback placement; ``NamespaceHosts`` overrides where things run."""

    mode = "loopback"

    def __init__(self, n: int) -> None:
        self.n = n
        self._procs: list[subprocess.Popen[bytes]] = []

    def open(self) -> None:
        """Nothing to build on the loopback."""

    def place(self, drones: Sequence[Drone]) -> list[Drone]:
        return [replace(d, address="127.0.0.1", interface="lo", mavlink_port=PX4_PORT + d.index)
                for d in drones]  # fmt: skip

    def command(self, index: int, argv: Sequence[str]) -> list[str]:
        """``argv`` as run for drone ``index``."""
        return list(argv)

    def popen(self, index: int, argv: Sequence[str], log: IO[bytes]) -> subprocess.Popen[bytes]:
        proc = subprocess.Popen(  # noqa: S603 - argv list, no shell
            self.command(index, argv),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        self._procs.append(proc)
        return proc

    def close(self) -> None:
        """SIGTERM (daemons leave cleanly, telling their peers), then SIGKILL stragglers."""
        stop_processes(self._procs, STOP_TIMEOUT_S)
        self._procs.clear()


class NamespaceHosts(Hosts):
    """One network namespace per drone on one bridge (needs root)."""

    mode = "namespaces"

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self.lan = Lan(n)

    def open(self) -> None:
        self.lan.__enter__()

    def place(self, drones: Sequence[Drone]) -> list[Drone]:
        return [
            replace(
                d,
                address=self.lan[d.index].address,
                interface=self.lan[d.index].ifname,
                mavlink_port=PX4_PORT,
            )
            for d in drones
        ]

    def command(self, index: int, argv: Sequence[str]) -> list[str]:
        return self.lan[index].command(argv)

    def close(self) -> None:
        try:
            super().close()  # SIGTERM first, so daemons send DATA(p[UD]) while the LAN exists
        finally:
            self.lan.close()
