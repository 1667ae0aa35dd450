"""The paper's measures from one run's ns-3 stats and the commander's tallies. Pure.

Definitions (paper section 5.1, Tables 2-5; docs/testbed.md):

- frames = PHY transmissions (``PhyTxBegin``) including ACKs; an ACK counts in the class
  of the data frame it acknowledges.
- ``peak_pps``: the busiest second of all frames on the channel within the window;
  ``peak_discovery_pps`` the same for the contender's discovery class only.
- ``discovery_frames_60s``: discovery-class frames in the first 60 s after launch (RTPS:
  SPDP + SEDP on the metatraffic ports; zenoh: scouting and its TCP sessions, which carry
  declarations and data alike, so it is an upper bound for zenoh).
- ``mac_drop_ratio`` = N_drop^MAC / N_tx^MAC (eq. 5), ``phy_drop_density`` =
  N_drop^PHY / N_tx^PHY (eq. 4, may exceed 1), ``retx_ratio`` = N_retx^PHY / N_tx^PHY
  (eq. 6), as fractions; N_drop^MAC = MacTxDrop + DroppedMpdu (queue overflow, retry limit,
  lifetime), N_drop^PHY = PhyRxDrop + PhyTxDrop, N_rx^PHY = PhyRxEnd.
- ``success_rate``: the fraction of members whose ``messages``-th sample reached the
  commander within the window; ``success``: all of them did.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, Final

DISCOVERY_CLASSES: Final[Mapping[str, tuple[str, ...]]] = {
    "rtps": ("rtps_discovery",),
    "zenoh": ("zenoh",),
}


def percentile(values: Sequence[float], q: float) -> float:
    """The q-th percentile (0..100), nearest-rank; NaN for no values."""
    if not values:
        return math.nan
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100.0 * len(ordered)))
    return float(ordered[min(rank, len(ordered)) - 1])


def frame_series(
    stats: Mapping[str, Any], start_s: int, window_s: int, classes: Sequence[str] | None
) -> list[int]:
    """Frames per second for ``window_s`` seconds from sim second ``start_s``.

    ``classes`` None: every frame; else data frames of those classes plus their ACKs.
    """
    names: list[str] = list(stats["classes"])
    per_second: list[list[int]] = stats["per_second"]
    acks: list[list[int]] = stats["acks_per_second_by_class"]
    out = []
    for s in range(start_s, start_s + window_s):
        if not 0 <= s < len(per_second):
            out.append(0)
            continue
        if classes is None:
            out.append(sum(per_second[s]))
        else:
            idx = [names.index(c) for c in classes]
            out.append(sum(per_second[s][i] + acks[s][i] for i in idx))
    return out


def class_series(stats: Mapping[str, Any], start_s: int, window_s: int) -> dict[str, list[int]]:
    """Per class (ACKs folded into the class they acknowledge) frames per second."""
    names = [c for c in stats["classes"] if c != "ack"]
    return {c: frame_series(stats, start_s, window_s, (c,)) for c in names}


def layer_counters(stats: Mapping[str, Any]) -> dict[str, int]:
    """The paper's Table 2 counters summed over all nodes."""
    nodes: list[dict[str, Any]] = stats["nodes"]

    def total(*keys: str) -> int:
        return sum(int(n[k]) for n in nodes for k in keys)

    return {
        "n_tx_mac": total("mac_tx"),
        "n_drop_mac": total("mac_tx_drop", "mac_dropped_mpdu"),
        "n_tx_phy": total("phy_tx"),
        "n_retx_phy": total("phy_retx"),
        "n_rx_phy": total("phy_rx_end"),
        "n_drop_phy": total("phy_rx_drop", "phy_tx_drop"),
    }


def _ratio(num: int, den: int) -> float | None:
    return None if den == 0 else num / den


def lag_stats(stats: Mapping[str, Any], start_s: float) -> dict[str, float]:
    """Real-time lag (ns-3 behind the wall clock) from ``start_s`` on, in ms."""
    tick = float(stats["lag_tick_s"])
    samples = [float(x) for x in stats["lag_ms"][max(0, int(start_s / tick)) :]]
    return {
        "rt_lag_p50_ms": percentile(samples, 50),
        "rt_lag_p99_ms": percentile(samples, 99),
        "rt_lag_max_ms": max(samples) if samples else math.nan,
    }


def lag_validity(lag: Mapping[str, float], max_lag_ms: float) -> dict[str, Any]:
    """A run's ``valid`` and ``invalid_reason`` from its ``lag_stats``: valid unless the
    real-time lag p99 exceeds ``max_lag_ms`` (NaN, no samples: not judged, so valid)."""
    p99 = lag["rt_lag_p99_ms"]
    ok = not (p99 > max_lag_ms)
    reason = None if ok else f"real-time lag p99 {p99:.1f} ms > {max_lag_ms} ms"
    return {"valid": ok, "invalid_reason": reason}


def success(
    received: Mapping[str, Mapping[str, Any]],
    members: Sequence[int],
    launch_wall: float,
    window_s: float,
) -> tuple[float, list[int]]:
    """(fraction of members whose n-th message arrived in the window, members that failed)."""
    failed = []
    for m in members:
        entry = received.get(str(m))
        nth = entry.get("nth") if entry else None
        if not isinstance(nth, int | float) or nth - launch_wall > window_s:
            failed.append(m)
    if not members:
        return 1.0, []
    return (len(members) - len(failed)) / len(members), failed


def discovery_breakdown(
    stats: Mapping[str, Any], *, launch_wall: float, window_s: int, family: str
) -> dict[str, int]:
    """The discovery class's frames in the first 60 s split into data frames (first
    transmissions and retries alike) and the ACKs answering the unicast ones."""
    start_s = max(0, int(launch_wall - float(stats["wall_at_sim0"])))
    names: list[str] = list(stats["classes"])
    idx = [names.index(c) for c in DISCOVERY_CLASSES[family]]
    end = min(start_s + min(window_s, 60), len(stats["per_second"]))
    data = sum(stats["per_second"][s][i] for s in range(start_s, end) for i in idx)
    acks = sum(stats["acks_per_second_by_class"][s][i] for s in range(start_s, end) for i in idx)
    return {"data_frames": int(data), "acks": int(acks)}


def run_measures(
    stats: Mapping[str, Any],
    *,
    launch_wall: float,
    window_s: int,
    family: str,
) -> dict[str, Any]:
    """Channel measures of one run (everything but discovery time and success)."""
    start_s = max(0, int(launch_wall - float(stats["wall_at_sim0"])))
    total = frame_series(stats, start_s, window_s, None)
    disc = frame_series(stats, start_s, window_s, DISCOVERY_CLASSES[family])
    c = layer_counters(stats)
    return {
        "window_start_sim_s": start_s,
        "peak_pps": max(total) if total else 0,
        "peak_discovery_pps": max(disc) if disc else 0,
        "discovery_frames_60s": sum(disc[:60]),
        "frames_60s": sum(total[:60]),
        "pps": total,
        "discovery_pps": disc,
        "class_pps": class_series(stats, start_s, window_s),
        "counters": c,
        "mac_drop_ratio": _ratio(c["n_drop_mac"], c["n_tx_mac"]),
        "phy_drop_density": _ratio(c["n_drop_phy"], c["n_tx_phy"]),
        "retx_ratio": _ratio(c["n_retx_phy"], c["n_tx_phy"]),
        "lag_max_ms_per_second": [
            round(float(x), 1) for x in stats["lag_max_ms_per_second"][start_s : start_s + window_s]
        ],
        **lag_stats(stats, float(start_s)),
    }
