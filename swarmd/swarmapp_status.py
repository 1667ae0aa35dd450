"""``SwarmApp``'s shared state and what it tells about itself: ``status`` (the fragment of
``swarmctl status --json``, docs/operations.md) and the role's queries. Split out of
``swarmapp.py`` by concern at 773 lines (style.md rule 19), as ``daemon_status.py`` declares
the daemon's: ``SwarmApp`` (``swarmd/swarmapp.py``) is this class with its life cycle and
discovery's input, and its other bases hold the rest: the PX4 link (``swarmapp_px4.py``),
the state file and the write-ahead (``swarmapp_saves.py``), the core's events
(``swarmapp_events.py``), the control socket's requests (``swarmapp_requests.py``).
"""

from __future__ import annotations

from typing import Any

from swarmd.bundle.model import Bundle, Participant
from swarmd.config import DaemonConfig
from swarmd.dataplane import DataPlane
from swarmd.driver import Driver
from swarmd.px4.bridge import Px4Bridge
from swarmd.statefile import NodeState
from swarmd.swarm.commander import CommandTracker, ReadinessTable
from swarmd.swarm.core import SwarmCore
from swarmd.swarm.events import SwarmEvent
from swarmd.swarm.roles import Roles
from swarmd.userdata import UserDataSocket

Datagram = tuple[bytes, tuple[str, int]]


class SwarmAppStatus:
    """The state every concern of ``SwarmApp`` reads, set in ``SwarmApp.__init__`` and
    ``SwarmApp.start``; each concern's own state is declared in its own class."""

    config: DaemonConfig
    bundle: Bundle
    log: Any
    me: Participant
    roles: Roles
    bridge: Px4Bridge | None
    state: NodeState | None
    plane: DataPlane | None
    socket: UserDataSocket | None
    core: SwarmCore | None
    driver: Driver[bytes, Datagram, SwarmEvent] | None
    counters: dict[str, int]

    @property
    def is_commander(self) -> bool:
        return self.roles.is_commander

    @property
    def reports_readiness(self) -> bool:
        return self.roles.reports_readiness

    @property
    def targets_remote(self) -> list[str]:
        return list(self.roles.targets_remote)

    @property
    def table(self) -> ReadinessTable:
        return self._core().table

    @property
    def tracker(self) -> CommandTracker:
        return self._core().tracker

    # ---- status ---------------------------------------------------------------------------

    def status(self) -> dict[str, Any]:
        """The fragment merged into ``swarmctl status --json`` (docs/operations.md): a pure
        function of the cores' state, evaluated when asked."""
        swarm, driver = self._core(), self._driver()
        now = driver.now()
        dataplane: dict[str, Any] = {"enabled": self.plane is not None}
        if self.plane is not None:
            dataplane.update(self.plane.status(now))
            sock = {} if self.socket is None else self.socket.counters
            dataplane["adapter"] = {
                "socket_errors": sock.get("socket_error_user", 0),
                "tx_dropped_full": sock.get("tx_dropped_full_user", 0),
                "handler_errors": driver.counters["handler_errors"],
                "tx_closed": self.counters.get("tx_closed", 0),
            }
            dataplane["readiness_published"] = swarm.counters["readiness_published"]
            # what this life re-reported of its earlier lives' outcomes (docs/dataplane.md)
            dataplane["outcomes_rereported"] = swarm.counters["outcomes_rereported"]
            dataplane["state_save_errors"] = self.counters["state_save_errors"]
            dataplane["state_file_missing"] = self.counters["state_file_missing"]
        px4: dict[str, Any] = {"enabled": self.bridge is not None}
        if self.bridge is not None:
            px4.update(self.bridge.status())
        return {
            "role": self.roles.role,
            "clock_s": round(now, 3),
            "readiness": swarm.table.rows(now),
            "px4": px4,
            "dataplane": dataplane,
            "commands": swarm.tracker.recent(now) if self.is_commander else [],
            "executor": swarm.executor_status(now),
        }

    def _core(self) -> SwarmCore:
        if self.core is None:
            raise RuntimeError("the swarm layer is not started")
        return self.core

    def _driver(self) -> Driver[bytes, Datagram, SwarmEvent]:
        if self.driver is None:
            raise RuntimeError("the swarm layer is not started")
        return self.driver
