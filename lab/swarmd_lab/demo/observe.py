"""What the demo knows about its drones: live status polls and, afterwards, their logs.

The live view polls every daemon's control socket (``status``), as ``swarmctl status`` does.
The summary uses the daemons' own log lines instead (the first line, ``peer_discovered``,
``phase_changed``, ``px4_readiness``, ``command_sent``, ``command_outcome``): their
timestamps are taken where things happened, not when a poll noticed them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from swarmd.control import DaemonUnreachable, RequestError, request

POLL_TIMEOUT_S = 1.0


@dataclass(slots=True)
class NodeView:
    """One drone as its last status poll showed it."""

    name: str
    up: bool = False
    phase: str = "-"
    discovered: int = 0
    total: int = 0
    q: float | None = None
    px4_ready: bool = False
    px4_reason: str = "-"
    landed: str = "-"
    frames_sent: int = 0
    userdata_sent: int = 0


@dataclass(slots=True)
class Observer:
    """Polls the daemons and remembers when each drone first reached each milestone."""

    names: list[str]
    sockets: list[Path]
    t0: float  # demo start, on the caller's clock
    views: dict[str, NodeView] = field(default_factory=dict)
    discovered_at: dict[str, float] = field(default_factory=dict)
    ready_at: dict[str, float] = field(default_factory=dict)
    in_air_at: dict[str, float] = field(default_factory=dict)
    table: dict[str, dict[str, Any]] = field(default_factory=dict)
    commands: list[dict[str, Any]] = field(default_factory=list)

    def poll(self, now: float) -> None:
        for name, sock in zip(self.names, self.sockets, strict=True):
            view = self.views.setdefault(name, NodeView(name))
            try:
                st = request(str(sock), "status", timeout=POLL_TIMEOUT_S)
            except (DaemonUnreachable, RequestError, OSError):
                view.up = False
                continue
            self._update(view, st, now)
            if name == self.names[0]:
                self.table = dict(st.get("readiness") or {})
                self.commands = list(st.get("commands") or [])

    def _update(self, view: NodeView, st: dict[str, Any], now: float) -> None:
        t = round(now - self.t0, 2)
        view.up = True
        view.phase = str(st.get("phase", "-"))
        view.discovered = int(st.get("peers_discovered") or 0)
        view.total = int(st.get("peers_total") or 0)
        view.q = (st.get("link") or {}).get("q")
        counters = st.get("counters") or {}
        view.frames_sent = int(counters.get("tx_datagrams") or 0)
        dp = st.get("dataplane") or {}
        view.userdata_sent = int((dp.get("counters") or {}).get("tx_datagrams") or 0)
        verdict = (st.get("px4") or {}).get("readiness") or {}
        view.px4_ready = bool(verdict.get("ready"))
        view.px4_reason = "ready" if view.px4_ready else str(verdict.get("reason") or "-")
        view.landed = str(verdict.get("landed_state") or "-")
        if view.total and view.discovered == view.total:
            self.discovered_at.setdefault(view.name, t)
        if view.px4_ready:
            self.ready_at.setdefault(view.name, t)
        if view.landed == "IN_AIR":
            self.in_air_at.setdefault(view.name, t)


# -- the daemons' logs ----------------------------------------------------------------------


def read_log(path: Path) -> list[dict[str, Any]]:
    """The JSON lines of a daemon or simulator log (journald's ``<N>`` prefix tolerated)."""
    out = []
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except FileNotFoundError:
        return []
    for line in lines:
        text = line[3:] if line[:1] == "<" and line[2:3] == ">" else line
        if not text.startswith("{"):
            continue
        try:
            event = json.loads(text)
        except ValueError:
            continue
        if isinstance(event, dict):
            out.append(event)
    return out


def epoch(event: dict[str, Any]) -> float | None:
    """The event's timestamp (structlog ISO 8601, UTC) as seconds since the epoch."""
    stamp = event.get("timestamp")
    if not isinstance(stamp, str):
        return None
    try:
        return datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return None


@dataclass(slots=True)
class NodeLog:
    """Milestones of one drone from its daemon's log, in seconds since the demo started."""

    started: float | None = None  # its first log line
    discovered_all: float | None = None  # when the last bundle peer was discovered
    phases: list[tuple[float, str]] = field(default_factory=list)
    ready: list[tuple[float, bool]] = field(default_factory=list)
    command_sent: list[float] = field(default_factory=list)
    completed: float | None = None


def milestones(events: list[dict[str, Any]], peers: int, t0_epoch: float) -> NodeLog:
    log = NodeLog()
    seen: set[str] = set()
    for e in events:
        t = epoch(e)
        if t is None:
            continue
        t -= t0_epoch
        if log.started is None:
            # the daemon's first line comes right after its engine and sockets exist (the
            # "started" line waits for the PX4 link and the control socket, so is later)
            log.started = t
            log.phases.append((t, "boot"))
        match e.get("event"):
            case "peer_discovered":
                seen.add(str(e.get("peer")))
                if len(seen) >= peers and log.discovered_all is None:
                    log.discovered_all = t
            case "phase_changed":
                log.phases.append((t, str(e.get("new"))))
            case "px4_readiness":
                log.ready.append((t, bool(e.get("ready"))))
            case "command_sent":
                log.command_sent.append(t)
            case "command_outcome" if e.get("result") == "COMPLETED" and log.completed is None:
                log.completed = t
            case _:
                pass
    return log
