"""Ctrl-C stops the suite, and leaves no namespace or process of its own (tests/interrupt.py).

Each test runs ``tests/interrupt_target.py`` in a pytest of its own session, waits until
that run is inside a LAN of namespaces, sends it SIGINT, and asserts the run ends with
pytest's interrupted status (2) with its namespaces and its process gone. Both failed on
main: a run started with SIGINT ignored (a background job of a non-interactive shell) ran
its test to the end and passed (status 0); a second SIGINT during the clean-up cut the
LAN's teardown short (status -2, the namespaces and the SIGTERM-ignoring process left).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Final

import pytest
from swarmd_lab.netns import NamespaceRecord, cleanup_stale, list_namespaces

from tests.conftest import sweep_dead_runs
from tests.interrupt import scratch_folders

pytestmark = pytest.mark.netns

REPO: Final = Path(__file__).resolve().parents[1]
TARGET: Final = REPO / "tests" / "interrupt_target.py"
WAIT_S: Final = 60.0  # generous: a loaded 2-core box starts a pytest and a LAN in ~10 s
# sets SIGINT's disposition (argv[1]: "ignore" or "default"), then execs the rest of argv;
# an ignored signal stays ignored across exec, as a shell's background job has it
EXEC_WITH_SIGINT: Final = (
    "import os, signal, sys; "
    "signal.signal(signal.SIGINT, signal.SIG_IGN if sys.argv[1] == 'ignore' "
    "else signal.SIG_DFL); os.execv(sys.argv[2], sys.argv[2:])"
)


def _wait_for(cond: Callable[[], bool], proc: subprocess.Popen[bytes], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not cond():
        assert proc.poll() is None, f"the run ended (status {proc.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} within {WAIT_S:.0f} s"
        time.sleep(0.05)


def _alive(pid: int) -> bool:
    """Running, not a zombie (killed, its parent gone, and init not yet reaped it)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rpartition(")")[2].split()[0] != "Z"  # proc(5): the state


@pytest.fixture
def interrupted_run(tmp_path: Path) -> Iterator[Callable[..., subprocess.Popen[bytes]]]:
    """``start(sigint, wait_s=30) -> Popen``: the target run in its own session (our SIGINT
    is not its terminal's), its test waiting ``wait_s`` in the LAN; killed with everything
    of its own on every exit path of the test."""
    runs: list[subprocess.Popen[bytes]] = []

    def start(sigint: str, wait_s: float = 30.0) -> subprocess.Popen[bytes]:
        argv = [sys.executable, "-c", EXEC_WITH_SIGINT, sigint, sys.executable, "-m", "pytest"]
        argv += ["-q", "-p", "no:cacheprovider", str(TARGET)]
        with (tmp_path / "run.log").open("ab") as log:
            proc = subprocess.Popen(  # noqa: S603 - our own argv
                argv, cwd=REPO, start_new_session=True, stdout=log, stderr=log,
                env={**os.environ, "SWARMD_INTERRUPT_DIR": str(tmp_path),
                     "SWARMD_INTERRUPT_WAIT_S": str(wait_s)},
            )  # fmt: skip
        runs.append(proc)
        return proc

    yield start
    for proc in runs:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(WAIT_S)
        cleanup_stale(f"swn-{proc.pid}-")  # what it left, had it failed
        for folder in scratch_folders(proc.pid):
            shutil.rmtree(folder, ignore_errors=True)


def _interrupt(run: subprocess.Popen[bytes], folder: Path, *marks: str) -> None:
    """SIGINT ``run`` as each of ``marks`` appears in ``folder``; then assert it ended with
    pytest's interrupted status and left neither its namespaces nor the stubborn process."""
    for mark in marks:
        _wait_for((folder / mark).exists, run, mark)
        run.send_signal(signal.SIGINT)
    assert run.wait(WAIT_S) == pytest.ExitCode.INTERRUPTED, (folder / "run.log").read_text()
    prefix, pid = (folder / "ready").read_text().split()
    assert [n for n in list_namespaces() if n.startswith(prefix + "-")] == []
    assert not _alive(int(pid)), "the process in the namespace still runs"
    assert scratch_folders(run.pid) == []


def test_one_sigint_stops_a_run_that_started_with_sigint_ignored(
    interrupted_run: Callable[..., subprocess.Popen[bytes]], tmp_path: Path
) -> None:
    _interrupt(interrupted_run("ignore"), tmp_path, "ready")


def test_a_second_sigint_during_the_cleanup_stops_at_once_and_leaks_nothing(
    interrupted_run: Callable[..., subprocess.Popen[bytes]], tmp_path: Path
) -> None:
    # the second lands while the LAN's teardown waits on the child that ignores SIGTERM
    _interrupt(interrupted_run("default"), tmp_path, "ready", "teardown")


def test_a_sigint_in_a_teardown_still_removes_its_namespaces(
    interrupted_run: Callable[..., subprocess.Popen[bytes]], tmp_path: Path
) -> None:
    # the test ends at once; the one SIGINT lands while the LAN's teardown waits
    _interrupt(interrupted_run("default", wait_s=0), tmp_path, "teardown")


def test_the_next_run_removes_what_a_killed_attack_run_left() -> None:
    """A run killed harder than Ctrl-C (SIGKILL) leaves its namespaces; the next session's
    sweep removes the attack swarms' (``atk-<pid>-...``) too, not only ``swn-<pid>-...``."""
    gone = subprocess.Popen([sys.executable, "-c", "pass"])  # noqa: S603 - a pid now dead
    gone.wait()
    left = f"atk-{gone.pid}-1-hub"
    record = NamespaceRecord()
    try:
        record.add(left)  # as that run's attacked_swarm made it
        assert left in sweep_dead_runs()
        assert left not in list_namespaces()
    finally:
        record.close()
