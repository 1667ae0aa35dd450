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
from bench.wifi.native import BuildError, dilate_library, fastdds_discovery_server, fastdds_peer
from bench.wifi.ns3_loader import unavailable_reason
from bench.wifi.report import main_rows, paired_ratios, summarise, table, validation_table
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


def _harness(tmp_path: Path, argv: list[str], timeout: float) -> subprocess.Popen[str]:
    """Run bench/wifi/run.py to the end; assert it left none of its namespaces behind."""
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "bench" / "wifi" / "run.py"), *argv, "--out", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        _, stderr = proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    own = f"{BASE}-{proc.pid}-"
    left = [name for name in list_namespaces() if name.startswith(own)]
    for name in left:
        delete_namespace(name)
    assert proc.returncode == 0, stderr[-3000:]
    assert not left, f"the harness left namespaces behind: {left}"
    return proc


@pytest.mark.netns
@pytest.mark.interop
@pytest.mark.timeout(600)
def test_wifi_smoke_swarmd_and_cyclone(tmp_path: Path) -> None:
    reason = unavailable_reason()
    if reason is not None:
        pytest.skip(f"wifi testbed unavailable: {reason}")
    argv = ["--n", "3", "--contenders", "swarmd,cyclonedds", "--window-s", "20"]
    argv += ["--messages", "5", "--max-lag-ms", "1000"]
    _harness(tmp_path, argv, timeout=540)
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
    assert text.count("| swarmd | 3 | 1 | 1/1 |") == 1  # the summary row (k = 1)
    assert text.count("| swarmd | 3 | 1 | 1 |") == 1  # the discovery breakdown row


@pytest.mark.netns
@pytest.mark.interop
@pytest.mark.timeout(400)
def test_wifi_smoke_fastdds_contenders_dilated(tmp_path: Path) -> None:
    """Both Fast DDS contenders discover and deliver over the channel, under dilation k=2.

    A few experiment seconds at N=3: the contenders and the dilated harness work end to
    end; the measurements themselves are the campaign's (docs/benchmarks.md).
    """
    reason = unavailable_reason()
    if reason is not None:
        pytest.skip(f"wifi testbed unavailable: {reason}")
    try:
        fastdds_peer()
        dilate_library()
    except BuildError as exc:
        pytest.skip(f"native pieces unavailable: {exc}")
    if fastdds_discovery_server() is None:
        pytest.skip("fastdds CLI (fastdds-tools) missing")
    argv = ["--n", "3", "--contenders", "fastdds,fastdds-server", "--window-s", "6"]
    argv += ["--messages", "2", "--max-lag-ms", "1000", "--dilation", "2", "--no-report"]
    _harness(tmp_path, argv, timeout=360)
    runs = {p.name: json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*.json")}
    assert set(runs) == {"fastdds-n3-k2-r1.json", "fastdds-server-n3-k2-r1.json"}
    for r in runs.values():
        missing = [f for f in FIELDS if f not in r]
        assert not missing, f"{r['contender']}: missing {missing}"
        assert r["setup"]["dilation"] == 2.0
        assert len(r["pps"]) == 6  # experiment seconds, not real ones
        assert r["discovery_frames_60s"] > 0, f"{r['contender']}: no discovery on the channel"
        assert r["all_discovered_s"] is not None, f"{r['contender']}: commander matched no one"
        assert r["received"], f"{r['contender']}: no sample reached the commander"


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
    assert cyclone["peak_pps_median"] == 1000.0  # the lagging run's 9 is not in it
    assert "| 10 | 1 | 5.0 % | 5.0 % |" in table(rows)


def test_report_keeps_dilated_and_real_time_runs_apart() -> None:
    dilated = {"setup": {"dilation": 3.0}}
    runs = [
        {**_run("swarmd", 50), **dilated},
        {**_run("cyclonedds", 1000), **dilated},
        _run("cyclonedds", 700),
    ]
    rows = summarise(runs)
    assert sorted((r["contender"], r["k"]) for r in rows) == [
        ("cyclonedds", 1.0),
        ("cyclonedds", 3.0),
        ("swarmd", 3.0),
    ]
    # the main table is the campaign's k at each N; k = 1 beside it is the validation
    assert [(r["contender"], r["k"]) for r in main_rows(rows)] == [
        ("swarmd", 3.0),
        ("cyclonedds", 3.0),
    ]
    assert "| cyclonedds | 10 | 1 | 1/1 | 700 (700-700)" in validation_table(rows)
    assert paired_ratios(runs, "cyclonedds", "peak_pps") == {(10, 3.0): [0.05]}


def test_paired_ratios_only_pair_valid_runs_of_the_same_repeat() -> None:
    runs = [
        {**_run("swarmd", 50), "run": 1},
        {**_run("cyclonedds", 1000), "run": 1},
        {**_run("swarmd", 40), "run": 2},
        {**_run("cyclonedds", 10, valid=False), "run": 2},
        {**_run("swarmd", 30), "run": 3},
        {**_run("cyclonedds", 600), "run": 3},
    ]
    assert paired_ratios(runs, "cyclonedds", "peak_pps") == {(10, 1.0): [0.05, 0.05]}
    assert paired_ratios(runs, "zenoh", "peak_pps") == {}
