"""Ctrl-C in the suite: the first stops the run with every fixture's clean-up, the second at once.

A pytest plugin (``pytest_plugins`` in tests/conftest.py). What went wrong before (session
18, reproduced on an attack test, ``tests/test_attacks_local_netns.py``):

- A suite started as a background job of a non-interactive shell (``make test &`` in a
  script, an agent's or a CI step's shell) inherits SIGINT *ignored* (bash does that for
  ``&`` without job control), and Python keeps an ignored SIGINT ignored: two SIGINTs to
  pytest did nothing and the run went on to the next files. Here SIGINT always interrupts.
- A second Ctrl-C while the first one's clean-up ran (a LAN's daemons being stopped) raised
  KeyboardInterrupt inside that teardown: pytest skips every finalizer after one that
  raises it, so the namespaces and the processes in them stayed behind. Here the second
  SIGINT kills this run's processes and deletes its namespaces itself (one ``ip netns
  delete`` each, no stop waits), then ends pytest with its interrupted status, 2.
- A first Ctrl-C landing in a fixture's teardown (a LAN being closed between two tests)
  cut that clean-up short the same way; the namespaces it still held are now deleted
  after the session's teardown (``pytest_sessionfinish`` below).
- The attack tests' ``lab`` fixture restarted the whole swarm after an interrupted test
  before the module's teardown removed it (tests/attacker/lab.py no longer does).

The handler is ours, not ``signal.default_int_handler``, so ``asyncio.run`` in a test does
not install its own (Python 3.11 only does over the default one): Ctrl-C raises
KeyboardInterrupt inside the loop rather than cancelling the main task, which a coroutine
could swallow. A run killed harder (SIGKILL, a crash) still leaves namespaces; the next
run's ``_sweep_dead_namespaces`` (tests/conftest.py) removes those whose creator is gone.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
from collections.abc import Callable, Generator
from pathlib import Path
from types import FrameType
from typing import Any, Final

import pytest
from swarmd_lab.netns import delete_recorded

INTERRUPTED: Final = int(pytest.ExitCode.INTERRUPTED)  # 2: what pytest exits with on Ctrl-C


def descendants(pid: int) -> list[int]:
    """Every live process below ``pid`` (children first), read from /proc."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # gone since the listing
            continue
        ppid = int(stat.rpartition(")")[2].split()[1])  # proc(5): the field after state
        children.setdefault(ppid, []).append(int(entry.name))
    found: list[int] = []
    todo = list(children.get(pid, []))
    while todo:
        child = todo.pop(0)
        found.append(child)
        todo.extend(children.get(child, []))
    return found


def scratch_folders(pid: int) -> list[Path]:
    """The run's short scratch folders, named by its pid: the ``workdir`` fixture's
    (tests/conftest.py) and the attack swarms' (tests/attacker/lab.py)."""
    tmp = Path("/tmp")
    named = [tmp / f"{base}-{pid}" for base in ("atk", "spf")]
    return [*tmp.glob(f"swt-{pid}-*"), *(path for path in named if path.exists())]


def stop_at_once() -> list[str]:
    """SIGKILL every process this run started, delete every namespace it recorded and its
    scratch folders; return the namespaces' names."""
    for pid in descendants(os.getpid()):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)
    removed = delete_recorded()
    for folder in scratch_folders(os.getpid()):
        shutil.rmtree(folder, ignore_errors=True)
    return removed


class Interrupts:
    """The suite's SIGINT handler: KeyboardInterrupt the first time, ``stop_at_once`` and
    exit the second."""

    def __init__(self) -> None:
        self.owner = os.getpid()
        self.count = 0
        # the terminal, kept before pytest captures fd 2 around each test, for the one line
        # the second Ctrl-C prints (not inherited by children: os.dup's copy is CLOEXEC)
        self.terminal = os.dup(2)

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1
        if self.count == 1 or os.getpid() != self.owner:  # the latter: a fork before its exec
            raise KeyboardInterrupt
        # the clean-up below must not itself be cut short by a third Ctrl-C
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        removed = stop_at_once()
        gone = ", ".join(removed) or "none were left"
        line = f"\nsecond Ctrl-C: killed this run's processes; namespaces removed: {gone}\n"
        with contextlib.suppress(OSError):
            os.write(self.terminal, line.encode())
        os._exit(INTERRUPTED)


_previous: list[Callable[[int, FrameType | None], Any] | int | signal.Handlers] = []


def pytest_configure(config: pytest.Config) -> None:
    previous = signal.getsignal(signal.SIGINT)
    _previous.append(signal.default_int_handler if previous is None else previous)
    signal.signal(signal.SIGINT, Interrupts())


def pytest_unconfigure(config: pytest.Config) -> None:
    handler = signal.getsignal(signal.SIGINT)
    if isinstance(handler, Interrupts):
        os.close(handler.terminal)
    if _previous:
        signal.signal(signal.SIGINT, _previous.pop())


@pytest.hookimpl(tryfirst=True)  # before the terminal reporter keeps the traceback
def pytest_keyboard_interrupt(excinfo: pytest.ExceptionInfo[BaseException]) -> None:
    """Drop this handler's frame from the traceback, so pytest's summary names the line
    the run was at, as with Python's own handler; say what happens next."""
    tb = excinfo.tb
    while tb.tb_next is not None:
        if tb.tb_next.tb_frame.f_code is Interrupts.__call__.__code__:
            tb.tb_next = None
            break
        tb = tb.tb_next
    print(
        "\nCtrl-C: cleaning up (stopping daemons, removing namespaces); "
        "Ctrl-C again to stop at once",
        file=sys.stderr,
        flush=True,
    )


@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_sessionfinish(session: pytest.Session) -> Generator[None]:
    """After every fixture's teardown: delete the namespaces whose owner was cut short (a
    second KeyboardInterrupt raised inside a ``finally`` that was closing them)."""
    try:
        yield
    finally:
        left = delete_recorded()
        if left:
            print(f"removed namespaces their owners left: {left}", file=sys.stderr, flush=True)
