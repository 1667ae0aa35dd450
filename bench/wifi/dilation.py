"""Time dilation for one testbed run (docs/testbed.md, "Time dilation").

After Gupta et al., *To Infinity and Beyond: Time-Warped Network Emulation* (NSDI 2006):
every process of a run, the ns-3 channel included, reads clocks that run ``k`` times slower
than real time and waits ``k`` times longer (``dilate.c``, LD_PRELOAD). One experiment
second then has ``k`` real seconds of CPU behind it, so on two shared cores ns-3 keeps up
with bursts it cannot follow in real time. All processes share the harness's anchors, so
they agree on one experiment clock; the harness itself is not dilated and maps its own
readings with the same formula (``exp``).

The kernel's timers are not dilated; the neighbour (ARP) timers are scaled per namespace
(``scale_kernel_timers``), TCP's minimum RTO on the subnet route. Delayed ACKs (40 ms) and
IGMP timers stay real: a stated limit.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

from swarmd_lab.netns import Namespace

from bench.wifi.native import dilate_library

# neighbour-cache timers (ms) of eth0 scaled by k: defaults of Linux 6.x
NEIGH_TIMERS_MS: Final = (
    ("base_reachable_time_ms", 30_000),
    ("retrans_time_ms", 1_000),
    ("delay_first_probe_time", 5),  # seconds
    ("gc_stale_time", 60),  # seconds
)
TCP_RTO_MIN_MS: Final = 200


@dataclass(frozen=True)
class Dilation:
    """One run's experiment clock: ``k`` and the real anchors (ns) it is slowed around."""

    k: float
    anchor_real_ns: int
    anchor_mono_ns: int

    @classmethod
    def start(cls, k: float) -> Dilation:
        if not k >= 1.0:
            raise ValueError(f"dilation factor must be >= 1, got {k}")
        return cls(k, time.time_ns(), time.monotonic_ns())

    @property
    def active(self) -> bool:
        return self.k > 1.0

    def exp(self, real_wall: float) -> float:
        """Experiment wall time (what dilated processes read) of a real ``time.time()``."""
        a = self.anchor_real_ns / 1e9
        return a + (real_wall - a) / self.k

    def now(self) -> float:
        return self.exp(time.time())

    def real_s(self, exp_s: float) -> float:
        """Real seconds an interval of ``exp_s`` experiment seconds takes."""
        return exp_s * self.k

    def env(self) -> dict[str, str]:
        """Environment for a dilated process (empty when k is 1: nothing preloaded)."""
        if not self.active:
            return {}
        return {
            "LD_PRELOAD": str(dilate_library()),
            "BENCH_DILATION": f"{self.k!r} {self.anchor_real_ns} {self.anchor_mono_ns}",
        }

    def describe(self) -> str:
        return f"k={self.k:g}" if self.active else "none"


def scale_kernel_timers(drones: Sequence[Namespace], k: float, subnet: str) -> None:
    """Stretch each drone's neighbour timers and TCP's minimum RTO by ``k``."""
    if k <= 1.0:
        return
    for d in drones:
        lines = [
            f"sysctl -qw net.ipv4.neigh.eth0.{key}={round(value * k)}"
            for key, value in NEIGH_TIMERS_MS
        ]
        lines.append(
            f"ip route replace {subnet} dev eth0 proto kernel scope link src {d.address} "
            f"rto_min {round(TCP_RTO_MIN_MS * k)}ms"
        )
        proc = subprocess.run(
            ["ip", "netns", "exec", d.name, "sh", "-ec", "; ".join(lines)],
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            raise RuntimeError(f"dilating kernel timers in {d.name}: {proc.stderr.strip()}")
