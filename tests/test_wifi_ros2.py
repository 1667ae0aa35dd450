"""The ROS 2 contenders of the emulated 802.11 testbed (issue 19, bench/wifi/ros2_contenders.py).

The smoke run puts real rclpy nodes (stock SIMPLE, Discovery Server, generated static
profiles, swarmd's relay) on a 3-drone ns-3 channel under time dilation and asserts that each
discovered and delivered; never timings (the machine is shared). The rest checks, without a
channel, what the contenders are built from (the generated static route, the ros2-swarmd
route, a contender without a route) and what the
report computes from run files (first message of every member, the Fig. 8 ordering).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.netns import Namespace, delete_namespace, list_namespaces

from bench.wifi import contenders, ros2_contenders, run
from bench.wifi.ns3_loader import unavailable_reason
from bench.wifi.report_ros2 import fig8_lines, first_all_s, ros2_markdown
from bench.wifi.ros2_contenders import (
    ROUTES,
    Ros2Contender,
    static_route,
    stock_route,
    swarmd_route,
    unavailable,
)
from bench.wifi.topology import BASE
from swarmd.config import load_config

REPO = Path(__file__).resolve().parents[1]
ROS2_RUNNABLE = ("ros2", "ros2-ds", "ros2-static", "ros2-swarmd")


def _drones(n: int) -> list[Namespace]:
    # never entered: the routes only read names and addresses
    return [Namespace(f"nowhere-{i}", f"10.78.0.{i + 1}", 24) for i in range(n)]


def test_static_route_gives_every_drone_the_generated_unicast_static_profile(
    tmp_path: Path,
) -> None:
    c = Ros2Contender("ros2-static", _drones(3), tmp_path, window_s=5, messages=2)
    envs = static_route(c)
    assert len(envs) == 3
    for i, env in enumerate(envs):
        assert env["RMW_IMPLEMENTATION"] == "rmw_fastrtps_cpp"
        # rmw_fastrtps must leave the XML's peers alone (no multicast added)
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
        xml = Path(env["FASTDDS_DEFAULT_PROFILES_FILE"]).read_text()
        assert "<EDP>STATIC</EDP>" in xml
        assert "239.255" not in xml
        others = [f"10.78.0.{j + 1}" for j in range(3) if j != i]
        assert all(address in xml for address in others)  # every other drone a peer


def test_no_route_leaks_the_callers_ros2_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ROS_DISCOVERY_SERVER", "192.0.2.1:11811")
    monkeypatch.setenv("FASTDDS_DEFAULT_PROFILES_FILE", "/nonexistent.xml")
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert ROUTES["ros2"] is stock_route
    env = stock_route(Ros2Contender("ros2", _drones(2), tmp_path, window_s=5, messages=2))[1]
    assert "ROS_DISCOVERY_SERVER" not in env
    assert "FASTDDS_DEFAULT_PROFILES_FILE" not in env
    assert env["ROS_DOMAIN_ID"] == "0"


def test_a_contender_without_a_route_is_refused_before_any_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert "ros2-swarmd" in contenders.CONTENDERS
    monkeypatch.setitem(ROUTES, "ros2-swarmd", None)
    why = unavailable("ros2-swarmd")
    assert why is not None and "ROUTES" in why
    with pytest.raises(ValueError, match="no launch"):
        contenders.make(
            "ros2-swarmd", _drones(2), tmp_path, window_s=5, messages=2, link_dir=tmp_path
        )
    with pytest.raises(SystemExit) as exit_info:
        run.main(["--n", "3", "--contenders", "ros2-swarmd", "--out", str(tmp_path)])
    assert exit_info.value.code == 2
    assert not (tmp_path / "runs").exists()


def test_swarmd_route_runs_a_relaying_daemon_per_drone_and_via_swarmd_profiles(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert ROUTES["ros2-swarmd"] is swarmd_route
    c = Ros2Contender(
        "ros2-swarmd", _drones(3), tmp_path, window_s=5, messages=2, link_dir=tmp_path / "chan"
    )
    started: list[tuple[int, list[str]]] = []

    def start(
        i: int, argv: list[str], env: dict[str, str], name: str, *, host_id: int,
        append: bool = False,
    ) -> Any:  # fmt: skip
        started.append((i, argv))
        c.infrastructure.append(subprocess.Popen(["sleep", "30"]))  # a live "daemon"
        return c.infrastructure[-1]

    monkeypatch.setattr(c, "start_infrastructure", start)
    monkeypatch.setattr(ros2_contenders, "_discovered", lambda c, i: True)
    turned_on: list[str] = []
    monkeypatch.setattr(ros2_contenders, "sysctls", lambda ns, kv: turned_on.append(ns))
    try:
        envs = swarmd_route(c)
    finally:
        for p in c.infrastructure:
            p.kill()
            p.wait()
    assert [i for i, _ in started] == [0, 1, 2]
    assert turned_on == [f"nowhere-{i}" for i in range(3)]  # IPv6 back on every drone's lo
    for i, argv in started:
        config = load_config(argv[argv.index("--config") + 1])
        assert config.node == f"uav{i + 1}"
        assert config.ros2.relay  # the daemon serves its node's discovery
        # its link quality is the channel's, as the swarmd contender's (not a fixed 0.5)
        assert config.link.file == str(tmp_path / "chan" / f"link-{i}.json")
        assert "file" in config.link.sources
        # swarmd's data plane on, as on a drone: the commander vouches on its readiness
        assert config.dataplane.enabled
    for env in envs:
        xml = Path(env["FASTDDS_DEFAULT_PROFILES_FILE"]).read_text()
        peers = xml.split("<initialPeersList>")[1].split("</initialPeersList>")[0]
        # the node's one initial peer is its drone's relay on [::1]: no other drone's address
        assert peers.count("<locator>") == 1 and "<address>::1</address>" in peers


def test_swarmd_route_stops_when_a_daemon_exits(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    c = Ros2Contender("ros2-swarmd", _drones(2), tmp_path, window_s=5, messages=2)

    def start(
        i: int, argv: list[str], env: dict[str, str], name: str, *, host_id: int,
        append: bool = False,
    ) -> Any:  # fmt: skip
        c.infrastructure.append(subprocess.Popen(["true"]))
        c.infrastructure[-1].wait()
        return c.infrastructure[-1]

    monkeypatch.setattr(c, "start_infrastructure", start)
    monkeypatch.setattr(ros2_contenders, "sysctls", lambda ns, kv: None)
    with pytest.raises(RuntimeError, match="swarmd exited"):
        swarmd_route(c)


def _run(contender: str, frames: int, *, valid: bool = True, firsts: int = 2) -> dict[str, Any]:
    return {
        "contender": contender,
        "n": 3,
        "run": 4,
        "valid": valid,
        "peak_pps": frames,
        "discovery_frames_60s": frames,
        "discovery_breakdown_60s": {"data_frames": frames // 2, "acks": frames - frames // 2},
        "all_discovered_from_launch_s": 0.5,
        "success_rate": 1.0,
        "received": {
            str(m): {"count": 9, "first": 100.0 + m, "nth": None} for m in range(1, 1 + firsts)
        },
        "setup": {"dilation": 1.0, "commit": "abc", "started_at": 100.0},
    }


def test_first_message_of_every_member_is_the_last_members_first() -> None:
    assert first_all_s(_run("ros2", 10)) == 2.0
    assert first_all_s(_run("ros2", 10, firsts=1)) is None  # member 2 never heard


def test_fig8_ordering_is_judged_per_step_on_valid_runs_only() -> None:
    good = [_run("ros2", 900), _run("ros2-static", 400), _run("swarmd", 20)]
    assert "frames holds" in fig8_lines(good)
    swapped = [_run("ros2", 300), _run("ros2-static", 400), _run("swarmd", 20)]
    assert "frames does not hold" in fig8_lines(swapped)
    lagged = [_run("ros2", 900), _run("ros2-static", 400, valid=False), _run("swarmd", 20)]
    assert "not known (ros2-static invalid)" in fig8_lines(lagged)
    assert ros2_markdown([_run("swarmd", 20)]) == ""  # no ROS 2 run: no section


@pytest.mark.netns
@pytest.mark.interop
@pytest.mark.timeout(600)
def test_wifi_smoke_ros2_contenders_dilated(tmp_path: Path) -> None:
    """Each runnable ROS 2 contender discovers and delivers over the channel under k = 2."""
    reason = unavailable_reason()
    if reason is not None:
        pytest.skip(f"wifi testbed unavailable: {reason}")
    why = unavailable("ros2")
    if why is not None:
        pytest.skip(why)
    argv = ["--n", "3", "--contenders", ",".join(ROS2_RUNNABLE), "--window-s", "6"]
    argv += ["--messages", "2", "--max-lag-ms", "1000", "--dilation", "2", "--no-report"]
    proc = subprocess.Popen(
        [sys.executable, str(REPO / "bench" / "wifi" / "run.py"), *argv, "--out", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    try:
        _, stderr = proc.communicate(timeout=540)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    left = [name for name in list_namespaces() if name.startswith(f"{BASE}-{proc.pid}-")]
    for name in left:
        delete_namespace(name)
    assert proc.returncode == 0, stderr[-3000:]
    assert not left, f"the harness left namespaces behind: {left}"
    runs = {p.name: json.loads(p.read_text()) for p in (tmp_path / "runs").glob("*.json")}
    assert set(runs) == {f"{c}-n3-k2-r1.json" for c in ROS2_RUNNABLE}
    for r in runs.values():
        name = r["contender"]
        assert r["setup"]["dilation"] == 2.0
        if name != "ros2-swarmd":  # its nodes' discovery stays on lo; swarmd's own SPDP
            # runs at the bundle's period, which a 6 s window may hold none of
            assert r["discovery_frames_60s"] > 0, f"{name}: no discovery on the channel"
        assert r["all_discovered_s"] is not None, f"{name}: the listener matched no one"
        assert set(r["received"]) == {"1", "2"}, f"{name}: not every talker reached it"


def test_targets_are_judged_on_the_route_as_shipped_only() -> None:
    """A ros2-swarmd run of an earlier route configuration (another commit) is listed for the
    record but does not decide a verdict; other contenders' runs always count."""
    from bench.wifi import report_ros2

    def run(contender: str, commit: str, peak: int) -> dict[str, Any]:
        return {
            "contender": contender, "n": 20, "run": 1, "valid": True, "peak_pps": peak,
            "discovery_frames_60s": 30, "success_rate": 1.0,
            "setup": {"dilation": 6.0, "commit": commit},
        }  # fmt: skip

    shipped = report_ros2.ROUTE_COMMITS[0] + "+dirty"
    old = [run("ros2", "0ld", 10000), run("ros2-swarmd", "0ld", 6000)]
    new = [run("ros2", shipped, 10000), run("ros2-swarmd", shipped, 280)]
    text = report_ros2.target_lines(old + new)
    judged, record = text.split("Every `ros2-swarmd` run")
    assert "busiest second <= 5 % of stock ros2's in the same step: **met** (2.8 %" in judged
    assert "60.0 %" not in judged and "60.0 %" in record and "**" not in record
