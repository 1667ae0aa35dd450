"""A reader that closes stdout early ends a command quietly (swarmd/cli/pipes.py).

The pipe's read end is closed before the command starts, so its first write meets a
closed pipe whatever the timing.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swarmd.cli.pipes import EXIT_PIPE_CLOSED

ROOT = Path(__file__).resolve().parents[1]
SWARM3 = ROOT / "firmware_bundle/missions/swarm3.yaml"


def run_into_closed_pipe(*args: str) -> subprocess.CompletedProcess[bytes]:
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{ROOT / 'lab'}"}
        return subprocess.run(
            [sys.executable, *args],
            stdout=write_end,
            stderr=subprocess.PIPE,
            cwd=ROOT,
            env=env,
            timeout=60,
            check=False,
        )
    finally:
        os.close(write_end)


def swarmctl_bundle_show(tmp_path: Path) -> tuple[str, ...]:
    """``swarmctl bundle show`` of a bundle built here: a command with stdout output that
    needs no daemon."""
    swarmctl = ("-m", "swarmd.cli.swarmctl", "bundle")
    keys, bundle = tmp_path / "keys", tmp_path / "swarm3.bundle"
    for argv in (
        ("keygen", "--out", str(keys), "--mission", str(SWARM3)),
        ("build", str(SWARM3), "-o", str(bundle), "--sign-key", str(keys / "swarm-signing.key")),
    ):
        subprocess.run([sys.executable, *swarmctl, *argv], check=True, capture_output=True)
    return (*swarmctl, "show", str(bundle), "--json")


def command_of(tool: str, tmp_path: Path) -> tuple[str, ...]:
    if tool == "swarmctl":
        return swarmctl_bundle_show(tmp_path)
    if tool == "flight_campaign":
        return ("-m", "bench.wifi.flight_campaign", "--n", "10")
    matrix_dir = ROOT / "bench/results/flight-stagger"
    return ("-m", "bench.wifi.flight_report", "--matrix", str(matrix_dir))


@pytest.mark.parametrize("tool", ["swarmctl", "flight_campaign", "flight_report"])
def test_a_closed_stdout_ends_the_command_quietly_with_141(tool: str, tmp_path: Path) -> None:
    done = run_into_closed_pipe(*command_of(tool, tmp_path))
    assert done.returncode == EXIT_PIPE_CLOSED, done.stderr.decode(errors="replace")
    assert b"Traceback" not in done.stderr
    assert b"BrokenPipeError" not in done.stderr
