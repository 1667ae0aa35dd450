"""The run ``tests/test_interrupt_netns.py`` interrupts: one test waiting inside a LAN of
namespaces, with a process in it that ignores SIGTERM (so the LAN's teardown takes its
3 s stop wait, long enough for a second Ctrl-C to land in it). The file name keeps pytest
from collecting it; that test runs it by path, naming in ``SWARMD_INTERRUPT_DIR`` a folder
where it writes ``ready`` (the LAN's prefix and the process's pid) and ``teardown``.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Final

import pytest

from tests.conftest import LanFactory

pytestmark = pytest.mark.netns

# the test's own bound: it ends by itself if no SIGINT comes (0: at once, to the teardown)
WAIT_S: Final = float(os.environ.get("SWARMD_INTERRUPT_WAIT_S", "30"))
# a child that ignores SIGTERM, says it does, then waits (bounded)
STUBBORN: Final = (
    "import signal, sys, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
    "open(sys.argv[1], 'w').close(); time.sleep(60)"
)


def _folder() -> Path:
    return Path(os.environ["SWARMD_INTERRUPT_DIR"])


@pytest.fixture
def teardown_marker(lan_factory: LanFactory) -> Iterator[None]:
    """Torn down just before ``lan_factory`` (pytest's reverse order): says it started."""
    yield
    (_folder() / "teardown").write_text("")


def test_waits_inside_a_lan(lan_factory: LanFactory, teardown_marker: None) -> None:
    lan = lan_factory(2)
    started = _folder() / "stubborn"
    child = lan[0].popen([sys.executable, "-c", STUBBORN, str(started)])
    deadline = time.monotonic() + 30.0
    while not started.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    (_folder() / "ready").write_text(f"{lan.prefix} {child.pid}")
    time.sleep(WAIT_S)
