"""``swarmd run`` as a process: sd_notify READY/STATUS/WATCHDOG/STOPPING to a socket the test
binds, JSON logs, SIGTERM, and one-line exit 78 on a bad config or bundle."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
from pathlib import Path

import pytest

from tests.daemon_support import (
    SWARMD,
    BundleFiles,
    clean_env,
    loopback_config,
    run_domain,
    write_bundle,
)

WAIT_S = 20.0


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    # domain + 1: never the same ports as test_daemon_loopback in the same run
    return write_bundle(workdir, 2, domain_id=run_domain() + 1)


def _config(workdir: Path, files: BundleFiles) -> Path:
    return loopback_config(workdir, files)


def _env(**extra: str) -> dict[str, str]:
    return clean_env(**extra)


def test_ready_watchdog_and_clean_sigterm(workdir: Path, files: BundleFiles) -> None:
    notify_path = str(workdir / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(notify_path)
    sock.settimeout(WAIT_S)
    proc = subprocess.Popen(
        [SWARMD, "run", "--config", str(_config(workdir, files))],
        env=_env(NOTIFY_SOCKET=notify_path, WATCHDOG_USEC="200000"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        messages: list[str] = []
        while sum(m == "WATCHDOG=1" for m in messages) < 3:
            messages.append(sock.recv(4096).decode())
        assert messages[0].startswith("READY=1\nSTATUS=phase ")
        assert "peers 0/1 discovered" in messages[0]
        assert all(m.startswith(("STATUS=", "WATCHDOG=1")) for m in messages[1:])
        # the control socket is up once READY was sent
        assert (workdir / "ctl.sock").exists()
        proc.send_signal(signal.SIGTERM)
        while not (msg := sock.recv(4096).decode()).startswith("STOPPING=1"):
            assert msg.startswith(("STATUS=", "WATCHDOG=1"))
        _, err = proc.communicate(timeout=WAIT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        sock.close()
    assert proc.returncode == 0
    lines = [json.loads(line) for line in err.splitlines()]  # every log line is JSON
    events = [e["event"] for e in lines]
    # a first start records the bundle's serial as this node's floor (docs/security.md)
    assert events[0] == "bundle_floor_raised" and lines[0]["serial"] == 1
    assert events[1] == "link_source_retired"  # no nl80211 here (or lo is not wireless)
    assert "started" in events
    assert lines[-1]["event"] == "stopped"
    assert lines[-1]["reason"] == "SIGTERM"
    assert not (workdir / "ctl.sock").exists()


def _run(args: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SWARMD, *args], capture_output=True, text=True, timeout=WAIT_S, env=_env(), check=False
    )


def test_bad_config_exits_78_with_one_line(workdir: Path, files: BundleFiles) -> None:
    cfg = _config(workdir, files)
    cfg.write_text(cfg.read_text().replace("poll_interval_s: 0.2", "poll_interval_s: fast"))
    proc = _run(["run", "--config", str(cfg)])
    assert proc.returncode == 78
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1
    assert proc.stderr.startswith(f"swarmd: config rejected: {cfg}:")
    assert "field link.poll_interval_s: expected a number" in proc.stderr


def test_tampered_bundle_exits_78_with_one_line(workdir: Path, files: BundleFiles) -> None:
    data = bytearray(files.path.read_bytes())
    data[-10] ^= 0x01
    files.path.write_bytes(bytes(data))
    proc = _run(["run", "--config", str(_config(workdir, files))])
    assert proc.returncode == 78
    assert proc.stderr.count("\n") == 1
    assert proc.stderr.startswith(f"swarmd: bundle rejected: {files.path}: ")


def test_node_not_in_bundle_exits_78(workdir: Path, files: BundleFiles) -> None:
    cfg = _config(workdir, files)
    cfg.write_text(cfg.read_text().replace("node: uav1", "node: uav7"))
    proc = _run(["run", "--config", str(cfg)])
    assert proc.returncode == 78
    assert proc.stderr.count("\n") == 1
    assert f"{cfg}:1: field node: 'uav7' is not a participant" in proc.stderr


def test_check_config(workdir: Path, files: BundleFiles) -> None:
    proc = _run(["check-config", "--config", str(_config(workdir, files))])
    assert proc.returncode == 0, proc.stderr
    assert "ok (node uav1, swarm testswarm)" in proc.stdout
