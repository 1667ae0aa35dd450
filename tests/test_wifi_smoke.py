"""Smoke run of the emulated 802.11 testbed (bench/wifi): N=3, swarmd against Cyclone DDS.

Real processes in network namespaces on a real-time ns-3 802.11g channel. Asserts that
the harness ran and produced complete per-run JSON, that everything it created is gone,
and that swarmd discovered every pair; never on timings (the machine is shared).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from swarmd_lab.netns import delete_namespace, list_namespaces

from bench.wifi.metrics import frame_series, layer_counters, percentile, success
from bench.wifi.ns3_loader import unavailable_reason
from bench.wifi.report import paired_ratios, summarise, table
from bench.wifi.topology import BASE, ns3_mac

REPO = Path(__file__).resolve().parents[1]
FIELDS = (
    "contender",
    "n",
    "run",
    "peak_pps",
    "discovery_frames_60s",
    "success_rate",
    "all_discovered_s",
    "mac_drop_ratio",
    "phy_drop_density",
    "rt_lag_p99_ms",
    "valid",
    "pps",
    "counters",
)


def test_ns3_mac_matches_ns3_allocation_order() -> None:
    assert ns3_mac(0) == "00:00:00:00:00:01"
    assert ns3_mac(255) == "00:00:00:00:01:00"


def _stats() -> dict[str, object]:
    return {
        "classes": ["rtps_discovery", "rtps_user", "zenoh", "other", "ack"],
        "per_second": [[5, 0, 0, 1, 2], [1, 3, 0, 0, 1]],
        "acks_per_second_by_class": [[2, 0, 0, 0, 0], [0, 1, 0, 0, 0]],
        "lag_max_ms_per_second": [0.5, 1.0],
        "nodes": [
            {
                "mac_tx": 10,
                "mac_tx_drop": 1,
                "mac_dropped_mpdu": 2,
                "phy_tx": 20,
                "phy_retx": 4,
                "phy_rx_end": 30,
                "phy_rx_drop": 5,
                "phy_tx_drop": 0,
            }
        ],
    }


def test_frame_series_folds_acks_into_the_acked_class() -> None:
    stats = _stats()
    assert frame_series(stats, 0, 3, None) == [8, 5, 0]
    assert frame_series(stats, 0, 2, ("rtps_discovery",)) == [7, 1]
    assert frame_series(stats, 1, 1, ("rtps_user",)) == [4]


def test_layer_counters_follow_table_2() -> None:
    assert layer_counters(_stats()) == {
        "n_tx_mac": 10,
        "n_drop_mac": 3,
        "n_tx_phy": 20,
        "n_retx_phy": 4,
        "n_rx_phy": 30,
        "n_drop_phy": 5,
    }


def test_success_needs_the_nth_message_inside_the_window() -> None:
    received: dict[str, dict[str, float | None]] = {
        "1": {"nth": 110.0},
        "2": {"nth": 200.0},
        "3": {"nth": None},
    }
    rate, failed = success(received, [1, 2, 3, 4], launch_wall=100.0, window_s=60)
    assert rate == 0.25
    assert failed == [2, 3, 4]


def test_percentile_nearest_rank() -> None:
    assert percentile([3.0, 1.0, 2.0], 50) == 2.0
    assert percentile(list(map(float, range(1, 101))), 99) == 99.0
    assert math.isnan(percentile([], 99))


@pytest.mark.netns
@pytest.mark.interop
@pytest.mark.timeout(600)
def test_wifi_smoke_swarmd_and_cyclone(tmp_path: Path) -> None:
    reason = unavailable_reason()
    if reason is not None:
        pytest.skip(f"wifi testbed unavailable: {reason}")
    proc = subprocess.Popen(
        [
            sys.executable,
            str(REPO / "bench" / "wifi" / "run.py"),
            "--n",
            "3",
            "--contenders",
            "swarmd,cyclonedds",
            "--window-s",
            "20",
            "--messages",
            "5",
            "--max-lag-ms",
            "1000",
            "--out",
            str(tmp_path),
        ],  # fmt: skip
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        _, stderr = proc.communicate(timeout=540)
    finally:
        if proc.poll() is None:
            proc.kill()  # SIGKILL: its namespaces are swept below by the harness's prefix
            proc.communicate()
    # only the harness's own namespaces (swf-<its pid>-...): other tests' come and go
    own = f"{BASE}-{proc.pid}-"
    left = [name for name in list_namespaces() if name.startswith(own)]
    for name in left:
        delete_namespace(name)
    assert proc.returncode == 0, stderr[-3000:]
    assert not left, f"the harness left namespaces behind: {left}"
    runs = {p.name: json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*.json")}
    assert set(runs) == {"swarmd-n3-r1.json", "cyclonedds-n3-r1.json"}
    for r in runs.values():
        missing = [f for f in FIELDS if f not in r]
        assert not missing, f"{r['contender']}: missing {missing}"
        assert r["n"] == 3
        assert len(r["pps"]) == 20
        assert r["counters"]["n_tx_phy"] > 0, "no frame crossed the emulated channel"
    swarmd = runs["swarmd-n3-r1.json"]
    assert swarmd["all_discovered_s"] is not None, "swarmd did not discover every pair"
    assert swarmd["discovery_frames_60s"] > 0
    # the fair start: both stacks waited at the barrier and were counted from the release
    assert all(r["barrier_wait_s"] >= 0 for r in runs.values())
    assert swarmd["tx_counters"].get("daemons_counted") == 3
    cyclone = runs["cyclonedds-n3-r1.json"]
    assert cyclone["success_rate"] is not None
    assert (tmp_path / "summary.json").exists()
    text = (tmp_path / "table.md").read_text()
    assert text.count("| swarmd | 3 | 1/1 |") == 1  # the summary row
    assert text.count("| swarmd | 3 | 1 |") == 1  # the discovery breakdown row


def _run(contender: str, peak: int, *, valid: bool = True) -> dict[str, object]:
    return {
        "contender": contender,
        "n": 10,
        "run": 1,
        "valid": valid,
        "peak_pps": peak,
        "peak_discovery_pps": peak,
        "discovery_frames_60s": peak * 2,
        "success": True,
        "success_rate": 1.0,
        "all_discovered_s": 0.5,
        "mac_drop_ratio": 0.0,
        "phy_drop_density": 0.1,
        "retx_ratio": 0.2,
        "rt_lag_p99_ms": 1.0,
        "note": "",
    }


def test_report_leaves_invalid_runs_out_and_gives_ratios() -> None:
    rows = summarise(
        [_run("swarmd", 50), _run("cyclonedds", 1000), _run("cyclonedds", 9, valid=False)]
    )
    cyclone = next(r for r in rows if r["contender"] == "cyclonedds")
    assert (cyclone["runs"], cyclone["valid_runs"], cyclone["peak_pps_mean"]) == (2, 1, 1000.0)
    assert "| 10 | 5.0 % | - | 5.0 % | - |" in table(rows)


def test_paired_ratios_only_pair_valid_runs_of_the_same_repeat() -> None:
    runs = [
        {**_run("swarmd", 50), "run": 1},
        {**_run("cyclonedds", 1000), "run": 1},
        {**_run("swarmd", 40), "run": 2},
        {**_run("cyclonedds", 10, valid=False), "run": 2},
        {**_run("swarmd", 30), "run": 3},
        {**_run("cyclonedds", 600), "run": 3},
    ]
    assert paired_ratios(runs, "cyclonedds", "peak_pps") == {10: [0.05, 0.05]}
    assert paired_ratios(runs, "zenoh", "peak_pps") == {}
