"""A CPU cap for a test's daemons: each in its own cgroup, at most a fraction of one core.

Why: a drone's CPU is shared (the PX4 bridge, ROS nodes) and slower (a Jetson Nano's
Cortex-A57 is ~3-5x slower than the CI box), and the flood test once lost a real peer on a
machine at load 9-12 and passed alone. A CFS quota makes "a daemon with little CPU"
reproducible whatever else the machine runs: the daemon gets at most ``percent`` % of one
core, on a quiet machine exactly that.

cgroup v1 (``/sys/fs/cgroup/cpu``, ``cpu.cfs_quota_us``) or v2 (``cpu.max``, the cpu
controller enabled at the root). ``unavailable_reason()`` says why neither can be used
(the test then skips, naming it). Groups are removed on ``close``.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Final

V1: Final = Path("/sys/fs/cgroup/cpu")
V2: Final = Path("/sys/fs/cgroup")
PERIOD_US: Final = 100_000


def _root() -> tuple[Path, int] | None:
    """(the cgroup folder to create groups under, its version), or None."""
    if (V1 / "cpu.cfs_quota_us").exists() or (V1 / "tasks").exists():
        if os.access(V1, os.W_OK):
            return V1, 1
    controllers = V2 / "cgroup.controllers"
    if controllers.exists() and "cpu" in controllers.read_text().split():
        if os.access(V2, os.W_OK):
            return V2, 2
    return None


def unavailable_reason() -> str | None:
    if _root() is None:
        return "no writable cgroup cpu controller (v1 /sys/fs/cgroup/cpu or v2 cpu.max)"
    return None


class CpuLimit:
    """One cgroup per process added, each capped at ``percent`` % of one core."""

    def __init__(self, name: str, percent: float) -> None:
        root = _root()
        if root is None:
            raise RuntimeError(unavailable_reason())
        if not 0 < percent <= 100:
            raise ValueError("percent in (0, 100]")
        self.root, self.version = root
        self.name = name
        self.percent = percent
        self.groups: list[Path] = []

    def add(self, pid: int) -> Path:
        group = self.root / f"{self.name}-{len(self.groups)}"
        group.mkdir(exist_ok=True)
        self.groups.append(group)
        quota = max(1000, int(PERIOD_US * self.percent / 100))
        if self.version == 1:
            (group / "cpu.cfs_period_us").write_text(str(PERIOD_US))
            (group / "cpu.cfs_quota_us").write_text(str(quota))
        else:
            (group / "cpu.max").write_text(f"{quota} {PERIOD_US}")
        (group / "cgroup.procs").write_text(str(pid))
        return group

    def throttled_s(self) -> dict[str, float]:
        """Per group: seconds its processes wanted the CPU and were held back by the quota."""
        out: dict[str, float] = {}
        for group in self.groups:
            stat = dict(
                line.split() for line in (group / "cpu.stat").read_text().splitlines() if line
            )
            if "throttled_time" in stat:  # v1: ns
                out[group.name] = int(stat["throttled_time"]) / 1e9
            elif "throttled_usec" in stat:  # v2: us
                out[group.name] = int(stat["throttled_usec"]) / 1e6
        return out

    def close(self) -> None:
        """Move the processes back to the root group and remove the groups."""
        for group in self.groups:
            with contextlib.suppress(OSError):
                for pid in (group / "cgroup.procs").read_text().split():
                    with contextlib.suppress(OSError):
                        (self.root / "cgroup.procs").write_text(pid)
            with contextlib.suppress(OSError):
                group.rmdir()
        self.groups.clear()

    def __enter__(self) -> CpuLimit:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
