"""The live terminal view: a refreshing table on a terminal, plain progress lines otherwise.

On a TTY the screen is redrawn in place (cursor home, clear) with one row per drone; in a
pipe or CI log each change of the swarm's state is one line, so the log reads as a story:
discovery progress, readiness, the take-off's own progress lines, drones reaching IN_AIR.
"""

from __future__ import annotations

from collections import deque
from typing import Final, TextIO

from swarmd.cli.status_cmd import table
from swarmd_lab.demo.observe import Observer

HOME_CLEAR: Final = "\x1b[H\x1b[2J"
EVENT_LINES: Final = 6  # the latest progress lines kept under the table


class LiveView:
    def __init__(self, out: TextIO, *, tty: bool, title: str) -> None:
        self.out = out
        self.tty = tty
        self.title = title
        self.stage = "starting"
        self._events: deque[str] = deque(maxlen=EVENT_LINES)
        self._last_summary = ""

    def event(self, t: float, line: str) -> None:
        """A progress line (a stage change, a line of ``swarmctl takeoff``)."""
        text = f"[{t:6.1f} s] {line}"
        if self.tty:
            self._events.append(text)
        else:
            print(text, file=self.out, flush=True)

    def set_stage(self, t: float, stage: str) -> None:
        if stage != self.stage:
            self.stage = stage
            self.event(t, f"== {stage}")

    def refresh(self, t: float, obs: Observer) -> None:
        summary = self.summary(obs)
        if self.tty:
            self.out.write(HOME_CLEAR + "\n".join(self.screen(t, obs, summary)) + "\n")
            self.out.flush()
        elif summary != self._last_summary:
            self.event(t, summary)
        self._last_summary = summary

    def summary(self, obs: Observer) -> str:
        n = len(obs.names)
        up = sum(1 for v in obs.views.values() if v.up)
        found = len(obs.discovered_at)
        ready = sum(1 for v in obs.views.values() if v.px4_ready)
        waiting = [
            f"{v.name} ({v.px4_reason})"
            for v in obs.views.values()
            if v.up and not v.px4_ready and v.landed in ("ON_GROUND", "-")
        ]
        # drones that have reported IN_AIR, like "discovered all peers" counts those that got
        # there: the per-drone table shows the landed state of the moment, which may pass
        # through TAKEOFF again while the climb ends
        in_air = sum(1 for name in obs.names if name in obs.in_air_at)
        text = (
            f"daemons up {up}/{n} | discovered all peers {found}/{n} | "
            f"ready {ready}/{n} | IN_AIR {in_air}/{n}"
        )
        if waiting and len(waiting) <= 3 and not in_air:
            text += f" | not ready: {', '.join(waiting)}"
        return text

    def screen(self, t: float, obs: Observer, summary: str) -> list[str]:
        rows = []
        for name in obs.names:
            v = obs.views.get(name)
            if v is None or not v.up:
                rows.append([name, "down", "-", "-", "-", "-", "-"])
                continue
            rows.append(
                [
                    name,
                    v.phase,
                    f"{v.discovered}/{v.total}",
                    "-" if v.q is None else f"{v.q:.2f}",
                    str(obs.table.get(name, {}).get("count", "-")),
                    v.px4_reason,
                    v.landed,
                ]
            )
        lines = [f"{self.title}   t = {t:5.1f} s   {self.stage}", ""]
        lines += table(["DRONE", "PHASE", "PEERS", "Q", "REPORTS", "PX4", "LANDED"], rows)
        lines += ["", summary, "", *self._events]
        return lines
