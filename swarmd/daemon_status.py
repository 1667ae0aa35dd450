"""The daemon's shared state and what it tells about itself: ``status`` (swarmctl status,
schema in docs/operations.md), ``healthy`` and the ``WATCHDOG=1`` it gates, the ``STATUS=``
line of sd_notify, and its counters. Split out of ``daemon.py`` by concern at 757 lines
(style.md rule 19), as ``swarmd/ros2/relay_announce.py`` declares the relay's shared state:
``Daemon`` (``swarmd/daemon.py``) is this class with its life cycle, and
``DaemonEvents`` (``swarmd/daemon_events.py``) routes discovery's events in between.
"""

from __future__ import annotations

import asyncio
import os
import random
from typing import TYPE_CHECKING, Any

from swarmd import __version__
from swarmd.auth.epoch import EpochResult
from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.auth.spdp import SpdpAuth
from swarmd.bundle.model import Bundle
from swarmd.changereports import ChangeReports
from swarmd.config import DaemonConfig
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import Event
from swarmd.discovery.inputs import LinkSample
from swarmd.driver import Driver
from swarmd.filewriter import FileWriter
from swarmd.link.monitor import LinkMonitor
from swarmd.peerlog import PeerHistory
from swarmd.sdnotify import Notifier
from swarmd.udp import BatchedSocket, Datagram

if TYPE_CHECKING:  # the daemon imports them once its engine runs (swarmd/daemon.py)
    from swarmd.control import ControlServer
    from swarmd.ros2app import Ros2App
    from swarmd.swarmapp import SwarmApp


class DaemonStatus:
    """The daemon's state, set in ``Daemon.__init__`` and ``Daemon.start`` (the comments
    there say why each exists), and the status it serves."""

    config: DaemonConfig
    bundle: Bundle
    log: Any
    notifier: Notifier
    monitor: LinkMonitor
    rng: random.Random
    engine_config: EngineConfig
    local_ipv4: str
    watchdog_s: float | None
    counters: dict[str, int]
    keyring: KeyRing | None
    epoch: EpochResult | None
    engine: DiscoveryEngine | None
    driver: Driver[bytes, Datagram, Event] | None
    stopped: asyncio.Event
    peer_history: PeerHistory
    _peer_changes: ChangeReports[tuple[str, str], object]
    app: SwarmApp | None
    ros2: Ros2App | None
    _secrets: NodeSecrets
    _spdp_auth: SpdpAuth | None
    _loop: asyncio.AbstractEventLoop | None
    _transports: dict[str, BatchedSocket]
    _watchdog: asyncio.TimerHandle | None
    _link_task: asyncio.Task[None] | None
    _control: ControlServer | None
    writer: FileWriter
    _status_line: str
    _ready: bool
    _started_wall: float
    _started: float

    def _core(self) -> DiscoveryEngine:
        if self.engine is None:
            raise RuntimeError("the daemon is not started")
        return self.engine

    def _drive(self) -> Driver[bytes, Datagram, Event]:
        if self.driver is None:
            raise RuntimeError("the daemon is not started")
        return self.driver

    def count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    def healthy(self) -> bool:
        """The loop runs, the link poller lives and the engine timer is not overdue."""
        if self._loop is None or self.stopped.is_set():
            return False
        if self._link_task is None or self._link_task.done():
            return False
        deadline = None if self.driver is None else self.driver.deadline
        if deadline is not None and self.watchdog_s is not None:
            # a timer more than one ping interval late means the loop is starved
            return self._loop.time() - deadline < self.watchdog_s
        return True

    def _watchdog_tick(self) -> None:
        if self._loop is None or self.watchdog_s is None:
            return
        if self.healthy():
            self.notifier.watchdog()
        else:
            self.count("watchdog_withheld")
            self.log.warning("watchdog_withheld", reason="loop unhealthy")
        if not self.stopped.is_set():
            self._watchdog = self._loop.call_later(self.watchdog_s, self._watchdog_tick)

    def _status_text(self) -> str:
        if self.engine is None:
            return "starting"
        discovered, total = self.engine.peer_counts()
        return f"phase {self.engine.phase}, peers {discovered}/{total} discovered"

    def status(self) -> dict[str, Any]:
        """The engine's status plus what only the daemon knows (schema: docs/operations.md)."""
        engine, now = self._core(), self._drive().now()
        st = dict(engine.status(now))
        st["node"] = self.config.node
        # per peer: the link quality it advertises (its own Q, from its latest DATA(p)) and how
        # often it was (re)discovered; the last changes for the operator in flight
        views = {v.name: v for v in engine.peers()}
        peers = []
        for row in st.get("peers") or []:
            view = views.get(row.get("name"))
            q = None if view is None else view.link_quality_permille
            peers.append(
                {
                    **row,
                    "link_q": None if q is None else q / 1000,
                    "times_discovered": 0 if view is None else view.times_discovered,
                }
            )
        st["peers"] = peers
        st["peer_changes"] = self.peer_history.status(now)
        latest: LinkSample | None = self.monitor.latest
        link = dict(st.get("link") or {})
        if latest is not None:
            for key, value in (
                ("q", latest.q),
                ("snr_db", latest.snr_db),
                ("source", latest.source),
            ):
                if link.get(key) is None:
                    link[key] = value
        link["active_source"] = self.monitor.active_source
        link["retired_sources"] = self.monitor.retired
        st["link"] = link
        counters = dict(st.get("counters") or {})
        counters["daemon"] = dict(self.counters)
        if self._control is not None:  # hostile or stuck local clients (docs/security.md)
            counters["daemon"]["control_clients_refused"] = self._control.rejected_clients
            counters["daemon"]["control_clients_idle_closed"] = self._control.idle_clients_closed
            counters["daemon"]["control_clients_slow_closed"] = self._control.slow_clients_closed
        # the saves on the writer's thread (swarmd.filewriter): a slow card shows as pending
        for name, value in self.writer.counters.items():
            counters["daemon"][f"file_{name}"] = value
        counters["daemon"]["file_writes_pending"] = self.writer.outstanding
        st["counters"] = counters
        if self.app is not None:
            st.update(self.app.status())
        if self.ros2 is not None:
            st["ros2"] = self.ros2.status(now)
        st["daemon"] = {
            "version": __version__,
            "pid": os.getpid(),
            "uptime_s": round(now - self._started, 3),
            "started_at": self._started_wall,
            "interface": self.config.interface,
            "ipv4": self.local_ipv4,
            "spdp": "{}:{}".format(*engine.spdp_multicast),
            "metatraffic_port": engine.metatraffic_port,
            "watchdog_s": self.watchdog_s,
            "healthy": self.healthy(),
        }
        return st
