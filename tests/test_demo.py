"""``make demo`` end to end with three drones: in namespaces (root) and on the loopback.

The demo runs as a process, as ``make demo`` runs it, and must leave nothing behind: no
namespace of its run, no process, no per-run directory. Its outputs are checked for content,
not for speed.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from swarmd_lab.netns import list_namespaces

from tests.xrce_peers import peer_binary, peer_env

N = 3
FIELDS = ("discovered_all_s", "frames_sent", "ready", "airborne", "command_latency_s")


def _run_demo(
    out: Path, *extra: str, env: dict[str, str] | None = None
) -> tuple[subprocess.CompletedProcess[str], int]:
    """The finished demo and its pid (its namespaces are named ``swn-<pid>-...``)."""
    argv = [sys.executable, "-m", "swarmd_lab.demo", "--n", str(N), "--out", str(out),
            "--late-gps", "3", *extra]  # fmt: skip
    with subprocess.Popen(  # noqa: S603 - our own module, argv list
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    ) as proc:
        try:
            stdout, stderr = proc.communicate(timeout=150)
        except subprocess.TimeoutExpired:
            proc.terminate()  # the demo cleans up on SIGTERM
            stdout, stderr = proc.communicate(timeout=30)
        return subprocess.CompletedProcess(argv, proc.returncode, stdout, stderr), proc.pid


def _check(out: Path, proc: subprocess.CompletedProcess[str], mode: str) -> None:
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == mode and summary["n"] == N
    assert summary["takeoff"]["swarmctl_exit_code"] == 0
    assert summary["takeoff"]["airborne"] == N
    nodes = summary["nodes"]
    assert sorted(nodes) == ["drone-01", "drone-02", "lead"]
    for name, node in nodes.items():
        assert all(k in node for k in FIELDS), (name, node)
        assert node["ready"] and node["airborne"], (name, node)
        assert node["discovered_all_s"] is not None and node["discovered_all_s"] >= 0
        assert node["frames_sent"] > 0
        assert node["command_latency_s"] is not None
    assert nodes["lead"]["role"] == "commander"
    assert (out / "timeline.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # plain progress lines (no TTY here): discovery, readiness, take-off, IN_AIR, the table
    text = proc.stdout
    assert "[" in text and "\x1b[H" not in text
    assert "swarmctl: readiness:" in text and "TAKEOFF command" in text
    assert f"IN_AIR {N}/{N}" in text
    assert "CMD LATENCY (ms)" in text
    leftover = [line for line in text.splitlines() if line.startswith("set up in ")]
    run_dir = leftover[0].split()[3].rstrip(":")
    assert not os.path.exists(run_dir), f"{run_dir} left behind"


@pytest.mark.netns
def test_demo_in_namespaces(tmp_path: Path) -> None:
    proc, pid = _run_demo(tmp_path / "out")
    _check(tmp_path / "out", proc, "namespaces")
    assert "each a network namespace" in proc.stdout
    leaked = [n for n in list_namespaces() if n.startswith(f"swn-{pid}-")]
    assert not leaked, f"the demo left namespaces behind: {leaked}"


def test_demo_on_loopback(tmp_path: Path) -> None:
    proc, _ = _run_demo(tmp_path / "out", "--loopback")
    _check(tmp_path / "out", proc, "loopback")
    assert "running every drone on loopback (127.0.0.1) with distinct ports" in proc.stdout


@pytest.mark.netns
def test_demo_with_ros2_nodes_through_swarmd(tmp_path: Path) -> None:
    """``make demo ROS2=1``: a real rclpy node per drone, discovery served by swarmd; the
    listener hears every talker, the service answers, and no ROS 2 discovery is on the
    link (swarmd's own SPDP is)."""
    pytest.importorskip("rclpy", reason="ROS 2 wheels not installed (scripts/setup.sh)")
    proc, pid = _run_demo(tmp_path / "out", "--ros2")
    _check(tmp_path / "out", proc, "namespaces")
    ros2 = json.loads((tmp_path / "out" / "summary.json").read_text())["ros2"]
    assert ros2["talkers"] == N - 1
    assert sorted(ros2["listener"]["senders"]) == ["drone-01", "drone-02"]
    assert ros2["listener"]["answers"]
    assert ros2["link"]["ros2_spdp"] == 0 and ros2["link"]["ros2_sedp"] == 0
    assert ros2["link"]["ros2_graph"] == 0  # rmw's graph topic stays on each drone
    assert ros2["link"]["swarmd_spdp"] > 0
    assert "ROS 2 (rclpy through swarmd)" in proc.stdout
    assert not [n for n in list_namespaces() if n.startswith(f"swn-{pid}-")]


@pytest.mark.netns
def test_demo_with_xrce_vehicles(tmp_path: Path) -> None:
    """``make demo VEHICLE=xrce``: swarmd's PX4 stand-in over uXRCE-DDS per drone (PX4's
    client session, the shared vehicle model), swarmd as agent; needs no third-party peer.
    Every drone becomes ready through the XRCE backend and flies: the stand-in's core topic
    set has no home_position, so the take-off altitude is measured from its GPS altitude
    (docs/px4.md, Altitude) and the vehicle climbs to param7 minus that."""
    proc, pid = _run_demo(tmp_path / "out", "--vehicle", "xrce")
    text = proc.stdout
    assert "vehicles: swarmd-px4-xrce" in text and "xrce-agent" in text, text[-3000:]
    assert f"swarmctl: readiness: {N}/{N} ready" in text, text[-3000:]
    assert "no_home" not in text, text[-3000:]
    assert f"takeoff: {N}/{N} confirmed airborne" in text, text[-3000:]
    assert len(re.findall(r": completed \((IN_AIR|TAKEOFF)\)", text)) == N, text[-3000:]
    _check(tmp_path / "out", proc, "namespaces")  # exit 0, N/N airborne, every node's fields
    assert not [n for n in list_namespaces() if n.startswith(f"swn-{pid}-")]


@pytest.mark.netns
def test_demo_with_xrce_vehicles_through_micro_xrce_agent(tmp_path: Path) -> None:
    """``make demo VEHICLE=xrce-client``: per drone, px4_like_client through eProsima's
    MicroXRCEAgent and swarmd as that agent's second client; ``swarmctl takeoff`` flies N/N.
    Third-party: runs only with ``XRCE_PEERS`` (its MicroXRCEAgent put on PATH)."""
    agent = peer_binary("MicroXRCEAgent")
    env = peer_env()
    env["PATH"] = f"{agent.parent}{os.pathsep}{env.get('PATH', '')}"
    proc, pid = _run_demo(tmp_path / "out", "--vehicle", "xrce-client", env=env)
    text = proc.stdout
    assert "through eProsima's MicroXRCEAgent" in text and "xrce-client" in text, text[-3000:]
    assert f"takeoff: {N}/{N} confirmed airborne" in text, text[-3000:]
    assert len(re.findall(r": completed \((IN_AIR|TAKEOFF)\)", text)) == N, text[-3000:]
    _check(tmp_path / "out", proc, "namespaces")
    assert not [n for n in list_namespaces() if n.startswith(f"swn-{pid}-")]


def test_xrce_client_without_micro_xrce_agent_says_so_in_one_line(tmp_path: Path) -> None:
    """``make demo VEHICLE=xrce-client`` with no MicroXRCEAgent on PATH: one line saying it is
    needed, a non-zero exit, nothing started (no run directory announced)."""
    env = dict(os.environ, PATH=str(tmp_path))  # an empty directory: no MicroXRCEAgent
    proc, _ = _run_demo(tmp_path / "out", "--vehicle", "xrce-client", env=env)
    assert proc.returncode not in (0, None), proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "MicroXRCEAgent" in lines[0] and "PATH" in lines[0], lines
    assert "Traceback" not in proc.stderr and "set up in" not in proc.stdout


@pytest.mark.netns
def test_ctrl_c_stops_every_drone_and_removes_the_namespaces() -> None:
    argv = [sys.executable, "-m", "swarmd_lab.demo", "--n", "3", "--out", "/nonexistent-demo-out"]
    proc = subprocess.Popen(  # noqa: S603 - our own module, argv list
        argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    watchdog = threading.Timer(60.0, proc.kill)  # a hung demo fails the test, never the run
    watchdog.start()
    try:
        assert proc.stdout is not None
        seen: list[str] = []
        for line in proc.stdout:
            seen.append(line)
            if "started 3 swarmd + 3 simulators" in line:
                break
        run_dir = next(ln.split()[3].rstrip(":") for ln in seen if ln.startswith("set up in "))
        assert [n for n in list_namespaces() if n.startswith(f"swn-{proc.pid}-")]
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=45)
    finally:
        watchdog.cancel()
    assert proc.returncode == 130, "".join(seen) + rest
    assert "interrupted: stopping every drone" in rest
    assert not [n for n in list_namespaces() if n.startswith(f"swn-{proc.pid}-")]
    assert not os.path.exists(run_dir)
    # every process of the run had its config (or socket) path in the run folder
    left = subprocess.run(["pgrep", "-f", run_dir], capture_output=True, text=True, check=False)  # noqa: S607
    assert left.stdout.strip() == "", left.stdout
