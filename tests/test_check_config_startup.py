"""``swarmd check-config`` refuses what ``swarmd run`` refuses at start, with the same line.

``run``'s start (``Daemon.start``) checks, before it binds anything, that the node's
address is the bundle's pinned ``ipv4`` and that a ROS 2 relay has a graph to serve. An
operator who runs ``check-config`` on the bench must not read ``ok`` for a config the
drone then stops with exit 78 (docs/operations.md, "Exit codes"). Neither config here
gets as far as a socket: both processes stop at the check.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

from swarmd.exitcodes import EX_CONFIG
from tests.daemon_support import (
    loopback_config,
    relay_config,
    run_domain,
    run_swarmd,
    write_bundle,
)

WAIT_S = 20.0


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return run_swarmd(*args, timeout_s=WAIT_S)


def _both_refuse(cfg: Path) -> str:
    """``check-config`` and ``run`` on ``cfg``: both exit 78 with one identical line (``run``
    logs its ``stopped`` event before it)."""
    check = _run("check-config", "--config", str(cfg))
    run = _run("run", "--config", str(cfg))
    assert check.returncode == EX_CONFIG, check
    assert run.returncode == EX_CONFIG, run
    assert check.stdout == ""
    assert check.stderr.count("\n") == 1, check.stderr
    assert run.stderr.splitlines()[-1] == check.stderr.rstrip("\n")
    return check.stderr


def test_check_config_refuses_an_address_other_than_the_bundles_pin(workdir: Path) -> None:
    # domain + 13: never the ports of the other daemon test files in the same run
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13, ipv4=["10.42.0.11", "10.42.0.12"])
    line = _both_refuse(loopback_config(workdir, files))  # announces 127.0.0.1
    assert "field network.ipv4" in line
    assert "127.0.0.1" in line and "10.42.0.11" in line


def test_check_config_accepts_the_pinned_address(workdir: Path) -> None:
    """The control: the same bundle pinning the address the config announces is ``ok``."""
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13, ipv4=["127.0.0.1", "10.42.0.12"])
    proc = _run("check-config", "--config", str(loopback_config(workdir, files)))
    assert proc.returncode == 0, proc.stderr
    assert ": ok (node uav1" in proc.stdout


def test_check_config_refuses_a_relay_without_a_ros2_graph(workdir: Path) -> None:
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13)  # no ros2: section
    line = _both_refuse(loopback_config(workdir, files, extra=relay_config()))
    assert "field ros2.relay" in line
